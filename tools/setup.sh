#!/usr/bin/env bash
# Installs the Debian 12 packages Tessera needs (only those missing; apt-get update first),
# then configures and builds into ./build. Run as root on a fresh machine; safe to re-run.
#
#   tools/setup.sh           what the demo needs: the build's packages, then the `tessera` program
#   tools/setup.sh --tests   also what only the tests need, then everything: tests, benchmarks,
#                            the fuzz sub-build. clang, Node and npm install before the build (it
#                            uses them); Chromium, nginx, mmdebstrap, ImageMagick, Xvfb, the glTF
#                            samples and the npm test tools install in the background while it
#                            compiles (build/setup-test-packages.log)
set -euo pipefail
cd "$(dirname "$0")/.."
tests=0
case "${1:-}" in
  "") ;;
  --tests) tests=1 ;;
  *) echo "usage: tools/setup.sh [--tests]" >&2; exit 2 ;;
esac

packages=(
  build-essential cmake ninja-build pkg-config git
  libzstd-dev libturbojpeg0-dev libxxhash-dev
  libstb-dev libsquish-dev            # BC page encoding (stb_dxt); an independent BC decoder for tests
  libopenimageio-dev libtiff-dev libwebp-dev  # libwebp: WebP alpha kept straight
  libcli11-dev nlohmann-json3-dev libfmt-dev
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
  libboost-dev libssl-dev zlib1g-dev openssl
  libepoxy-dev libegl-dev libegl-mesa0 libgl1-mesa-dri libglfw3-dev  # GL client (llvmpipe headless)
  libtinyobjloader-dev libtinygltf-dev  # scene/: OBJ and glTF scenes
  libgtest-dev libgmock-dev libbenchmark-dev  # small; the build configures its tests even when it does not build them
  python3
)
# What only the tests need. The build itself needs clang (the fuzz sub-build) and npm (server/web's
# OpenSeadragon goes into the build); the rest is needed only when the tests run, so it installs
# in the background while the build compiles (apt and npm wait on the network and the disk, the
# compiler on the CPUs).
test_build_packages=(
  clang libclang-rt-14-dev           # libFuzzer targets
)
test_run_packages=(
  xvfb xauth                          # windowed-mode tests on an X server without a display
  imagemagick openimageio-tools webp  # tests read images other tools wrote (alpha conventions, formats)
  libtiff-tools                       # tiffcp and tiffset: JPEG-compressed YCbCr and oriented TIFFs
  assimp-testmodels gltfpack          # real glTF 2.0 scenes (Khronos samples, meshoptimizer's packer) for the atlas tests
  python3-yaml time systemd           # systemd: systemd-analyze lints deploy/tessera.service
  mmdebstrap                          # deploy/build-image.py: the image's root filesystem
  nginx-light                         # remote stores over plain HTTP range requests (tests)
  chromium                            # the web viewer, tested in a real headless browser
)
((tests)) && packages+=("${test_build_packages[@]}")

# The packages of `$@` that are not installed, into the array `missing`.
find_missing() {
  missing=()
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
}
apt_updated=0
apt_install() {  # quietly; apt-get update once per run
  export DEBIAN_FRONTEND=noninteractive
  ((apt_updated)) || { apt-get update -qq; apt_updated=1; }
  apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}
npm_ci() {  # $1: a folder with a package-lock.json; only when the lock changed
  if [[ ! -f $1/node_modules/.package-lock.json || $1/package-lock.json -nt $1/node_modules/.package-lock.json ]]; then
    echo "setup: installing $1's packages from npm"
    (cd "$1" && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
  fi
}

find_missing "${packages[@]}"
# Node and npm for the web side: OpenSeadragon (built into the server's web viewer) and the test
# tools (an S3 server, a headless-browser driver); any installed npm will do.
((tests)) && { command -v npm >/dev/null 2>&1 || missing+=(nodejs npm); }
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  apt_install "${missing[@]}"
fi

# The npm packages (each package-lock.json pins them): server/web holds OpenSeadragon, which the
# build puts into the server's web viewer. Without npm (the demo's setup on a fresh machine) the
# web viewer is built without OpenSeadragon and its page says so; `--tests` installs it.
command -v npm >/dev/null 2>&1 && npm_ci server/web

# With --tests: the packages only the test run needs (and tests/npm, what the tests drive), in the
# background while the build runs; its output goes to build/setup-test-packages.log.
background=""
if ((tests)); then
  find_missing "${test_run_packages[@]}"
  mkdir -p build
  (
    if ((${#missing[@]})); then
      echo "setup: installing ${missing[*]}"
      apt_install "${missing[@]}"
    fi
    npm_ci tests/npm
  ) > build/setup-test-packages.log 2>&1 &
  background=$!
  echo "setup: installing the test-only packages in the background (build/setup-test-packages.log)"
fi
# The build's exit status, then the background install's: both must succeed.
finish() {
  local rc=$1
  if [[ -n $background ]]; then
    if ! wait "$background"; then
      echo "setup: installing the test-only packages failed:" >&2
      cat build/setup-test-packages.log >&2
      rc=1
    else
      cat build/setup-test-packages.log
    fi
  fi
  exit "$rc"
}
trap 'finish 1' ERR

build_type=${TESSERA_BUILD_TYPE:-RelWithDebInfo}
if ((tests)); then
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE="$build_type" -DTESSERA_FUZZ=ON ${TESSERA_CMAKE_ARGS:-} >/dev/null
  cmake --build build --parallel "$(nproc)"
else
  # The fuzz sub-build needs clang, a test package: off until `--tests` turns it on (a build that
  # has it on already keeps it).
  fuzz=OFF
  grep -q '^TESSERA_FUZZ:BOOL=ON' build/CMakeCache.txt 2>/dev/null && fuzz=ON
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE="$build_type" -DTESSERA_FUZZ=$fuzz ${TESSERA_CMAKE_ARGS:-} >/dev/null
  cmake --build build --parallel "$(nproc)" --target tessera
fi
finish 0
