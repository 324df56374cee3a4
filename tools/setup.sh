#!/usr/bin/env bash
# Installs the Debian 12 packages Tessera needs (only those missing; apt-get update first),
# then configures and builds into ./build. Run as root on a fresh machine; safe to re-run.
set -euo pipefail
cd "$(dirname "$0")/.."

packages=(
  build-essential cmake ninja-build pkg-config git
  clang libclang-rt-14-dev           # libFuzzer targets
  libzstd-dev libturbojpeg0-dev libxxhash-dev
  libstb-dev libsquish-dev            # BC page encoding (stb_dxt); an independent BC decoder for tests
  libopenimageio-dev libtiff-dev
  libcli11-dev nlohmann-json3-dev libfmt-dev
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
  libboost-dev libssl-dev zlib1g-dev openssl
  libepoxy-dev libegl-dev libegl-mesa0 libgl1-mesa-dri libglfw3-dev libtinyobjloader-dev  # GL client (llvmpipe headless)
  libgtest-dev libgmock-dev libbenchmark-dev
  xvfb xauth                          # windowed-mode tests on an X server without a display
  imagemagick openimageio-tools       # tests read images other tools wrote (alpha conventions, formats)
  python3 python3-yaml time systemd   # systemd: systemd-analyze lints deploy/tessera.service
  mmdebstrap                          # deploy/build-image.py: the image's root filesystem
  nginx-light                         # remote stores over plain HTTP range requests (tests)
  chromium                            # the web viewer, tested in a real headless browser
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# Node and npm for the web-side test tools (an S3 server); any installed npm will do.
command -v npm >/dev/null 2>&1 || missing+=(nodejs npm)
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# The npm packages (each package-lock.json pins them), when a lock changed: server/web holds
# OpenSeadragon, which the build puts into the server's web viewer; tests/npm what the tests drive.
for dir in server/web tests/npm; do
  if [[ ! -f $dir/node_modules/.package-lock.json || $dir/package-lock.json -nt $dir/node_modules/.package-lock.json ]]; then
    echo "setup: installing $dir's packages from npm"
    (cd "$dir" && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
  fi
done

build_type=${TESSERA_BUILD_TYPE:-RelWithDebInfo}
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE="$build_type" ${TESSERA_CMAKE_ARGS:-} >/dev/null
cmake --build build --parallel "$(nproc)"
