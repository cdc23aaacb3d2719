# Throwaway PostgreSQL 15 and S3 (moto) servers on loopback, for the
# scale-out test and benchmark. Source it, then call
#
#   services_start DIR LOGDIR   # sets TREEMORPH_TEST_POSTGRES_URL, TREEMORPH_TEST_S3_URL
#                               # and exports the AWS_* variables for the S3 server
#   services_stop               # (call it from an EXIT trap)
#   services_createdb NAME      # a fresh database; prints its URL
#
# Needs, and installs nothing itself:
#   Debian: postgresql-15   (apt-get install -y postgresql-15)
#   PyPI:   moto[server]    (pip install 'moto[server]'; gives moto_server —
#                            taken from target/ci-venv, where scripts/setup
#                            installs scripts/ci/requirements.txt, else PATH)
#   python3                 (free ports, the bucket)
# As root the database server runs as the `postgres` user (it refuses root).

PG_BIN=${PG_BIN:-/usr/lib/postgresql/15/bin}
if [ -z "${MOTO_SERVER:-}" ]; then
  if [ -x target/ci-venv/bin/moto_server ]; then
    MOTO_SERVER=$PWD/target/ci-venv/bin/moto_server
  else
    MOTO_SERVER=moto_server
  fi
fi
_services_pg_data=""
_services_moto_pid=""

_free_port() {
  python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# As root, PostgreSQL runs as `postgres`, which may not traverse the
# checkout (a clone in a `mktemp -d` directory is 0700): it works from `/`.
_as_pg() {
  if [ "$(id -u)" = 0 ]; then (cd / && runuser -u postgres -- "$@"); else "$@"; fi
}

services_start() {
  local dir=$1 logs=$2
  mkdir -p "$logs"
  local pg="$dir/pg" pg_log="$logs/postgres.log"
  if [ "$(id -u)" = 0 ]; then
    # Data, socket and log where `postgres` can reach them whatever the
    # checkout's permissions; the log is linked from the artefacts.
    pg=$(mktemp -d /tmp/treemorph-pg.XXXXXX)
    chmod 755 "$pg"
    chown postgres "$pg"
    pg_log="$pg/postgres.log"
    ln -sfn "$pg_log" "$logs/postgres.log"
  else
    mkdir -p "$pg"
  fi
  [ -x "$PG_BIN/initdb" ] || { echo "PostgreSQL 15 is missing: apt-get install -y postgresql-15" >&2; return 1; }
  command -v "$MOTO_SERVER" >/dev/null || { echo "moto_server is missing: pip install 'moto[server]'" >&2; return 1; }

  local pg_port s3_port
  pg_port=$(_free_port)
  _services_pg_data="$pg/data"
  _as_pg "$PG_BIN/initdb" -D "$_services_pg_data" -A trust -U postgres -E UTF8 --no-sync >"$logs/initdb.log" 2>&1
  # fsync off: a test server, and the test kills workers, not the database.
  _as_pg "$PG_BIN/pg_ctl" -D "$_services_pg_data" -l "$pg_log" -w -t 60 \
    -o "-p $pg_port -k $pg -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=300" start >/dev/null
  export TREEMORPH_TEST_POSTGRES_URL="postgres://postgres@127.0.0.1:$pg_port"
  SERVICES_PG_PORT=$pg_port

  s3_port=$(_free_port)
  "$MOTO_SERVER" -H 127.0.0.1 -p "$s3_port" >"$logs/moto.log" 2>&1 &
  _services_moto_pid=$!
  export AWS_ACCESS_KEY_ID=treemorph-test AWS_SECRET_ACCESS_KEY=treemorph-test
  export AWS_REGION=us-east-1 AWS_ENDPOINT_URL="http://127.0.0.1:$s3_port"
  export AWS_EC2_METADATA_DISABLED=true
  # Wait for the S3 server, then create the bucket.
  python3 - "$AWS_ENDPOINT_URL/treemorph-test" <<'PY'
import sys, time, urllib.request
url = sys.argv[1]
for _ in range(150):
    try:
        urllib.request.urlopen(urllib.request.Request(url, method="PUT"), timeout=2)
        sys.exit(0)
    except Exception as e:
        last = e
        time.sleep(0.2)
sys.exit(f"the S3 server did not come up: {last}")
PY
  export TREEMORPH_TEST_S3_URL="s3://treemorph-test"
  echo "PostgreSQL on 127.0.0.1:$pg_port, S3 (moto) on 127.0.0.1:$s3_port"
}

services_stop() {
  if [ -n "$_services_pg_data" ] && [ -f "$_services_pg_data/postmaster.pid" ]; then
    _as_pg "$PG_BIN/pg_ctl" -D "$_services_pg_data" -m immediate stop >/dev/null 2>&1 || true
  fi
  if [ -n "$_services_moto_pid" ]; then
    kill "$_services_moto_pid" 2>/dev/null || true
    wait "$_services_moto_pid" 2>/dev/null || true
  fi
  _services_pg_data=""
  _services_moto_pid=""
}

services_createdb() {
  "$PG_BIN/psql" -q -h 127.0.0.1 -p "$SERVICES_PG_PORT" -U postgres -d postgres \
    -c "CREATE DATABASE $1" >/dev/null
  echo "$TREEMORPH_TEST_POSTGRES_URL/$1"
}
