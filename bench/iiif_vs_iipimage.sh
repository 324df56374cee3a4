#!/usr/bin/env bash
# IIIF tiles: `tessera serve` against IIPImage (Debian's iipimage-server behind lighttpd's FastCGI,
# as IIPImage documents), the same image on both: Tessera's store built by `tessera build`,
# IIPImage's a tiled pyramidal JPEG TIFF made by libvips (both JPEG quality 90). Each is asked for
# the tiles its own info.json announces, every level (a viewer's requests), as IIIF tile URLs.
#
#  1. peak: wrk -t2 -cCONNECTIONS, random tiles from the list, ROUNDS interleaved rounds of SECONDS;
#  2. latency at half of each one's own median peak (open model, serve_load --http --rate), and
#     at one common rate (IIPImage's half peak) for all: ROUNDS interleaved rounds of SECONDS, the
#     medians of the rounds' percentiles reported (on a shared 2-core VM one run's p99 can move 2x
#     from run to run: a few ms stalls of the machine land in ~1% of the requests).
# Tessera runs twice: as deployed (encoded web tiles cached) and with --web-cache 0, every tile
# decoded, cropped and encoded again per request, as IIPImage does with its cached raw tiles.
# Both servers, wrk and serve_load share this machine's cores; compare the ratio, not absolutes.
# Each server keeps its own caches at their defaults (Tessera: --web-cache 64 MiB; IIPImage:
# MAX_IMAGE_CACHE_SIZE 10 MB of tiles, here 256 MB so both hold every tile of this image), except
# that the decoded tiles both keep get the same 256 MB (IIPImage's MAX_IMAGE_CACHE_SIZE, Tessera's
# --web-decoded-cache, whose default is 128 MiB).
#
#   bench/iiif_vs_iipimage.sh [ROUNDS] [SECONDS] [SIZE] [WORKDIR]   defaults: 3 10 8192 build/bench-iiif
#   env: CONNECTIONS (32), TESSERA, SERVE_LOAD
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
secs=${2:-10}
size=${3:-8192}
work=$(realpath -m "${4:-build/bench-iiif}")
conns=${CONNECTIONS:-32}
tessera=${TESSERA:-build/tessera}
load=${SERVE_LOAD:-build/bench/serve_load}
for b in "$tessera" "$load"; do [ -x "$b" ] || { echo "build first: $b missing" >&2; exit 1; }; done
need=()
for p in iipimage-server lighttpd libvips-tools wrk; do dpkg-query -W -f='${Status}' $p 2>/dev/null | grep -q "ok installed" || need+=($p); done
if ((${#need[@]})); then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null; fi
mkdir -p "$work/runs"
rm -f "$work"/runs/*.json
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }

# ---- the image, twice --------------------------------------------------------------------------
if [ ! -f "$work/src.tif" ]; then
  for c in 1 2 3; do vips perlin "$work/p$c.v" "$size" "$size" --cell-size $((64 * c)) --seed $c; done
  vips bandjoin "$work/p1.v $work/p2.v $work/p3.v" "$work/rgb.v"
  vips linear "$work/rgb.v" "$work/src.tif" 127.5 127.5 --uchar
  rm -f "$work"/p?.v "$work/rgb.v"
fi
[ -f "$work/pyr.tif" ] || vips tiffsave "$work/src.tif" "$work/pyr.tif" --tile --pyramid --compression jpeg --Q 90 \
  --tile-width 256 --tile-height 256
[ -f "$work/img.tsr" ] || "$tessera" build "$work/src.tif" -o "$work/img.tsr" --quality 90 -q

# ---- IIPImage behind lighttpd (FastCGI) ----------------------------------------------------------
ipp=$(free_port)
mkdir -p "$work/lighttpd"
cat > "$work/lighttpd/lighttpd.conf" <<CONF
server.modules = ("mod_fastcgi")
server.document-root = "$work/lighttpd"
server.bind = "127.0.0.1"
server.port = $ipp
server.pid-file = "$work/lighttpd/pid"
server.errorlog = "$work/lighttpd/error.log"
server.max-keep-alive-requests = 100000
fastcgi.server = ( "/fcgi-bin/iipsrv.fcgi" => ((
  "socket" => "$work/lighttpd/iipsrv.sock",
  "bin-path" => "/usr/lib/iipimage-server/iipsrv.fcgi",
  "min-procs" => $(nproc), "max-procs" => $(nproc), "check-local" => "disable",
  "bin-environment" => ( "LOGFILE" => "$work/lighttpd/iipsrv.log", "VERBOSITY" => "0",
                         "MAX_IMAGE_CACHE_SIZE" => "256", "JPEG_QUALITY" => "90", "MAX_CVT" => "5000" )
)))
CONF
lighttpd -D -f "$work/lighttpd/lighttpd.conf" &
ipp_pid=$!
"$tessera" serve --store "$work/img.tsr" --grpc "" --http 127.0.0.1:0 2> "$work/tessera.log" &
tsr_pid=$!
"$tessera" serve --store "$work/img.tsr" --grpc "" --http 127.0.0.1:0 --web-cache 0 --web-decoded-cache 256MiB 2> "$work/tessera_nocache.log" &
tnc_pid=$!
stop() { kill "$1" 2>/dev/null || true; wait "$1" 2>/dev/null || true; }
trap 'stop $tsr_pid; stop $tnc_pid; stop $ipp_pid' EXIT
listening() {
  for _ in $(seq 1 100); do grep -q '"msg":"listening"' "$1" && break; sleep 0.1; done
  grep -m1 '"msg":"listening"' "$1" | sed -E 's/.*"http":"([^"]*)".*/\1/'
}
tsr=$(listening "$work/tessera.log")
tnc=$(listening "$work/tessera_nocache.log")
ipp_base="/fcgi-bin/iipsrv.fcgi?IIIF=$work/pyr.tif"
for _ in $(seq 1 100); do curl -sf -o /dev/null "http://127.0.0.1:$ipp$ipp_base/info.json" && break; sleep 0.2; done

# ---- each one's own tiles, from its info.json ----------------------------------------------------
urls() {  # INFO_URL PREFIX SIZE_FORM ("w," or "w,h") OUT
  curl -sf "$1" | python3 -c '
import json, math, sys
info = json.load(sys.stdin)
prefix, form = sys.argv[1], sys.argv[2]
W, H = info["width"], info["height"]
for t in info["tiles"]:
    tw, th = t["width"], t.get("height", t["width"])
    for sf in t["scaleFactors"]:
        for y in range(0, H, th * sf):
            for x in range(0, W, tw * sf):
                w, h = min(tw * sf, W - x), min(th * sf, H - y)
                ow, oh = math.ceil(w / sf), math.ceil(h / sf)
                size = f"{ow}," if form == "w," else f"{ow},{oh}"
                print(f"{prefix}/{x},{y},{w},{h}/{size}/0/default.jpg")' "$2" "$3" > "$4"
}
urls "http://$tsr/iiif/img/info.json" "/iiif/img" "w,h" "$work/tessera_urls.txt"
urls "http://127.0.0.1:$ipp$ipp_base/info.json" "$ipp_base" "w," "$work/iip_urls.txt"
for f in tessera_urls iip_urls; do
  n=0; bad=0
  while read -r u; do
    n=$((n + 1)); [ $((n % 97)) -eq 0 ] || continue
    host=$([ $f = tessera_urls ] && echo "$tsr" || echo "127.0.0.1:$ipp")
    [ "$(curl -s -o /dev/null -w '%{http_code}' "http://$host$u")" = 200 ] || bad=$((bad + 1))
  done < "$work/$f.txt"
  echo "$f: $(wc -l < "$work/$f.txt") tiles, $bad failed of a sample"
  [ "$bad" -eq 0 ] || { echo "tile URLs fail on $f" >&2; exit 1; }
done

# ---- peak and latency at half of it --------------------------------------------------------------
declare -A host=([tessera]=$tsr [tessera-nocache]=$tnc [iip]=127.0.0.1:$ipp)
declare -A list=([tessera]=$work/tessera_urls.txt [tessera-nocache]=$work/tessera_urls.txt [iip]=$work/iip_urls.txt)
names=(tessera tessera-nocache iip)
wrk_run() {  # run-name server
  wrk -t2 -c"$conns" -d"${secs}s" -s bench/wrk_tiles.lua "http://${host[$2]}" -- "${list[$2]}" "$RANDOM" \
    | sed -n 's/^WRK_JSON //p' > "$work/runs/$1.json"
}
for n in "${names[@]}"; do wrk -t2 -c"$conns" -d5s -s bench/wrk_tiles.lua "http://${host[$n]}" -- "${list[$n]}" 1 > /dev/null; done
for r in $(seq 1 "$rounds"); do  # interleaved, the order turned each round
  for i in 0 1 2; do n=${names[$(((i + r) % 3))]}; wrk_run "peak-$n-$r" "$n"; done
done
peak() {  # name -> median tiles/s
  python3 -c '
import json, glob, statistics, sys
v = [json.load(open(f)) for f in glob.glob(sys.argv[1])]
print(round(statistics.median(r["requests"] / (r["duration_us"] / 1e6) for r in v)))' "$work/runs/peak-$1-[0-9]*.json"
}
declare -A pk
for n in "${names[@]}"; do pk[$n]=$(peak "$n"); done
common=$((pk[iip] / 2))
for r in $(seq 1 "$rounds"); do  # interleaved like the peaks: one run's p99 here swings with the machine
  for i in 0 1 2; do
    n=${names[$(((i + r) % 3))]}
    "$load" --http "${host[$n]}" --url-file "${list[$n]}" --connections "$conns" --rate $((pk[$n] / 2)) --duration "$secs" \
      --seed "$r" --json "$work/runs/half-$n-$r.json" > /dev/null
    "$load" --http "${host[$n]}" --url-file "${list[$n]}" --connections "$conns" --rate "$common" --duration "$secs" \
      --seed "$r" --json "$work/runs/common-$n-$r.json" > /dev/null
  done
done
python3 - "$work" "${pk[tessera]}" "${pk[tessera-nocache]}" "${pk[iip]}" "$common" "$rounds" <<'PY'
import json, statistics, sys
work = sys.argv[1]
peaks = dict(zip(["tessera", "tessera-nocache", "iip"], map(int, sys.argv[2:5])))
common, rounds = int(sys.argv[5]), int(sys.argv[6])
def run(kind, name):  # the rounds' medians, each percentile on its own; the rounds' p99s kept
    runs = [json.load(open(f"{work}/runs/{kind}-{name}-{r}.json")) for r in range(1, rounds + 1)]
    lat = {q: statistics.median(x["latency_ms"][q] for x in runs) for q in runs[0]["latency_ms"]}
    return {"latency_ms": lat, "errors": sum(x["errors"] for x in runs),
            "p99_per_round": [x["latency_ms"]["p99"] for x in runs]}
print(f"{'server':<16} {'peak tiles/s':>13} {'p50 / p99 @ half peak':>24} {'p50 / p99 @ ' + str(common) + '/s':>24}")
rows = {}
for name, peak in peaks.items():
    h, c = run("half", name), run("common", name)
    hl, cl = h["latency_ms"], c["latency_ms"]
    rows[name] = {"peak": peak, "half": h, "common": c}
    print(f"{name:<16} {peak:>13} {hl['p50']:>10.2f} / {hl['p99']:>7.2f} ms {cl['p50']:>10.2f} / {cl['p99']:>7.2f} ms"
          + (f"  errors {h['errors'] + c['errors']}" if h["errors"] + c["errors"] else ""))
print(f"p99 at {common}/s, round by round: " + "; ".join(
    f"{n} {' '.join(f'{v:.2f}' for v in rows[n]['common']['p99_per_round'])}" for n in peaks))
for name in ["tessera", "tessera-nocache"]:
    r = rows[name]
    print(f"{name} / iipimage: peak {r['peak'] / peaks['iip']:.2f}x; p99 at {common}/s "
          f"{rows['iip']['common']['latency_ms']['p99'] / r['common']['latency_ms']['p99']:.2f}x lower")
json.dump(rows, open(f"{work}/results.json", "w"))
PY
