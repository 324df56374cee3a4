# `cmake --install` of the full build: the two programs and the OIIO module (component
# "runtime", declared beside their targets), and the client libraries as a CMake package
# (component "dev"): headers, static libraries and TesseraConfig.cmake, so that an engine finds
# them with find_package(Tessera) and links tessera::client, tessera::client_gl,
# tessera::scene, tessera::storage, tessera::core (docs/client.md, "Embedding the client"; examples/ is such a program).
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

# The libraries an embedding program links, and what they link privately (static libraries carry
# their private dependencies to the final link). Exported under tessera::<short name>.
set(tessera_exported
  tessera_core:core
  tessera_storage:storage
  tessera_blocks:blocks
  tessera_protocol_gen:protocol_gen
  tessera_protocol:protocol
  tessera_client_net:client_net
  tessera_client:client
  tessera_scene:scene
  tessera_client_gl:client_gl
  tessera_warnings:warnings)
set(tessera_export_targets "")
foreach(pair IN LISTS tessera_exported)
  string(REPLACE ":" ";" pair "${pair}")
  list(GET pair 0 target)
  list(GET pair 1 name)
  set_target_properties(${target} PROPERTIES EXPORT_NAME ${name})
  # The public headers are C++20 (defaulted comparisons, std::span): a consumer gets the standard
  # with the target, whatever its own default.
  get_target_property(type ${target} TYPE)
  if(type STREQUAL "INTERFACE_LIBRARY")
    target_compile_features(${target} INTERFACE cxx_std_20)
  else()
    target_compile_features(${target} PUBLIC cxx_std_20)
  endif()
  list(APPEND tessera_export_targets ${target})
endforeach()
install(TARGETS ${tessera_export_targets} EXPORT TesseraTargets
  ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR} COMPONENT dev
  INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})

# Public headers only. The protocol's headers stay out: they include the generated protobuf and
# gRPC code, which no embedding program should have to see. So do the builder's (its image and
# sparse sources too), the remote stores' and the JSON description's, whose libraries are not
# part of the package: an installed header declares nothing an installed library lacks.
install(DIRECTORY core/include/ storage/include/ storage/blocks/include/ client/include/ client/net/include/
                  scene/include/ client/gl/include/
  DESTINATION ${CMAKE_INSTALL_INCLUDEDIR} COMPONENT dev
  FILES_MATCHING PATTERN "*.hpp"
  PATTERN "builder.hpp" EXCLUDE
  PATTERN "image_source.hpp" EXCLUDE
  PATTERN "sparse_source.hpp" EXCLUDE
  PATTERN "atlas.hpp" EXCLUDE
  PATTERN "remote_source.hpp" EXCLUDE
  PATTERN "store_json.hpp" EXCLUDE)
# scene/'s atlas.hpp is public (the scene's atlas layout); only the builder's is excluded above.
install(FILES scene/include/tessera/scene/atlas.hpp
  DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/tessera/scene COMPONENT dev)

set(tessera_cmake_dir ${CMAKE_INSTALL_LIBDIR}/cmake/Tessera)
install(EXPORT TesseraTargets NAMESPACE tessera:: DESTINATION ${tessera_cmake_dir} COMPONENT dev)
configure_package_config_file(cmake/TesseraConfig.cmake.in ${CMAKE_CURRENT_BINARY_DIR}/TesseraConfig.cmake
  INSTALL_DESTINATION ${tessera_cmake_dir})
write_basic_package_version_file(${CMAKE_CURRENT_BINARY_DIR}/TesseraConfigVersion.cmake
  COMPATIBILITY SameMinorVersion)
install(FILES ${CMAKE_CURRENT_BINARY_DIR}/TesseraConfig.cmake ${CMAKE_CURRENT_BINARY_DIR}/TesseraConfigVersion.cmake
  DESTINATION ${tessera_cmake_dir} COMPONENT dev)
