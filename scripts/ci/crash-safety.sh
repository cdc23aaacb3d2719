#!/usr/bin/env bash
# Crash-safety test (hardening issue): kill -9 the server 20 times while it
# takes uploads and runs jobs; nothing it acknowledged may be lost, nothing
# partial may ever be served, and the database must stay intact.
#
# scripts/ci/crash_safety.py does the work, on one persistent data directory
# (embedded SQLite, local blobs) and the test-only job runner
# (TREEMORPH_TEST_RUNNER=slow:100,trace=DIR: 16 frames of 100 ms, so a job
# runs about 1.6 s; outputs are stamped with their attempt's token and every
# attempt's start and end go to a trace file), with 2 workers and 2 s
# leases (`--lease-secs 2`, as tests/it/process.rs, so the next process
# takes over a killed attempt within seconds):
#   20 times: start the server; two threads upload a 3 MB body in a loop
#   (a tree JSON or a GLB, sent in 64 KiB pieces with a pause after each, so
#   the body is in flight for about half a second, then parsed and stored);
#   a third generates 2 trees, posts 3 morph jobs (each with an
#   Idempotency-Key; a post whose answer was lost is retried with the same
#   key after the restart), cancels a random job half of the time and polls
#   the job list; a fourth renders frames at random instants of succeeded
#   jobs (`frame.glb?t=`, 100 ms each), one after another; a fifth deletes
#   one ended job within 30 ms before the kill; after a random 0.3-3 s the
#   server gets SIGKILL. Every 201, 202 and 204 the clients received is
#   recorded.
#   Then `PRAGMA integrity_check` on the crashed database (python3 sqlite3),
#   one more start (slow:10, to drain the backlog quickly), unacknowledged
#   job posts retried, and a wait until every job is terminal (90 s).
# Asserts:
#   - nothing lost: every acknowledged tree and job is listed; one job per
#     idempotency key (no duplicate after a retry, no phantom); a retried
#     post gets the id of its first acknowledgement, if any (one job post
#     per life is timed to race the kill, so some answers are lost after
#     the commit and the retry must find that job again);
#   - deletes hold: a job whose DELETE was answered 204 is not listed and
#     answers 404 (its outputs and instants too); a delete cut by the kill
#     either happened or the job is listed and verified like any other;
#     every instant rendered is the test runner's bytes for that instant;
#   - every job terminal (succeeded, failed or cancelled) and for a reason
#     the test can explain: cancelled only if we asked; an acknowledged
#     cancellation of a queued job stays cancelled, of a running one ends
#     cancelled or succeeded (it may finish first); failed only with the
#     "worker stopped responding" error after 3 attempts (--max-attempts);
#   - nothing partial served: every listed tree (acknowledged or not) has
#     its metadata, a tree.json that parses with the node and leaf counts of
#     its stats, a GLB whose header, length and chunks are consistent, and
#     an analysis that parses; uploads of the same file have equal stats;
#     every succeeded job serves all its frames, animation.glb, metrics.json
#     and a delta stream whose records all pass their CRC and count exactly
#     its frames; every served output carries the token of the attempt the
#     trace shows ended ok; and every served body equals, byte for byte, the
#     committed blob file it comes from. Failed and cancelled jobs serve
#     exactly the frames their last attempt published (frames_ready, with
#     that attempt's token) and no whole-sequence file;
#   - stray files a crash leaves (spooled uploads in DATA/tmp, blob-store
#     staging files `name#N`, blobs of trees that never got a row, attempt
#     directories other than the published one) are listed in strays.json
#     and the summary; orphan tree blobs must answer 404. None may be
#     served: no route reads DATA/tmp, staging names are no blob key, and
#     the byte-for-byte comparison above shows every served body is the
#     committed file;
#   - the last server stops cleanly on SIGTERM; integrity_check is `ok`
#     again; no job names a missing tree or keeps a lease; the database's
#     row counts equal the API's lists; the server log has no panic;
#   - coverage: at least 5 kills hit an upload in flight, at least 5 job
#     attempts were cut by a kill, at least 5 kills hit a render in flight
#     and at least 5 deletes racing a kill took effect.
# Prints a summary (kills, acknowledged jobs and uploads, final statuses).
#
# Environment: CRASH_SAFETY_SEED (repeat a run's random choices; the seed
# is printed first), TREEMORPH_BIN (use this binary instead of building;
# for iterating on the script).
# Needs (installs nothing itself): python3, and Rust as for scripts/test.
# Budget: about 1-2 minutes on 2 cores once the binary is built.
# Logs: $TREEMORPH_TEST_OUT/crash-safety (default
# target/test-artifacts/crash-safety): server.log (all starts), the helper's
# output, strays.json.
set -euo pipefail
cd "$(dirname "$0")/../.."

out=${TREEMORPH_TEST_OUT:-target/test-artifacts}/crash-safety
rm -rf "$out"
mkdir -p "$out"
out=$(cd "$out" && pwd)
work=$(mktemp -d)
helper_pid=""

cleanup() {
  status=$?
  if [ -n "$helper_pid" ]; then kill "$helper_pid" 2>/dev/null || true; wait "$helper_pid" 2>/dev/null || true; fi
  # A server left behind if the helper itself was killed.
  if [ -f "$out/server.pid" ]; then
    pid=$(cat "$out/server.pid")
    if grep -q treemorph "/proc/$pid/cmdline" 2>/dev/null; then kill -9 "$pid" 2>/dev/null || true; fi
  fi
  rm -rf "$work"
  if [ "$status" != 0 ]; then
    echo "crash-safety test FAILED; logs in $out" >&2
  fi
  exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

command -v python3 >/dev/null || { echo "python3 is missing" >&2; exit 1; }

if [ -n "${TREEMORPH_BIN:-}" ]; then
  bin=$TREEMORPH_BIN
else
  # The binary as scripts/test's other steps build it (whole workspace with
  # its tests: the same dependency features, so no second build).
  cargo test --workspace --locked --no-run
  bin=$(realpath -m "${CARGO_TARGET_DIR:-target}")/debug/treemorph
fi

seed_args=()
if [ -n "${CRASH_SAFETY_SEED:-}" ]; then seed_args=(--seed "$CRASH_SAFETY_SEED"); fi
python3 scripts/ci/crash_safety.py --bin "$bin" --work "$work" --out "$out" "${seed_args[@]}" \
  > >(tee "$out/helper.log") 2>&1 &
helper_pid=$!
wait "$helper_pid"
helper_pid=""
