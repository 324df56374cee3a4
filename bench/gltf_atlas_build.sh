#!/usr/bin/env bash
# Building an atlas from a glTF scene of many textures against building one image of the same
# texels (docs/benchmarks.md, "glTF atlas build"). COUNT textures of SIZE² (ImageMagick plasma,
# JPEG q90), one quad each in a glTF (every 7th repeating 2x2), made into a GLB by gltfpack
# (Debian's meshoptimizer tool: quantised attributes, KHR_texture_transform, the images inside);
# the single image is the same textures tiled by libvips (arrayjoin). ROUNDS interleaved rounds
# of `tessera build --atlas scene.glb` and `tessera build one.jpg`, both with the defaults.
#
#   bench/gltf_atlas_build.sh [COUNT] [SIZE] [ROUNDS] [WORKDIR]   defaults: 60 1024 3 build/bench-gltf
#   env: TESSERA
set -euo pipefail
cd "$(dirname "$0")/.."
count=${1:-60}
size=${2:-1024}
rounds=${3:-3}
work=$(realpath -m "${4:-build/bench-gltf}")
tessera=$(realpath "${TESSERA:-build/tessera}")
[ -x "$tessera" ] || { echo "build first: $tessera missing" >&2; exit 1; }
need=()
for p in gltfpack imagemagick libvips-tools bc; do dpkg-query -W -f='${Status}' $p 2>/dev/null | grep -q "ok installed" || need+=($p); done
if ((${#need[@]})); then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null; fi
mkdir -p "$work/tex"
cd "$work"
echo "textures: $count of ${size}x${size} (ImageMagick plasma) ..."
for ((i = 0; i < count; i++)); do
  [ -f tex/t$i.jpg ] || convert -size ${size}x${size} -seed $i plasma:fractal -blur 0x1 -quality 90 tex/t$i.jpg
done
python3 - "$count" <<'EOF'
import json, struct, sys
n = int(sys.argv[1])
pos, uv, idx = [], [], []
for i in range(n):
    x, y, r = (i % 10) * 1.2, (i // 10) * 1.2, 2.0 if i % 7 == 0 else 1.0
    pos += [x, y, 0, x + 1, y, 0, x + 1, y + 1, 0, x, y + 1, 0]
    uv += [0, r, r, r, r, 0, 0, 0]
buf = struct.pack(f"<{len(pos)}f", *pos) + struct.pack(f"<{len(uv)}f", *uv) + struct.pack("<6H", 0, 1, 2, 0, 2, 3)
open("scene.bin", "wb").write(buf)
pb, ub = 4 * len(pos), 4 * len(uv)
views = [{"buffer": 0, "byteOffset": 0, "byteLength": pb}, {"buffer": 0, "byteOffset": pb, "byteLength": ub},
         {"buffer": 0, "byteOffset": pb + ub, "byteLength": 12}]
acc, meshes, nodes, mats, tex, img = [], [], [], [], [], []
for i in range(n):
    acc += [{"bufferView": 0, "byteOffset": 48 * i, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": pos[12 * i:12 * i + 3], "max": pos[12 * i + 6:12 * i + 9]},
            {"bufferView": 1, "byteOffset": 32 * i, "componentType": 5126, "count": 4, "type": "VEC2"}]
    meshes.append({"primitives": [{"attributes": {"POSITION": 2 * i, "TEXCOORD_0": 2 * i + 1}, "indices": 2 * n, "material": i}]})
    nodes.append({"mesh": i})
    mats.append({"name": f"m{i}", "pbrMetallicRoughness": {"baseColorTexture": {"index": i}, "metallicFactor": 0}})
    tex.append({"source": i, "sampler": 0})
    img.append({"uri": f"tex/t{i}.jpg"})
acc.append({"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"})
doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": list(range(n))}], "nodes": nodes, "meshes": meshes,
       "materials": mats, "textures": tex, "images": img, "samplers": [{"wrapS": 10497, "wrapT": 10497}],
       "buffers": [{"uri": "scene.bin", "byteLength": len(buf)}], "bufferViews": views, "accessors": acc}
json.dump(doc, open("scene.gltf", "w"))
EOF
gltfpack -i scene.gltf -o scene.glb >/dev/null
[ -f one.jpg ] || vips arrayjoin "$(for ((i = 0; i < count; i++)); do printf 'tex/t%d.jpg ' $i; done)" one.jpg[Q=90] --across 10
echo "single image: $(vipsheader one.jpg); scene.glb $(stat -c %s scene.glb) bytes (gltfpack)"
now() { date +%s.%N; }
declare -a atlas_s one_s
for ((r = 0; r < rounds; r++)); do
  t0=$(now); "$tessera" build -q --atlas scene.glb -o atlas.tsr; t1=$(now)
  "$tessera" build -q one.jpg -o one.tsr; t2=$(now)
  atlas_s+=("$(echo "$t1 - $t0" | bc)"); one_s+=("$(echo "$t2 - $t1" | bc)")
  echo "round $((r + 1)): atlas ${atlas_s[-1]} s, one image ${one_s[-1]} s"
done
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR] = $1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}'; }
ma=$(median "${atlas_s[@]}"); mo=$(median "${one_s[@]}")
texels=$((count * size * size))
atlas_wh=$("$tessera" inspect atlas.tsr | awk '/^image/ {print $2 * $4}')
printf '\n| build | median wall (s) | texels/s (M) | store (MiB) |\n|---|---:|---:|---:|\n'
printf '| atlas from scene.glb (%d textures) | %.2f | %.1f | %.1f |\n' "$count" "$ma" "$(echo "$texels / $ma / 1000000" | bc -l)" "$(echo "$(stat -c %s atlas.tsr) / 1048576" | bc -l)"
printf '| one image, the same texels | %.2f | %.1f | %.1f |\n' "$mo" "$(echo "$texels / $mo / 1000000" | bc -l)" "$(echo "$(stat -c %s one.tsr) / 1048576" | bc -l)"
printf '\natlas / one image texels per second: %.2fx; atlas occupancy %.1f%% (%d texture texels of %d)\n' \
  "$(echo "$mo / $ma" | bc -l)" "$(echo "100 * $texels / $atlas_wh" | bc -l)" "$texels" "$atlas_wh"
