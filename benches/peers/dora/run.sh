#!/usr/bin/env bash
# Latency through a linear chain of n dora relay nodes (one process each), the dora peer of
# `cargo bench -p dyknow-executor --bench chain` (see README.md).
#   benches/peers/dora/run.sh [--messages N] [--rate HZ] [--hops 1,10,25,50]
# Uses dora-rs-cli 1.1.0 from benches/.venv-dora (created on first use) and `dora run`
# (coordinator and daemon in the one CLI process, on 127.0.0.1, gone when it returns).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
venv="$here/../../.venv-dora"
messages=1000 rate=0 hops=1,10,25,50
while [ $# -gt 0 ]; do
  case "$1" in
    --messages) messages="$2"; shift 2 ;;
    --rate) rate="$2"; shift 2 ;;
    --hops) hops="$2"; shift 2 ;;
    *) echo "usage: $0 [--messages N] [--rate HZ] [--hops 1,10,25,50]" >&2; exit 2 ;;
  esac
done

if ! "$venv/bin/dora" --version >/dev/null 2>&1; then
  [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
  "$venv/bin/pip" install -q dora-rs-cli==1.1.0
fi
dora="$venv/bin/dora"
# Its own target directory (not DyKnow's, which `benches/run.sh` exports as CARGO_TARGET_DIR).
target="${DORA_TARGET_DIR:-$HOME/.cache/dyknow/dora-target}"
CARGO_TARGET_DIR="$target" cargo build --release --locked --quiet --manifest-path "$here/Cargo.toml"
bin="$target/release"

tmp="$(mktemp -d)"
pid=""
# Every process under `dora run` (the CLI, which is coordinator and daemon, and its nodes).
tree() { local c; for c in $(pgrep -P "$1" || true); do tree "$c"; done; echo "$1"; }
cleanup() {
  if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
    local pids
    pids="$(tree "$pid")"
    kill -INT "$pid" 2>/dev/null || true
    sleep 3
    # shellcheck disable=SC2086
    kill -KILL $pids 2>/dev/null || true
  fi
  rm -rf "$tmp"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# Stay on loopback: no multicast scouting (the daemon wires every node link explicitly).
export DORA_ZENOH_MULTICAST=off

echo "$("$dora" --version): chain of n relays, $messages messages $(
  [ "$rate" = 0 ] && echo "back to back" || echo "at $rate Hz"), after 50 to warm up; latency source → sink in µs"
printf '%-20s %4s %10s %10s %10s %12s\n' variant n mean p50 p99 p50-per-hop
for n in ${hops//,/ }; do
  yaml="$tmp/chain-$n.yml"
  {
    echo "nodes:"
    echo "  - id: bench"
    echo "    path: $bin/bench"
    echo "    inputs: { in: relay$((n - 1))/out }"
    echo "    outputs: [out]"
    echo "    env: { MESSAGES: \"$messages\", RATE: \"$rate\", HOPS: \"$n\", RESULT_FILE: \"$tmp/result-$n\" }"
    for ((i = 0; i < n; i++)); do
      echo "  - id: relay$i"
      echo "    path: $bin/relay"
      echo "    inputs: { in: $([ "$i" = 0 ] && echo bench || echo "relay$((i - 1))")/out }"
      echo "    outputs: [out]"
    done
  } >"$yaml"
  # A generous bound: 10 min plus the paced time.
  limit=$(awk -v m="$messages" -v r="$rate" 'BEGIN { print int(600 + (r > 0 ? m / r : 0)) }')
  before="$(cut -d' ' -f1-3 /proc/loadavg)"
  timeout -s INT -k 20 "$limit" "$dora" run "$yaml" >"$tmp/log-$n" 2>&1 &
  pid=$!
  status=0
  wait "$pid" || status=$?
  pid=""
  after="$(cut -d' ' -f1-3 /proc/loadavg)"
  if [ "$status" != 0 ] || [ ! -s "$tmp/result-$n" ]; then
    echo "n=$n failed (exit $status):" >&2
    tail -n 30 "$tmp/log-$n" >&2
    exit 1
  fi
  # n=<n> mean=<µs> p50=<µs> p99=<µs>
  awk -v n="$n" '{
    for (i = 1; i <= NF; i++) { split($i, kv, "="); v[kv[1]] = kv[2] }
    printf "%-20s %4d %10.1f %10.1f %10.1f %12.1f\n", "dora (process/hop)", n, v["mean"], v["p50"], v["p99"], v["p50"] / n
  }' "$tmp/result-$n"
  # dora sends an output over direct Zenoh (node to node) once a startup handshake proved its
  # route, else through the daemon for the whole run: say so if any hop took the daemon path.
  slow=$(grep -ac 'stays on the reliable daemon path' "$tmp/log-$n" || true)
  echo "# n=$n: $slow outputs on the daemon path; loadavg before $before, after $after" >&2
done
