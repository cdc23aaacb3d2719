# Shell helpers for scripts/test's steps (sourced; tested by
# tests/it/scripts.rs).

# quietly CMD [ARG...]: runs CMD with its stderr (the command line's
# progress lines) held back. When CMD fails, prints the command, its exit
# status and that stderr, and fails with the same status; a CI log then
# says why a step stopped.
quietly() {
  local log status=0
  log=$(mktemp)
  "$@" 2>"$log" || status=$?
  if [ "$status" -ne 0 ]; then
    printf 'failed with exit status %s: %s\n' "$status" "$*" >&2
    cat "$log" >&2
  fi
  rm -f "$log"
  return "$status"
}

# cpu_idle_percent: the share (0-100) of the machine's CPU time that was
# idle over the next second, from /proc/stat.
cpu_idle_percent() {
  local a b total=0 i
  read -r -a a </proc/stat
  sleep 1
  read -r -a b </proc/stat
  # cpu user nice system idle iowait irq softirq steal
  for i in 1 2 3 4 5 6 7 8; do
    total=$((total + ${b[i]:-0} - ${a[i]:-0}))
  done
  echo $((total > 0 ? 100 * (b[4] - a[4]) / total : 100))
}

# wait_until_idle [SECONDS]: waits, up to SECONDS (default 60), until the
# CPUs were at least 80 % idle over one second, and says what it saw. A
# latency measurement that starts while a previous step's processes wind
# down measures them: the slow-client check once failed at a p99 that
# rose run by run (p50 1.2 -> 3.8 ms) right after the fuzz step, and
# passed at 1.4x its baseline when run again alone. Never fails: judging
# a busy machine is the measurement's job.
wait_until_idle() {
  local limit=${1:-60} waited=0 idle
  while :; do
    idle=$(cpu_idle_percent)
    [ "$idle" -ge 80 ] || [ "$waited" -ge "$limit" ] && break
    waited=$((waited + 1))
  done
  echo "CPU ${idle}% idle (waited ${waited} s for at least 80 %)"
}
