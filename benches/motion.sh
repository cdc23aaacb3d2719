#!/usr/bin/env bash
# How morphs move, per schedule: for each pair of trees and each schedule
# one row of the job's metrics.json figures, measured on the frames it
# writes:
#   pair schedule matching jump_ratio max_jump out_of_order reversals
#   coincident crossings floating_leaves floating_branches
# jump_ratio is the largest per-frame move of a node or leaf corner over
# the median one; out_of_order the most chains in one frame not growing
# from the tip; reversals the most growing chains that shrank (wilting
# ones that grew); coincident the most visible leaves in one frame drawn on
# top of another with a different material pair (z-fighting copies);
# crossings the most pairs of branch tubes in one frame passing through
# each other that touch at neither end; siblings the most of those in one
# frame between limbs of one parent, and sibling_% that count as a
# percentage of all pairs of limbs on one parent; floating the most in one frame, by the output-level check on the delta
# stream's meshes.
#
# Usage: benches/motion.sh [TREE...]   With no trees, five preset pairs
# at SIZE branches (default 5000); with trees (GLB, glTF or JSON), every
# tree into the next one, the last into the first. Environment: FRAMES
# (default 60), SCHEDULES (default "linear staged"), MATCHINGS (default
# "one-to-many one-to-one"), TREEMORPH_BIN (a binary to use instead of
# building the release one).
set -euo pipefail
cd "$(dirname "$0")/.."
SIZE=${SIZE:-5000}
FRAMES=${FRAMES:-60}
SCHEDULES=${SCHEDULES:-linear staged}
MATCHINGS=${MATCHINGS:-one-to-many one-to-one}
. benches/bin.sh
DIR=$(mktemp -d)
trap 'rm -rf "$DIR"' EXIT
trees=("$@")
if [ ${#trees[@]} -eq 0 ]; then
  for p in maple:1 conifer:2 willow:3 eucalyptus:4 shrub:5; do
    "$BIN" generate --preset "${p%%:*}" --seed "${p##*:}" --size "$SIZE" \
      -o "$DIR/${p%%:*}.json" >/dev/null 2>&1
    trees+=("$DIR/${p%%:*}.json")
  done
fi
figures() {
  python3 - "$1" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))
top = lambda k: max(m[k])
print("%10.2f %8.4f %12d %9d %10d %9d %9d %9.4f %8d %8d" % (m["jump_ratio"], top("max_jump"),
      top("growth_out_of_order"), top("growth_reversals"), top("coincident_leaves"),
      top("crossings"), top("sibling_crossings"), 100 * m["sibling_crossing_share"],
      top("floating_leaves"), top("floating_branches")))
PY
}
printf '%-28s %-8s %-11s %10s %8s %12s %9s %10s %9s %9s %9s %8s %8s\n' pair schedule matching \
  jump_ratio max_jump out_of_order reversals coincident crossings siblings sibling_% f_leaves f_branch
n=${#trees[@]}
for ((i = 0; i < n; i++)); do
  a=${trees[$i]} b=${trees[$(((i + 1) % n))]}
  pair="$(basename "${a%.*}")>$(basename "${b%.*}")"
  for matching in $MATCHINGS; do
    for schedule in $SCHEDULES; do
      out=$DIR/run
      rm -rf "$out"
      if "$BIN" morph "$a" "$b" --frames "$FRAMES" --format delta --schedule "$schedule" \
        --matching "$matching" -o "$out" >"$DIR/log" 2>&1; then
        printf '%-28s %-8s %-11s %s\n' "$pair" "$schedule" "$matching" "$(figures "$out/metrics.json")"
      else
        printf '%-28s %-8s %-11s failed: %s\n' "$pair" "$schedule" "$matching" "$(tail -1 "$DIR/log")"
      fi
    done
  done
done
