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
