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
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

build_type=${TESSERA_BUILD_TYPE:-RelWithDebInfo}
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE="$build_type" ${TESSERA_CMAKE_ARGS:-} >/dev/null
cmake --build build --parallel "$(nproc)"
