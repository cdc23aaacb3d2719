#!/usr/bin/env bash
# HTTP service benchmark: GET /v1/jobs/{id} throughput and latency while two
# jobs run, and the time from POST /v1/jobs to the first frame (SSE `frame`
# event).
#
# Usage: benches/serve.sh [RUNNER]
#   RUNNER: `test` (default: the test-only synthetic runner, 50 ms/frame,
#   so the figures measure the service, not the geometry) or `real` (the
#   production runner: the time to first frame then measures the pipeline).
# Environment: SIZE, the two trees' branch count (default 2000),
# PRESET_A / PRESET_B, their presets (default maple / conifer), TREEMORPH_BIN
# (a binary to use instead of building the release one). A 5,000-chain
# morph: PRESET_A=eucalyptus SIZE=16000 (4,989 → 5,036 chains).
# Needs wrk (apt-get install wrk) and curl; oha (cargo install oha) for
# the fixed-rate run. Talks to 127.0.0.1 only.
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
A=$(curl -s -XPOST "$BASE/v1/trees/generate" -H 'content-type: application/json' -d '{"preset":"'"${PRESET_A:-maple}"'","seed":1,"size":'"$SIZE"'}' | json "['id']")
B=$(curl -s -XPOST "$BASE/v1/trees/generate" -H 'content-type: application/json' -d '{"preset":"'"${PRESET_B:-conifer}"'","seed":2,"size":'"$SIZE"'}' | json "['id']")
# (sed, not python, in the timed path: the job document starts with its id.)
job() { curl -s -XPOST "$BASE/v1/jobs" -H 'content-type: application/json' -d "{\"kind\":\"morph\",\"source\":\"$A\",\"target\":\"$B\",\"frames\":$1}" | sed -n 's/^{"id":"\([0-9a-f]*\)".*/\1/p'; }

# Time from POST to the first frame event, 5 runs (median printed). Each
# run starts once the previous job has ended, so a worker is free: the
# figure is the pipeline's latency, not time spent queued behind earlier
# jobs (capacity is benches/scaleout.sh's business). With the test runner
# this is queue latency + loading the two trees + one 50 ms frame; with the
# real runner it includes planning and encoding the first frame.
times=()
for _ in 1 2 3 4 5; do
  t0=$(date +%s%N)
  J=$(job 4)
  # grep exits at the first frame event; curl then fails writing (23).
  { curl -sN "$BASE/v1/jobs/$J/events" || true; } | grep -m1 -q '^event: frame'
  t1=$(date +%s%N)
  times+=($(( (t1 - t0) / 1000000 )))
  { curl -sN "$BASE/v1/jobs/$J/events" || true; } | grep -m1 -qE '^event: (done|failed|cancelled)'
done
sorted=($(printf '%s\n' "${times[@]}" | sort -n))
echo "post_to_first_frame_ms (median of 5, runner=$RUNNER): ${sorted[2]} (all: ${times[*]})"

# Two long jobs running while we hammer GET /v1/jobs/{id}.
J1=$(job 600); J2=$(job 600)
sleep 0.5
# Saturation: as many requests as 32 connections can make (closed loop).
wrk -t2 -c32 -d"$DURATION" --latency "$BASE/v1/jobs/$J1" | tee "$DATA/wrk.txt"
# The issue's figure: latency at a fixed 5,000 requests/s (open loop, with
# latency correction, so a stall counts for every request it delays).
# Needs oha (cargo install oha); skipped without it.
if command -v oha >/dev/null; then
  oha -z "$DURATION" -c 32 -q 5000 --latency-correction --no-tui --output-format json \
    "$BASE/v1/jobs/$J1" | python3 -c '
import json, sys
d = json.load(sys.stdin)
p = d["latencyPercentiles"]
print("fixed_rate_5000: %.0f req/s, p50 %.2f ms, p99 %.2f ms, max %.2f ms, status %s" % (
    d["summary"]["requestsPerSec"], p["p50"] * 1e3, p["p99"] * 1e3,
    d["summary"]["slowest"] * 1e3, d["statusCodeDistribution"]))'
fi
echo "jobs during the run: $(curl -s "$BASE/v1/jobs/$J1" | json "['status']") / $(curl -s "$BASE/v1/jobs/$J2" | json "['status']")"
