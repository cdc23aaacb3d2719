#!/usr/bin/env bash
# The animated GLB of a morph, both kinds and every encoding, as the CLI
# writes it and as three.js loads it. Prints one row per file:
#   kind encoding bytes targets max_error write_s load_ms gpu_mb
# (targets and max_error from metrics.json, basis and skinned; write_s is the
# whole `treemorph morph --format animated` run; load_ms and gpu_mb from
# tools/render/check-animated.mjs: GLTFLoader in headless Chromium, and
# every buffer attribute plus one float morph texture per geometry).
#
# Usage: benches/animation.sh        Environment: SIZE (branches, default
# 5000), FRAMES (default 60), KINDS (default "keyframes basis skinned"), ENCODINGS
# (default "float quantized meshopt"), TREEMORPH_BIN (a binary to use
# instead of building the release one). Needs `npm ci --prefix tools/render`
# and Chromium.
set -euo pipefail
cd "$(dirname "$0")/.."
SIZE=${SIZE:-5000}
FRAMES=${FRAMES:-60}
KINDS=${KINDS:-keyframes basis skinned}
ENCODINGS=${ENCODINGS:-float quantized meshopt}
. benches/bin.sh
DIR=$(mktemp -d)
trap 'rm -rf "$DIR"' EXIT
"$BIN" generate --preset maple --seed 1 --size "$SIZE" -o "$DIR/a.json" >/dev/null 2>&1
"$BIN" generate --preset conifer --seed 2 --size "$SIZE" -o "$DIR/b.json" >/dev/null 2>&1
echo '{"tolerance": 1, "meshes": []}' >"$DIR/none.json"
field() { sed -n "s/.*\"$1\": *\([0-9.e-]*\).*/\1/p" "$2" | head -1; }
printf '%-9s %-9s %12s %7s %9s %7s %7s %7s\n' kind encoding bytes targets max_error write_s load_ms gpu_mb
for kind in $KINDS; do
  for enc in $ENCODINGS; do
    out=$DIR/$kind-$enc
    start=$(date +%s.%N)
    "$BIN" morph "$DIR/a.json" "$DIR/b.json" --frames "$FRAMES" --format animated \
      --animation "$kind" --animation-encoding "$enc" -o "$out" >/dev/null 2>&1
    end=$(date +%s.%N)
    glb=$out/animation.glb
    line=$(node tools/render/check-animated.mjs "$glb" "$DIR/none.json" | head -1)
    load=$(sed -n 's/.*loaded in \([0-9]*\) ms.*/\1/p' <<<"$line")
    gpu=$(sed -n 's/.*GPU estimate \([0-9.]*\) MB.*/\1/p' <<<"$line")
    printf '%-9s %-9s %12s %7s %9s %7.2f %7s %7s\n' "$kind" "$enc" "$(stat -c %s "$glb")" \
      "$(field animation_targets "$out/metrics.json")" "$(field animation_max_error "$out/metrics.json" | cut -c1-7)" \
      "$(echo "$end - $start" | bc)" "$load" "$gpu"
    rm -rf "$out"
  done
done
