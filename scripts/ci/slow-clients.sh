#!/usr/bin/env bash
# Slow-client test (hardening issue): slowloris and slow-body connections
# must neither pile up nor slow legitimate clients down.
#
# Starts `treemorph serve` (embedded SQLite, a temporary data directory, no
# API keys, so `/v1` is open), then scripts/ci/slow_clients.py:
#   1. baseline: GET /v1/jobs (a real API route: authentication middleware,
#      database query, JSON) with `wrk -t2 -c16 --latency` and a 10 ms think
#      time per connection (a wrk Lua `delay()`; about 1500 requests/s, so
#      the 2 cores keep headroom and p99 measures how the server treats
#      clients, not how the CPU is shared), 5 runs of 2 s; the phase's p99
#      is the median of the runs' p99s (parsed from wrk's "99%" line), so
#      one burst of unrelated load on a shared runner does not decide it;
#   2. attack: `slowhttptest -B` (slow-body POST /v1/trees uploads: 1000
#      opened at 40/s, Content-Length 1 MB, a few bytes every 2 s; about
#      250-400 are open at once once under way) and `slowhttptest -H`
#      (slowloris: 1200 connections opened at 60/s, one more header line
#      every 2 s; about 550 are open at once once under way), both at nice
#      19 (slowhttptest -B busy-polls a whole core, which a real attacker
#      spends on its own machine); while both are open the same wrk series
#      runs again; once every slow connection is gone, a third series gives
#      the baseline after the attack;
#   3. asserts
#      (a) reaping. Every 0.25 s the helper lists the established client
#          sockets to the server's port with their inodes
#          (`ss -tne state established '( dport = :PORT )'`) and finds their
#          owner in /proc/PID/fd of the two slowhttptest processes: the
#          client side of a socket leaves ESTABLISHED the moment the server
#          closes it (FIN), and the owner tells slowloris, slow-body and wrk
#          sockets apart although all talk to one port. First and last
#          sighting give every slow connection's lifetime (±0.25 s).
#          Slowloris connections (headers never finish although data keeps
#          coming, so only a total header deadline ends them) must live at
#          most header-read-timeout + 2 s; slow-body connections (complete
#          headers, body trickling in) at most header-read-timeout + 2 s
#          too (the server's minimum body rate, `--min-body-rate`, cuts a
#          body off with 408 body_too_slow once the header timeout has
#          passed). This is more robust than slowhttptest's report, which
#          notices a close only at its next send (its CSVs are kept in the
#          logs). The attack must also have been real: at least 250
#          slowloris and 150 slow-body connections open throughout the wrk
#          series under attack.
#      (b) legitimate p99 under attack <= max(2 x B, B + 5 ms), B the larger
#          of the baselines before and after (brackets background load that
#          changed meanwhile): the issue asks for "p99 less than doubled";
#          the 5 ms floor keeps a 1-3 ms baseline from turning scheduler
#          noise into a failure. No request of any wrk run may fail.
#      (c) afterwards the server is healthy: /healthz, /readyz and /v1/jobs
#          answer, a tree can be generated and uploaded, no server socket is
#          left open, no spooled upload is left in DATA/tmp, and the server
#          logged no panic.
#   and prints a summary table.
#
# Environment: SLOW_CLIENTS_HEADER_TIMEOUT (seconds, default 10, the
# server's default), SLOW_CLIENTS_REQUEST_TIMEOUT (default 60, the
# server's default), SLOW_CLIENTS_PACE_MS (wrk think time, default 10),
# TREEMORPH_BIN (use this binary instead of building; for iterating on the
# script).
# Needs (installs nothing itself; scripts/setup installs them):
#   Debian: slowhttptest wrk iproute2 (ss) python3
# Budget: about 90 s on 2 cores once the binary is built.
# Logs: $TREEMORPH_TEST_OUT/slow-clients (default
# target/test-artifacts/slow-clients).
set -euo pipefail
cd "$(dirname "$0")/../.."

header_timeout=${SLOW_CLIENTS_HEADER_TIMEOUT:-10}
request_timeout=${SLOW_CLIENTS_REQUEST_TIMEOUT:-60}

out=${TREEMORPH_TEST_OUT:-target/test-artifacts}/slow-clients
rm -rf "$out"
mkdir -p "$out"
out=$(cd "$out" && pwd)
work=$(mktemp -d)
server_pid=""
helper_pid=""

cleanup() {
  status=$?
  if [ -n "$helper_pid" ]; then kill "$helper_pid" 2>/dev/null || true; wait "$helper_pid" 2>/dev/null || true; fi
  if [ -n "$server_pid" ]; then kill -9 "$server_pid" 2>/dev/null || true; wait "$server_pid" 2>/dev/null || true; fi
  rm -rf "$work"
  if [ "$status" != 0 ]; then
    echo "slow-client test FAILED; logs in $out" >&2
  fi
  exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

for tool in wrk slowhttptest ss python3; do
  command -v "$tool" >/dev/null || {
    echo "$tool is missing (Debian: apt-get install slowhttptest wrk iproute2 python3, or run scripts/setup)" >&2
    exit 1
  }
done

if [ -n "${TREEMORPH_BIN:-}" ]; then
  bin=$TREEMORPH_BIN
else
  # The binary as scripts/test's other steps build it (whole workspace with
  # its tests: the same dependency features, so no second build).
  cargo test --workspace --locked --no-run
  bin=$(realpath -m "${CARGO_TARGET_DIR:-target}")/debug/treemorph
fi

mkdir -p "$work/data"
RUST_LOG=${RUST_LOG:-info} NO_COLOR=1 "$bin" serve \
  --listen 127.0.0.1:0 \
  --data-dir "$work/data" \
  --header-read-timeout "$header_timeout" \
  --request-timeout "$request_timeout" \
  >"$out/server.stdout" 2>"$out/server.log" &
server_pid=$!

base=""
for _ in $(seq 1 300); do
  line=$(head -n 1 "$out/server.stdout" 2>/dev/null || true)
  case "$line" in
    "listening on "*) base=${line#listening on }; break ;;
  esac
  kill -0 "$server_pid" 2>/dev/null || { echo "the server exited at start; see $out/server.log" >&2; exit 1; }
  sleep 0.1
done
[ -n "$base" ] || { echo "the server printed no address within 30 s" >&2; exit 1; }
echo "server at $base (header-read-timeout ${header_timeout}s, request-timeout ${request_timeout}s)"

# Latency is compared with a baseline: start both on a quiet machine.
. scripts/lib.sh
wait_until_idle 60

python3 scripts/ci/slow_clients.py \
  --base "$base" \
  --data-dir "$work/data" \
  --server-log "$out/server.log" \
  --out "$out" \
  --header-timeout "$header_timeout" \
  --request-timeout "$request_timeout" &
helper_pid=$!
wait "$helper_pid"
helper_pid=""
