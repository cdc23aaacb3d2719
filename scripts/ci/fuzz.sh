#!/usr/bin/env bash
# Fuzzing (hardening issue): every cargo-fuzz target in fuzz/ runs for
# SECONDS (default 30) from its committed corpus.
#
#   scripts/ci/fuzz.sh [SECONDS] [TARGET...]
#
# The committed corpus (fuzz/corpus/TARGET) is read, never written: new
# inputs go to a scratch directory, so a CI run leaves the tree clean. A
# crash fails the script and leaves the input in fuzz/artifacts/TARGET;
# every crash becomes a regression test (the importer's in
# crates/import/tests/fuzz/, the parsers' in their crates' tests) and its
# input joins the corpus.
#
# Needs (installs nothing itself; scripts/setup installs it): cargo-fuzz.
# libFuzzer's instrumentation needs nightly flags: RUSTC_BOOTSTRAP=1 lets
# the stable toolchain accept them. The sanitizer is off: the workspace
# forbids `unsafe`, so AddressSanitizer would slow every run for bugs safe
# Rust cannot have; panics, overflow checks and debug assertions (on in
# cargo-fuzz's default build) are what the fuzzers look for, plus
# libFuzzer's own -rss_limit_mb (memory blow-ups) and -timeout (hangs).
# Logs: $TREEMORPH_TEST_OUT/fuzz (default target/test-artifacts/fuzz).
set -euo pipefail
cd "$(dirname "$0")/../.."

seconds=${1:-30}
shift || true
export RUSTC_BOOTSTRAP=1
out=${TREEMORPH_TEST_OUT:-target/test-artifacts}/fuzz
rm -rf "$out"
mkdir -p "$out"
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT

fuzz=(cargo fuzz)
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  mapfile -t targets < <("${fuzz[@]}" list --fuzz-dir fuzz)
fi

"${fuzz[@]}" build --fuzz-dir fuzz --sanitizer none

summary=()
status=0
for target in "${targets[@]}"; do
  mkdir -p "$scratch/$target" "fuzz/artifacts/$target"
  log="$out/$target.log"
  printf '==> fuzz %s (%ss)\n' "$target" "$seconds"
  if "${fuzz[@]}" run --fuzz-dir fuzz --sanitizer none "$target" \
      "$scratch/$target" "fuzz/corpus/$target" -- \
      -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 \
      -print_final_stats=1 >"$log" 2>&1; then
    runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -n 1)
    new=$(find "$scratch/$target" -type f | wc -l)
    summary+=("$(printf '%-16s ok     %10s runs  %5s new corpus inputs' "$target" "${runs:-?}" "$new")")
  else
    status=1
    summary+=("$(printf '%-16s FAILED (log: %s)' "$target" "$log")")
    grep -E 'panicked|ERROR|SUMMARY|Test unit written' "$log" | head -n 20 >&2 || true
  fi
done

printf '\n%s\n' "${summary[@]}"
exit "$status"
