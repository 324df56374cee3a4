#!/usr/bin/env bash
# Load test: `tessera serve` on loopback and `tessera loadtest` against it (docs/loadtest.md):
# N = 1, 16, 64 viewers, then a ramp for the most viewers holding p99 tile latency <= 16 ms and
# fallback <= 0.1%. Both processes share this machine: late/skipped frames say when the load
# generator could not keep up. Writes tables, JSON and SVG plots to WORKDIR.
#
#   bench/loadtest.sh [WORKDIR] [EXTRA LOADTEST FLAGS...]     default WORKDIR: /tmp/tessera-loadtest
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-/tmp/tessera-loadtest}
shift || true
tessera=${TESSERA:-build/tessera}
[ -x "$tessera" ] || { echo "build first: tools/setup.sh" >&2; exit 1; }
mkdir -p "$work"
store="$work/terrain.tsr"
[ -f "$store" ] || "$tessera" build procedural:terrain:16384 -o "$store" --quiet
port=$((20000 + RANDOM % 20000))
"$tessera" serve --store "$store" --grpc "127.0.0.1:$port" --http "" > "$work/serve.log" 2>&1 &
server=$!
trap 'kill $server 2>/dev/null || true' EXIT
for _ in $(seq 1 100); do grep -q '"msg":"listening"' "$work/serve.log" && break; sleep 0.1; done
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs); commit $(git rev-parse --short HEAD)"
"$tessera" loadtest --server "127.0.0.1:$port" --server-pid "$server" --store terrain --viewers 1,16,64 \
  --json "$work/viewers.json" --plot "$work/viewers.svg" --quiet "$@"
"$tessera" loadtest --server "127.0.0.1:$port" --server-pid "$server" --store terrain --ramp --max-viewers 64 \
  --json "$work/ramp.json" --plot "$work/ramp.svg" --quiet "$@"
