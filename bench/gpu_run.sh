#!/usr/bin/env bash
# Every GPU measurement in one run, for a lent GPU machine, in under 8 minutes (docs/benchmarks.md,
# "On a GPU"): the VT frame against plain texturing at 1920x1080 and 640x360 for each filter (wall,
# CPU and GPU-timer medians, with every page fading as the worst case), and the smallest BC1 pool
# that holds flyover at 1920x1080 (bytes per screen pixel). Hardware sparse textures are not built
# yet: the run says so rather than skipping silently.
#
# Uses build/tessera and build/bench/vt_vs_plain when they are there (built on another machine
# and carried over), else builds just those two once with every core. Writes OUT (default
# /tmp/tessera-gpu): gpu_run.md (date, commit, GPU, driver, GL renderer, every table, the time
# each step took) and the raw outputs beside it. Exit status: non-zero when a step fails.
#
#   bench/gpu_run.sh [OUT] [--quick]   --quick: tiny sizes and few frames, to check the script
#                                      itself on llvmpipe (its numbers mean nothing)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-/tmp/tessera-gpu}
quick=0
[ "${2:-}" = --quick ] && quick=1
mkdir -p "$out"
report="$out/gpu_run.md"
: > "$report"
start=$(date +%s)
say() { echo "$*" | tee -a "$report"; }
step() { say ""; say "## $1 (at $(( $(date +%s) - start )) s)"; }

say "# GPU run $(date -u +%Y-%m-%dT%H:%M:%SZ)"
say "- commit: $(git rev-parse --short HEAD 2>/dev/null || echo 'unknown (no .git here)')"
if command -v nvidia-smi > /dev/null; then
  say "- GPU: $(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | head -1)"
else
  say "- GPU: no nvidia-smi on this machine"
fi
say "- CPU: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"

step "Binaries"
if [ -x build/tessera ] && [ -x build/bench/vt_vs_plain ]; then
  say "using build/tessera and build/bench/vt_vs_plain as found"
else
  say "building tessera and vt_vs_plain with $(nproc) jobs"
  cmake -S . -B build -G Ninja -DTESSERA_FUZZ=OFF -DTESSERA_BUILD_TESTS=OFF > "$out/cmake.log" 2>&1
  ninja -C build -j "$(nproc)" tessera vt_vs_plain > "$out/build.log" 2>&1
fi
tessera=build/tessera

step "Stores"
small=4096; large=16384; frames=240; sizes="1920x1080 640x360"; pool_path_size=1920x1080
if [ $quick = 1 ]; then small=1024; large=2048; frames=12; sizes="320x180"; pool_path_size=320x180; fi
store="$out/terrain$small.tsr"
[ -f "$store" ] || "$tessera" build "procedural:terrain:$small" -o "$store" --quiet
say "built $store"

step "VT against plain texturing (bench/vt_vs_plain, flyover, $frames frames, --fade-ms 250)"
for size in $sizes; do
  build/bench/vt_vs_plain "$store" --size "$size" --frames "$frames" --fade-ms 250 \
    --json "$out/vt_vs_plain_$size.json" | tee "$out/vt_vs_plain_$size.txt"
  { echo '```'; cat "$out/vt_vs_plain_$size.txt"; echo '```'; } >> "$report"
done

step "Smallest BC1 pool for flyover at $pool_path_size (bench/pool_floor.py)"
lo=32; hi=512
[ $quick = 1 ] && lo=16 && hi=64
python3 bench/pool_floor.py --tessera "$tessera" --paths flyover --sizes "$pool_path_size" --formats bc1 --tiles 256 \
  --texels "$large" --lo "$lo" --hi "$hi" --work "$out/pool-floor" | tee "$out/pool_floor.txt"
cat "$out/pool_floor.txt" >> "$report"

step "Hardware sparse textures"
say "not built yet: there is no --page-table sparse backend to measure (docs/benchmarks.md)."

say ""
say "done in $(( $(date +%s) - start )) s"
