# Every dependency comes from a Debian 12 package (tools/setup.sh installs them).
find_package(PkgConfig REQUIRED)
find_package(Threads REQUIRED)
pkg_check_modules(ZSTD REQUIRED IMPORTED_TARGET libzstd)
pkg_check_modules(TURBOJPEG REQUIRED IMPORTED_TARGET libturbojpeg)
pkg_check_modules(XXHASH REQUIRED IMPORTED_TARGET libxxhash)
# gRPC and protobuf through pkg-config: Debian 12 ships no protobuf CMake config.
pkg_check_modules(GRPCPP REQUIRED IMPORTED_TARGET grpc++)
pkg_check_modules(PROTOBUF REQUIRED IMPORTED_TARGET protobuf)
find_package(absl REQUIRED CONFIG)  # comes with gRPC; the server's flat hash maps
find_package(nlohmann_json REQUIRED CONFIG)
find_package(ZLIB REQUIRED)  # PNG encoding (tiles over HTTP, the viewer's frames)
# stb_dxt: BC1/BC4/BC5 blocks (tessera::blocks), for block-codec stores and the client's pages.
pkg_check_modules(STB REQUIRED IMPORTED_TARGET stb)
if(NOT TESSERA_FUZZ_ONLY)
  find_package(CLI11 REQUIRED CONFIG)
  find_package(fmt REQUIRED CONFIG)
  find_package(Boost 1.74 REQUIRED CONFIG)  # header-only Asio and Beast
  find_package(OpenSSL REQUIRED)
endif()
if(NOT TESSERA_FUZZ_ONLY AND NOT TESSERA_SERVER_ONLY)
  # Debian 12's OpenImageIO CMake config names /usr/include/opencv4 even when OpenCV is not
  # installed; its pkg-config file is sound, so use that.
  pkg_check_modules(OIIO REQUIRED IMPORTED_TARGET OpenImageIO)
  pkg_check_modules(TIFF REQUIRED IMPORTED_TARGET libtiff-4)
  pkg_check_modules(WEBP REQUIRED IMPORTED_TARGET libwebp)
  # The GL client: libepoxy dispatches GL calls for both EGL (headless) and GLFW (windowed).
  pkg_check_modules(EPOXY REQUIRED IMPORTED_TARGET epoxy)
  pkg_check_modules(EGL REQUIRED IMPORTED_TARGET egl)
  pkg_check_modules(GLFW REQUIRED IMPORTED_TARGET glfw3)
  pkg_check_modules(TINYOBJ REQUIRED IMPORTED_TARGET tinyobjloader)
  pkg_check_modules(TINYGLTF REQUIRED IMPORTED_TARGET tinygltf)  # glTF 2.0 scenes for the atlas build
  if(TESSERA_BUILD_TESTS)
    find_package(GTest REQUIRED)
    # libsquish: an independent BC decoder, so the tests do not check our blocks with our own code.
    # (Debian 12's libsquish.pc names a missing /include, so it is found by hand.)
    find_path(SQUISH_INCLUDE_DIR squish.h REQUIRED)
    find_library(SQUISH_LIBRARY squish REQUIRED)
    add_library(Squish::squish UNKNOWN IMPORTED)
    set_target_properties(Squish::squish PROPERTIES IMPORTED_LOCATION ${SQUISH_LIBRARY}
      INTERFACE_INCLUDE_DIRECTORIES ${SQUISH_INCLUDE_DIR})
  endif()
endif()
