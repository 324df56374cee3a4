# Every dependency comes from a Debian 12 package (tools/setup.sh installs them).
find_package(PkgConfig REQUIRED)
find_package(Threads REQUIRED)
pkg_check_modules(ZSTD REQUIRED IMPORTED_TARGET libzstd)
pkg_check_modules(TURBOJPEG REQUIRED IMPORTED_TARGET libturbojpeg)
pkg_check_modules(XXHASH REQUIRED IMPORTED_TARGET libxxhash)
if(NOT TESSERA_FUZZ_ONLY)
  # Debian 12's OpenImageIO CMake config names /usr/include/opencv4 even when OpenCV is not
  # installed; its pkg-config file is sound, so use that.
  pkg_check_modules(OIIO REQUIRED IMPORTED_TARGET OpenImageIO)
  pkg_check_modules(TIFF REQUIRED IMPORTED_TARGET libtiff-4)
  find_package(CLI11 REQUIRED CONFIG)
  find_package(nlohmann_json REQUIRED CONFIG)
  find_package(fmt REQUIRED CONFIG)
  if(TESSERA_BUILD_TESTS)
    find_package(GTest REQUIRED)
  endif()
endif()
