#!/usr/bin/env bash
# HTTP service benchmark: GET /v1/jobs/{id} throughput and latency while two
# jobs run, and the time from POST /v1/jobs to the first frame (SSE `frame`
# event).
#
# Usage: benches/serve.sh [RUNNER]
#   RUNNER: `test` (default: the test-only synthetic runner, 50 ms/frame,
#   so the figures measure the service, not the geometry) or `real` (the
#   production runner: the time to first frame then measures the pipeline).
# Environment: SIZE, the two trees' branch count (default 2000; 5400 gives
# the issue's 5,000-chain morph), TREEMORPH_BIN (a binary to use instead of
# building the release one).
# Needs wrk (apt-get install wrk) and curl. Talks to 127.0.0.1 only.
set -euo pipefail
cd "$(dirname "$0")/.."
RUNNER=${1:-test}
DURATION=${DURATION:-10s}
SIZE=${SIZE:-2000}
if [ -n "${TREEMORPH_BIN:-}" ]; then
  BIN=$TREEMORPH_BIN
else
  cargo build --release -p treemorph --bin treemorph >&2
  BIN=target/release/treemorph
fi
DATA=$(mktemp -d)
OUT=$(mktemp)
trap 'kill $PID 2>/dev/null || true; wait $PID 2>/dev/null || true; rm -rf "$DATA" "$OUT"' EXIT
if [ "$RUNNER" = test ]; then export TREEMORPH_TEST_RUNNER=slow:50; fi
RUST_LOG=warn "$BIN" serve --listen 127.0.0.1:0 --data-dir "$DATA" --workers 2 >"$OUT" 2>"$DATA/log" &
PID=$!
for _ in $(seq 100); do grep -q listening "$OUT" 2>/dev/null && break; sleep 0.1; done
BASE=$(sed -n 's/^listening on //p' "$OUT")
json() { python3 -c "import json,sys; print(json.load(sys.stdin)$1)"; }
A=$(curl -s -XPOST "$BASE/v1/trees/generate" -H 'content-type: application/json' -d '{"preset":"maple","seed":1,"size":'"$SIZE"'}' | json "['id']")
B=$(curl -s -XPOST "$BASE/v1/trees/generate" -H 'content-type: application/json' -d '{"preset":"conifer","seed":2,"size":'"$SIZE"'}' | json "['id']")
# (sed, not python, in the timed path: the job document starts with its id.)
job() { curl -s -XPOST "$BASE/v1/jobs" -H 'content-type: application/json' -d "{\"kind\":\"morph\",\"source\":\"$A\",\"target\":\"$B\",\"frames\":$1}" | sed -n 's/^{"id":"\([0-9a-f]*\)".*/\1/p'; }

# Time from POST to the first frame event, 5 runs (median printed). With
# the test runner this is queue latency + loading the two 2,000-branch trees
# + one 50 ms frame; with the real runner it includes planning.
times=()
for _ in 1 2 3 4 5; do
  t0=$(date +%s%N)
  J=$(job 4)
  # grep exits at the first frame event; curl then fails writing (23).
  { curl -sN "$BASE/v1/jobs/$J/events" || true; } | grep -m1 -q '^event: frame'
  t1=$(date +%s%N)
  times+=($(( (t1 - t0) / 1000000 )))
done
sorted=($(printf '%s\n' "${times[@]}" | sort -n))
echo "post_to_first_frame_ms (median of 5, runner=$RUNNER): ${sorted[2]} (all: ${times[*]})"

# Two long jobs running while we hammer GET /v1/jobs/{id}.
J1=$(job 600); J2=$(job 600)
sleep 0.5
wrk -t2 -c32 -d"$DURATION" --latency "$BASE/v1/jobs/$J1" | tee "$DATA/wrk.txt"
echo "jobs during the run: $(curl -s "$BASE/v1/jobs/$J1" | json "['status']") / $(curl -s "$BASE/v1/jobs/$J2" | json "['status']")"
