#!/usr/bin/env bash
# Build benchmark: `tessera build` against `vips dzsave` on the same source, tile size, overlap
# and JPEG quality, interleaved in one run (the machine is shared and noisy: compare ratios,
# not absolute times). Prints a table and writes JSON.
#
#   bench/build_vs_vips.sh [SIZE] [REPS] [WORKDIR]     defaults: 16384 3 /tmp/tessera-bench
set -euo pipefail
cd "$(dirname "$0")/.."
size=${1:-16384}
reps=${2:-3}
work=${3:-/tmp/tessera-bench}
tessera=${TESSERA:-build/tessera}
[ -x "$tessera" ] || { echo "build first: tools/setup.sh" >&2; exit 1; }
command -v vips >/dev/null || { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libvips-tools >/dev/null; }
command -v /usr/bin/time >/dev/null || { apt-get update -qq && apt-get install -y -qq time >/dev/null; }
mkdir -p "$work"
src="$work/terrain-$size.tif"
[ -f "$src" ] || "$tessera" source "procedural:terrain:$size" -o "$src" -q

tile=256 border=4 quality=90
payload=$((tile - 2 * border))
results="$work/results.txt"
: > "$results"
measure() {  # name, command...
  local name=$1; shift
  local t; t=$(mktemp)
  /usr/bin/time -f "%e %M" -o "$t" "$@" >/dev/null 2>&1
  read -r secs kb < "$t"; rm -f "$t"
  echo "$name $secs $kb" >> "$results"
  echo "  $name: ${secs}s, peak RSS $((kb / 1024)) MiB"
}
# One untimed pass each to bring the source into the page cache for both.
cat "$src" > /dev/null
for r in $(seq 1 "$reps"); do
  echo "round $r/$reps"
  rm -rf "$work/out.tsr" "$work/dz" "$work/dz_files" "$work/dz.dzi"
  measure tessera "$tessera" build "$src" -o "$work/out.tsr" --tile-size $tile --border $border --codec jpeg \
    --quality $quality --chroma 444 --quiet
  measure vips vips dzsave "$src" "$work/dz" --tile-size $payload --overlap $border --depth onetile \
    --suffix ".jpg[Q=$quality,subsample_mode=off]"
done
tsr_bytes=$(stat -c %s "$work/out.tsr")
dz_bytes=$(du -sb "$work/dz_files" | cut -f1)
dz_tiles=$(find "$work/dz_files" -type f | wc -l)
python3 - "$results" "$size" "$tsr_bytes" "$dz_bytes" "$dz_tiles" "$(git rev-parse --short HEAD)" <<'PY'
import json, statistics, sys, platform, os
path, size, tsr_bytes, dz_bytes, dz_tiles, commit = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), sys.argv[6]
runs = {}
for line in open(path):
    name, secs, kb = line.split()
    runs.setdefault(name, []).append((float(secs), int(kb)))
mp = size * size / 1e6
out = {"source": f"procedural:terrain:{size} (uncompressed TIFF)", "commit": commit,
       "machine": f"{os.cpu_count()} cores, {platform.machine()}", "runs": {}}
print(f"\n{'tool':8} {'median s':>9} {'MP/s':>8} {'peak RSS MiB':>13} {'output MiB':>11}")
for name, rs in runs.items():
    t = statistics.median(r[0] for r in rs); m = max(r[1] for r in rs) / 1024
    size_b = tsr_bytes if name == "tessera" else dz_bytes
    out["runs"][name] = {"seconds": [r[0] for r in rs], "median_s": t, "mp_per_s": mp / t, "peak_rss_mib": m, "output_bytes": size_b}
    print(f"{name:8} {t:9.2f} {mp / t:8.1f} {m:13.0f} {size_b / 2**20:11.1f}")
tt, vv = out["runs"]["tessera"], out["runs"]["vips"]
out["speed_ratio"] = vv["median_s"] / tt["median_s"]
out["rss_ratio"] = tt["peak_rss_mib"] / vv["peak_rss_mib"]
out["vips_tiles"] = dz_tiles
print(f"\ntessera is {out['speed_ratio']:.2f}x the speed of vips dzsave, with {out['rss_ratio']:.2f}x its peak memory")
json.dump(out, open(os.path.join(os.path.dirname(path), "build_vs_vips.json"), "w"), indent=2)
PY
echo "JSON: $work/build_vs_vips.json"
