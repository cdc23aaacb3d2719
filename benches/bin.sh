# Sourced by the bench scripts from the repository root: sets BIN to
# $TREEMORPH_BIN when given, else builds the release binary and uses it.
if [ -n "${TREEMORPH_BIN:-}" ]; then
  BIN=$TREEMORPH_BIN
else
  cargo build --release -p treemorph --bin treemorph >&2
  BIN=$PWD/target/release/treemorph
fi
