#!/usr/bin/env bash
# Start-up with a large library (issue 18): writes the scale bench's stream-tree library of N
# transformations (default 10,000) as one Turtle file, loads it offline into a fresh store
# (`dyknow load`, validated and reasoned), then times `dyknow serve --model-only` on that store
# until `GET /environment` answers, RUNS times (default 3).
#   benches/startup.sh [N] [RUNS]
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/dyknow/target}"
n="${1:-10000}"
runs="${2:-3}"
cargo build --release --locked -p dyknow-server >&2
bin="$CARGO_TARGET_DIR/release/dyknow"
work="$(mktemp -d)"
trap 'kill "${pid:-0}" 2>/dev/null || true; rm -rf "$work"' EXIT
python3 - "$n" > "$work/library.ttl" <<'PY'
import sys
n = int(sys.argv[1])
print("@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .")
print("@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .")
for k in range(max(n // 2, 1)):
    for v, upkeep in (("a", "1.0"), ("b", "2.0")):
        port = "" if k == 0 else (
            ' dyknow:hasInPort [ a dyknow:InPort ; dyknow:hasName "in" ; '
            f'dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue "s{(k - 1) // 4}" ] ] ;')
        print(f'[] a dyknow:Transformation ; rdfs:label "p{k}{v}" ;{port} '
              'dyknow:hasOutPort [ a dyknow:OutPort ; dyknow:hasName "out" ; '
              f'dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue "s{k}" ] ] ; '
              'dyknow:hasCostModel [ a dyknow:LabourCostModel ; dyknow:hasValue 1.0 ] , '
              f'[ a dyknow:UpkeepCostModel ; dyknow:hasValue {upkeep} ] .')
PY
"$bin" load --data "$work/store" "$work/library.ttl"
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
for run in $(seq 1 "$runs"); do
  start=$(date +%s%N)
  "$bin" serve --data "$work/store" --model-only --bind "127.0.0.1:$port" > "$work/serve.log" 2>&1 &
  pid=$!
  until curl -sf -o /dev/null "http://127.0.0.1:$port/environment"; do
    kill -0 "$pid" 2>/dev/null || { cat "$work/serve.log" >&2; exit 1; }
    sleep 0.02
  done
  end=$(date +%s%N)
  echo "run $run: $n transformations, listening and answering after $(( (end - start) / 1000000 )) ms"
  kill "$pid"; wait "$pid" 2>/dev/null || true
done
