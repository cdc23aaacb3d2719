#!/usr/bin/env bash
# Scale-out test (issue 10): starts PostgreSQL 15 and an S3 server (moto) on
# loopback, then runs the tests that need them:
#   - the queue's PostgreSQL twins and concurrent migrations (src/jobs,
#     src/store),
#   - S3 blobs against moto (src/store/blobs.rs),
#   - an API process and a worker process sharing PostgreSQL
#     (tests/it/scaleout.rs),
#   - the fleet (tests/it/fleet.rs): 2 API + 3 worker processes of the real
#     binary, 200 jobs, a random worker kill -9'd and restarted 10 times;
#     every job must end terminal, no attempt may run twice at once, and
#     nothing from a superseded attempt may be served.
#
# Needs (installs nothing itself; .ci/run installs them):
#   Debian: postgresql-15   (apt-get install -y postgresql-15)
#   PyPI:   moto[server]    (pip install 'moto[server]')
#   python3, and Rust as for scripts/test.
# Budget: about 1-2 minutes on 2 cores once `cargo test --workspace` has
# built the test binaries (this uses the same build).
# Logs: $TREEMORPH_TEST_OUT/scaleout (default target/test-artifacts/scaleout).
set -euo pipefail
cd "$(dirname "$0")/../.."
. scripts/ci/services.sh

out=${TREEMORPH_TEST_OUT:-target/test-artifacts}/scaleout
rm -rf "$out"
mkdir -p "$out"
out=$(cd "$out" && pwd)
work=$(mktemp -d)

cleanup() {
  status=$?
  # Fleet processes left behind if the test itself was killed.
  for f in "$out"/fleet/logs/*.pid; do
    [ -f "$f" ] || continue
    pid=$(cat "$f")
    if grep -q treemorph "/proc/$pid/cmdline" 2>/dev/null; then kill -9 "$pid" 2>/dev/null || true; fi
  done
  services_stop
  rm -rf "$work"
  if [ "$status" != 0 ]; then
    echo "scale-out test FAILED; logs in $out" >&2
  fi
  exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

services_start "$work" "$out"
export TREEMORPH_SCALEOUT_OUT="$out/fleet"

# The ignored tests that need these servers, by name (other ignored tests —
# timings, corpus writers — stay ignored).
cargo test --workspace --locked --lib --tests -- --ignored \
  --nocapture postgres s3_blobs fleet:: 2>&1 | tee "$out/cargo-test.log"
