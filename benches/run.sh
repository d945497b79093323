#!/usr/bin/env bash
# Runs DyKnow's benchmarks with their peers side by side (docs/benchmarks.md).
#   benches/run.sh             every benchmark
#   benches/run.sh knowledge   the knowledge service (ingestion, SPARQL) against `oxigraph serve`; the SPARQL guard's cost; the counting allocator's
#   benches/run.sh reasoning   the reasoner against owlrl and reasonable
#   benches/run.sh engine      EXPLORE and reviews (Chapter 6 crash, generated environments against an exact MILP peer (HiGHS); eight seeds of each)
#   benches/run.sh mstl        MSTL progression (Figures 3.6, 3.7) against reelay and mstlo
#   benches/run.sh rcc8        RCC-8 closure (Figures 3.10, 3.11) against PyRCC8; landmarks (Figures 3.8, 3.9)
#   benches/run.sh groups      a formula group of 1,000 formulas over 100 live channels at 100 Hz (issue 15)
#   benches/run.sh ui          the web view with 500 running CUs in headless chromium (issue 16)
#   benches/run.sh dataplane   chains of relay CUs (Figure 5.5) against plain Zenoh and dora; crash recovery; timers
#   benches/run.sh load        64 HTTP clients for 10 minutes with Chapter 6 running; SPARQL against `oxigraph serve`
#   benches/run.sh scale       libraries of 100 to 10,000 transformations, 1 and 50 targets: spec change to change set, GET /cus, start-up (issue 18)
#   benches/run.sh startup     start-up on a store of 10,000 specs loaded offline (benches/startup.sh)
# The peers come from PyPI into benches/.venv (created on first use).
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/dyknow/target}"
venv=benches/.venv
if [ ! -x "$venv/bin/oxigraph" ] || [ ! -d "$venv/lib" ] || ! "$venv/bin/python" -c 'import owlrl, reasonable, reelay, mstlo_python, ortools, highspy' 2>/dev/null; then
  [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
  "$venv/bin/pip" install -q oxigraph==0.5.13 owlrl==7.6.2 reasonable==0.4.4 reelay==25.0.0 mstlo-python==0.2.2 ortools==9.15.6755 highspy==1.16.0
fi
# PyRCC8 1.2.2 is on PyPI only as a Python 2 source archive: benches/peers/install_pyrcc8.py
# fetches it (pinned sha256), ports it with lib2to3 and installs it (nothing if present).
"$venv/bin/python" -c 'import pyrcc8' 2>/dev/null || "$venv/bin/python" benches/peers/install_pyrcc8.py
# GQR, if benches/peers/build_gqr.sh built it from a checkout (GQR_SRC=...): the RCC-8 bench
# then runs it side by side too.
if [ -x benches/.gqr/gqr ]; then
  export GQR_BIN="$PWD/benches/.gqr/gqr" GQR_DATA_DIR="$PWD/benches/.gqr/src/data"
elif [ -n "${GQR_SRC:-}" ]; then
  benches/peers/build_gqr.sh
  export GQR_BIN="$PWD/benches/.gqr/gqr" GQR_DATA_DIR="$PWD/benches/.gqr/src/data"
fi
export OXIGRAPH_BIN="$PWD/$venv/bin/oxigraph"
export PEER_PYTHON="$PWD/$venv/bin/python"
which="${1:-all}"
# The benches that measure the service against a peer's release binary measure ours built the
# same way (profile `dist`: LTO, one codegen unit, as Oxigraph's release is built).
dist_binary() {
  cargo build --locked --profile dist -p dyknow-server --bin dyknow
  export DYKNOW_BIN="$CARGO_TARGET_DIR/dist/dyknow"
}
case "$which" in all|knowledge|load) dist_binary ;; esac
if [ "$which" = all ] || [ "$which" = knowledge ]; then
  cargo bench --locked --workspace --bench knowledge_service
  # The cost of the SPARQL cancellation guard, in process (no peer: oxigraph's own evaluator).
  cargo bench --locked --workspace --bench sparql_guard
  # The cost of counting what each thread holds (the binary's allocator, `--query-memory`).
  cargo bench --locked --workspace --bench counting
fi
if [ "$which" = all ] || [ "$which" = reasoning ]; then
  cargo bench --locked --workspace --bench reasoning
fi
if [ "$which" = all ] || [ "$which" = mstl ]; then
  cargo bench --locked --workspace --bench progression
fi
if [ "$which" = all ] || [ "$which" = rcc8 ]; then
  cargo bench --locked --workspace --bench closure
  cargo bench --locked --workspace --bench landmarks
fi
if [ "$which" = all ] || [ "$which" = engine ]; then
  cargo bench --locked --workspace --bench explore
  # Issue 18's any-time and proof bars over eight generated instances of each size, against
  # benches/explore-best-known.csv (the MILP peer's proven optima and bounds), with the LP
  # bound of 200 x 10 and the MILP peer beside each instance for 10 s (its 200 x 10 proofs).
  EXPLORE_SEEDS=0-7 EXPLORE_PEER=milp EXPLORE_PEER_SECONDS=10 cargo bench --locked --workspace --bench explore
  cargo bench --locked --workspace --bench reconfig_http
fi
if [ "$which" = all ] || [ "$which" = groups ]; then
  cargo bench --locked --workspace --bench groups -- --seconds 180
fi
if [ "$which" = all ] || [ "$which" = ui ]; then
  cargo bench --locked --workspace --bench ui -- --chains 50 --seconds 30
fi
if [ "$which" = all ] || [ "$which" = dataplane ]; then
  cargo bench --locked --workspace --bench chain -- --messages 1000
  # The dora peer (a standalone Cargo project; its own venv and target directory).
  benches/peers/dora/run.sh --messages 1000
  cargo bench --locked --workspace --bench chain -- --messages 1000 --rate 5 --idle-cus 0
  benches/peers/dora/run.sh --messages 1000 --rate 5
  cargo bench --locked --workspace --bench recovery
  cargo bench --locked --workspace --bench timers
fi
if [ "$which" = all ] || [ "$which" = load ]; then
  cargo bench --locked --workspace --bench load -- --secs 600 --clients 64
fi
if [ "$which" = all ] || [ "$which" = scale ]; then
  cargo bench --locked --workspace --bench scale
fi
if [ "$which" = all ] || [ "$which" = startup ]; then
  benches/startup.sh 10000 3
fi
