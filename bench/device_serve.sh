#!/usr/bin/env bash
# The serving benchmark (bench/serve_vs_nginx.sh) on a lent many-core machine, with the servers on
# CPUs of their own and the load tools on the rest, so that wrk and serve_load take no CPU from
# the servers (on the 2-core machines they take about half: docs/benchmarks.md, "Serving").
#
# Such a machine reaches no package registry, so nginx, wrk and GNU time come as Debian packages
# downloaded beforehand into build/device-debs and are unpacked there into a private prefix (not
# into /). The binaries are the ones built here: carry build/tessera, build/bench/serve_load,
# build/bench/export_tiles, build/bench/floor_server and build/device-debs (about 52 MB).
#
#   bench/device_serve.sh --fetch                  here: download the packages into build/device-debs
#   bench/device_serve.sh [OUT] [ROUNDS] [SECS]    there: run; defaults /tmp/tessera-serve 2 6
#   env: SERVER_CPUS (0-1), LOAD_CPUS (the other CPUs)
# Writes OUT/serve.txt (the bench's output) and OUT/results.json. An estimated 4-5 minutes with the
# defaults on 16 cores (the store is built and exported first).
set -euo pipefail
cd "$(dirname "$0")/.."
debs=build/device-debs
packages=(nginx wrk libluajit-5.1-2 time)

if [ "${1:-}" = --fetch ]; then
  mkdir -p "$debs"
  rm -f "$debs"/*.deb
  (cd "$debs" && apt-get download "${packages[@]}")
  ls -la "$debs"
  exit 0
fi

out=$(realpath -m "${1:-/tmp/tessera-serve}")
rounds=${2:-2}
secs=${3:-6}
cpus=$(nproc)
[ "$cpus" -ge 4 ] || { echo "device_serve: $cpus CPUs; this run is for a machine with at least 4 (see bench/serve_vs_nginx.sh)" >&2; exit 2; }
for b in build/tessera build/bench/serve_load build/bench/export_tiles build/bench/floor_server; do
  [ -x "$b" ] || { echo "device_serve: $b missing: build it here and carry it" >&2; exit 1; }
done

# nginx, wrk and time from the carried packages when the machine lacks them.
if ! command -v nginx > /dev/null || ! command -v wrk > /dev/null || ! type -P time > /dev/null; then
  ls "$debs"/*.deb > /dev/null 2>&1 || { echo "device_serve: no nginx/wrk here and no packages in $debs (run --fetch where Debian's registry is reachable, and carry $debs)" >&2; exit 1; }
  prefix=$(mktemp -d /tmp/tessera-device-prefix.XXXXXX)
  for d in "$debs"/*.deb; do dpkg -x "$d" "$prefix"; done
  export PATH="$prefix/usr/sbin:$prefix/usr/bin:$PATH"
  export LD_LIBRARY_PATH="$prefix/usr/lib/x86_64-linux-gnu${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
  echo "device_serve: nginx, wrk and time from $debs, unpacked in $prefix"
fi
nginx -v 2>&1 | head -1
wrk -v 2>&1 | head -1 || true

mkdir -p "$out"
export SERVER_CPUS=${SERVER_CPUS:-0-1}
export LOAD_CPUS=${LOAD_CPUS:-2-$((cpus - 1))}
bench/serve_vs_nginx.sh "$rounds" "$secs" "$out/work" 2>&1 | tee "$out/serve.txt"
cp "$out/work/results.json" "$out/results.json"
echo "device_serve: $out/serve.txt, $out/results.json"
