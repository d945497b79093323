#!/usr/bin/env bash
# Runs DyKnow's benchmarks with their peers side by side (docs/benchmarks.md).
# The peers come from PyPI into benches/.venv (created on first use).
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/dyknow/target}"
venv=benches/.venv
if [ ! -x "$venv/bin/oxigraph" ]; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install -q oxigraph==0.5.13
fi
export OXIGRAPH_BIN="$PWD/$venv/bin/oxigraph"
cargo bench --locked -p dyknow-server --bench knowledge_service "$@"
