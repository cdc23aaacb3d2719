#!/usr/bin/env bash
# Fuzzing (hardening issue): every cargo-fuzz target in fuzz/ runs for
# SECONDS (default 30) from its committed corpus.
#
#   scripts/ci/fuzz.sh [SECONDS] [TARGET...]
#   scripts/ci/fuzz.sh --build-only      (the build alone: scripts/test runs
#                                         it in the background beforehand)
#
# All targets build in one `cargo fuzz build`; then the targets run
# TREEMORPH_FUZZ_JOBS at a time (default: one per core, `nproc`). libFuzzer
# runs one process per target on one core, so on 2 cores two targets run
# side by side, each for its own seconds, longest first.
#
# TREEMORPH_FUZZ_TARGET_SECONDS="TARGET=SECONDS ..." gives some targets
# another time than SECONDS (CI: the importer, where fuzzing has found
# bugs and which runs some 20 times fewer inputs a second than the JSON
# parsers, gets twice the others' time: .ci/run).
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

build_only=false
if [ "${1:-}" = --build-only ]; then
  build_only=true
  shift
fi
seconds=${1:-30}
shift || true
export RUSTC_BOOTSTRAP=1
out=${TREEMORPH_TEST_OUT:-target/test-artifacts}/fuzz
rm -rf "$out"
mkdir -p "$out"
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT

fuzz=(cargo fuzz)
# TREEMORPH_FUZZ_OPT_LEVEL (default: the fuzz workspace's release profile,
# opt-level 3) sets the optimisation of every crate the targets build;
# `run` builds with the same environment, so it reuses `build`'s output.
# CI's short runs use 1 (.ci/run): the instrumented build of the whole
# stack took 4 m 51 s against 5 m 43 s at 3, for fewer inputs a second.
if [ -n "${TREEMORPH_FUZZ_OPT_LEVEL:-}" ]; then
  export CARGO_PROFILE_RELEASE_OPT_LEVEL=$TREEMORPH_FUZZ_OPT_LEVEL
fi
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  mapfile -t targets < <("${fuzz[@]}" list --fuzz-dir fuzz)
fi

"${fuzz[@]}" build --fuzz-dir fuzz --sanitizer none
if $build_only; then
  exit 0
fi

jobs=${TREEMORPH_FUZZ_JOBS:-$(nproc)}
[ "$jobs" -ge 1 ] 2>/dev/null || jobs=1

# One target: its status (ok/FAILED) goes to $scratch/$target.status.
fuzz_one() {
  local target=$1 secs=$2 log="$out/$1.log"
  mkdir -p "$scratch/$target" "fuzz/artifacts/$target"
  if "${fuzz[@]}" run --fuzz-dir fuzz --sanitizer none "$target" \
      "$scratch/$target" "fuzz/corpus/$target" -- \
      -max_total_time="$secs" -rss_limit_mb=2048 -timeout=10 \
      -print_final_stats=1 >"$log" 2>&1; then
    echo ok > "$scratch/$target.status"
  else
    echo FAILED > "$scratch/$target.status"
  fi
}

# Seconds per target, and the order to start them: longest first.
declare -A secs=()
for target in "${targets[@]}"; do secs[$target]=$seconds; done
for pair in ${TREEMORPH_FUZZ_TARGET_SECONDS:-}; do
  if [ -n "${secs[${pair%%=*}]:-}" ]; then secs[${pair%%=*}]=${pair#*=}; fi
done
mapfile -t order < <(for t in "${targets[@]}"; do echo "${secs[$t]} $t"; done | sort -s -k1,1nr | cut -d' ' -f2)

running=0
for target in "${order[@]}"; do
  if [ "$running" -ge "$jobs" ]; then
    wait -n || true
    running=$((running - 1))
  fi
  printf '==> fuzz %s (%ss)\n' "$target" "${secs[$target]}"
  fuzz_one "$target" "${secs[$target]}" &
  running=$((running + 1))
done
wait

summary=()
status=0
for target in "${targets[@]}"; do
  log="$out/$target.log"
  if [ "$(cat "$scratch/$target.status" 2>/dev/null)" = ok ]; then
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
