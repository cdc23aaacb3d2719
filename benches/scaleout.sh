#!/usr/bin/env bash
# Scale-out benchmark: jobs per minute with 1, 2 and 3 worker processes
# (one API process, PostgreSQL, S3 on moto, the production pipeline), then
# the queue's claim latency under contention on SQLite and PostgreSQL.
#
# Usage: benches/scaleout.sh [JOBS]          (default 24 jobs per run)
# Environment:
#   WORKERS_PER_PROCESS  jobs each worker process runs at once (default 1)
#   PROCESSES            worker-process counts to try (default "1 2 3")
#   FRAMES, SIZE         the job mix: frames per job (default 24) and the
#                        trees' branch count (default 1000); maple -> conifer,
#   OUTPUTS              the jobs' `outputs` (default {"glb": false}: the
#                        animated GLB and the delta stream, no per-frame GLBs,
#                        so the S3 server is not what is measured)
# Needs what scripts/ci/scaleout.sh needs (postgresql-15, moto[server]).
# Talks to 127.0.0.1 only. Note that this machine's 2 cores bound the
# scaling: beyond 2 busy processes the workers share the same cores.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/ci/services.sh

JOBS=${1:-24}
WORKERS_PER_PROCESS=${WORKERS_PER_PROCESS:-1}
PROCESSES=${PROCESSES:-"1 2 3"}
FRAMES=${FRAMES:-24}
SIZE=${SIZE:-1000}
OUTPUTS=${OUTPUTS:-'{"glb": false}'}

# TREEMORPH_BIN: a binary to use instead of building the release one.
if [ -n "${TREEMORPH_BIN:-}" ]; then
  BIN=$TREEMORPH_BIN
else
  cargo build --release --locked -p treemorph --bin treemorph >&2
  BIN=$PWD/target/release/treemorph
fi
work=$(mktemp -d)
pids=()
stop_fleet() {
  for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
  pids=()
}
cleanup() {
  stop_fleet
  services_stop
  rm -rf "$work"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

services_start "$work" "$work/logs" >&2

# Starts `treemorph serve` with ROLE; prints its base URL.
launch() {
  local role=$1 name=$2 db=$3 blobs=$4
  mkdir -p "$work/$name"
  RUST_LOG=warn "$BIN" serve --listen 127.0.0.1:0 --role "$role" --data-dir "$work/$name" \
    --database-url "$db" --blob-url "$blobs" --workers "$WORKERS_PER_PROCESS" --poll-ms 100 \
    >"$work/$name/out" 2>"$work/$name/log" &
  pids+=($!)
  for _ in $(seq 200); do grep -q listening "$work/$name/out" 2>/dev/null && break; sleep 0.05; done
  sed -n 's/^listening on //p' "$work/$name/out"
}

echo "job mix: $JOBS morph jobs, maple -> conifer, $SIZE branches, $FRAMES frames, outputs $OUTPUTS;"
echo "         $WORKERS_PER_PROCESS job(s) at once per worker process; $(nproc) cores"
for n in $PROCESSES; do
  db=$(services_createdb "bench_${n}_$$_$RANDOM")
  blobs="$TREEMORPH_TEST_S3_URL/bench-$$-$n"
  api=$(launch api "api-$n" "$db" "$blobs")
  for i in $(seq "$n"); do launch worker "worker-$n-$i" "$db" "$blobs" >/dev/null; done
  python3 - "$api" "$JOBS" "$FRAMES" "$SIZE" "$n" "$OUTPUTS" <<'PY'
import json, sys, time, urllib.request
base, jobs, frames, size, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
outputs = json.loads(sys.argv[6])
def call(method, path, body=None):
    req = urllib.request.Request(base + path, method=method,
        data=None if body is None else json.dumps(body).encode(),
        headers={"content-type": "application/json"})
    with urllib.request.urlopen(req, timeout=60) as r:
        return json.load(r)
a = call("POST", "/v1/trees/generate", {"preset": "maple", "seed": 1, "size": size})["id"]
b = call("POST", "/v1/trees/generate", {"preset": "conifer", "seed": 2, "size": size})["id"]
t0 = time.monotonic()
ids = [call("POST", "/v1/jobs", {"kind": "morph", "source": a, "target": b, "frames": frames, "outputs": outputs})["id"] for _ in range(jobs)]
left = set(ids)
while left:
    for j in list(left):
        doc = call("GET", f"/v1/jobs/{j}")
        if doc["status"] in ("succeeded", "failed", "cancelled"):
            if doc["status"] != "succeeded":
                sys.exit(f"job {j} {doc['status']}: {doc.get('error')}")
            left.discard(j)
    time.sleep(0.1)
dt = time.monotonic() - t0
print(f"{n} worker process(es): {jobs} jobs in {dt:.1f} s = {jobs / dt * 60:.1f} jobs/min")
PY
  stop_fleet
done

echo
echo "claim latency (3 pools x 4 claimers, 2000 jobs):"
cargo test --release --locked -p treemorph --lib claim_latency_report -- --ignored --nocapture 2>/dev/null \
  | grep '^claim latency'
