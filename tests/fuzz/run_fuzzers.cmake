# Two roles.
#
# Included from tests/CMakeLists.txt (TESSERA_FUZZ=ON): builds the libFuzzer targets in a clang
# sub-build of this same source tree, ${CMAKE_BINARY_DIR}/fuzz-build (-DTESSERA_FUZZ_ONLY=ON, see
# tests/fuzz/CMakeLists.txt), as part of the normal build, and registers the ctest tests
# store_reader_fuzz and server_request_fuzz, which run this file as a script.
#
# Run as a script (cmake -DFUZZER=... -P run_fuzzers.cmake): the test. Makes a fresh corpus
# directory from make_fuzz_corpus's seeds (the fuzzer adds inputs to it, so it lives in the build
# tree) plus the inputs in CORPUS_ARCHIVE (optional), runs every file of REGRESSIONS_DIR once,
# then fuzzes for FUZZ_SECONDS. Fails on any crash,
# leak, sanitizer report or timeout; the offending input is left in WORK_DIR/artifacts/.

if(CMAKE_SCRIPT_MODE_FILE)
  foreach(var FUZZER CORPUS_GEN WORK_DIR REGRESSIONS_DIR FUZZ_SECONDS)
    if(NOT DEFINED ${var})
      message(FATAL_ERROR "run_fuzzers.cmake: -D${var}=... is required")
    endif()
  endforeach()
  foreach(exe FUZZER CORPUS_GEN)
    if(NOT EXISTS "${${exe}}")
      message(FATAL_ERROR "${${exe}} does not exist: build first (the fuzz sub-build needs clang, "
                          "which tools/setup.sh installs)")
    endif()
  endforeach()
  file(REMOVE_RECURSE "${WORK_DIR}")
  file(MAKE_DIRECTORY "${WORK_DIR}/corpus" "${WORK_DIR}/artifacts")
  execute_process(COMMAND "${CORPUS_GEN}" "${WORK_DIR}/corpus" RESULT_VARIABLE rc)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${CORPUS_GEN} failed (${rc})")
  endif()
  # What long runs found beyond the generated seeds (merged with -merge=1, docs/reliability.md).
  if(DEFINED CORPUS_ARCHIVE AND EXISTS "${CORPUS_ARCHIVE}")
    file(ARCHIVE_EXTRACT INPUT "${CORPUS_ARCHIVE}" DESTINATION "${WORK_DIR}/corpus")
  endif()
  set(options -rss_limit_mb=2048 -timeout=10 "-artifact_prefix=${WORK_DIR}/artifacts/")
  file(GLOB regressions LIST_DIRECTORIES false "${REGRESSIONS_DIR}/*")
  list(FILTER regressions EXCLUDE REGEX "/README[^/]*$")
  if(regressions)
    list(LENGTH regressions n)
    message(STATUS "running ${n} regression input(s) from ${REGRESSIONS_DIR}")
    execute_process(COMMAND "${FUZZER}" ${options} ${regressions} RESULT_VARIABLE rc)
    if(NOT rc EQUAL 0)
      message(FATAL_ERROR "a regression input from ${REGRESSIONS_DIR} fails again (exit ${rc})")
    endif()
  endif()
  execute_process(COMMAND "${FUZZER}" ${options} -max_total_time=${FUZZ_SECONDS} -print_final_stats=1
                          "${WORK_DIR}/corpus" RESULT_VARIABLE rc)
  if(NOT rc EQUAL 0)
    file(GLOB found "${WORK_DIR}/artifacts/*")
    message(FATAL_ERROR "the fuzzer found a problem (exit ${rc}); input: ${found}\n"
                        "Reproduce: ${FUZZER} <input>; keep the input in ${REGRESSIONS_DIR} once fixed.")
  endif()
  return()
endif()

if(NOT TESSERA_FUZZ)
  return()
endif()
set(TESSERA_FUZZ_BUILD_DIR ${CMAKE_BINARY_DIR}/fuzz-build)
find_program(TESSERA_CLANGXX NAMES clang++ clang++-14)
find_program(TESSERA_CLANG NAMES clang clang-14)
if(NOT TESSERA_CLANGXX OR NOT TESSERA_CLANG)
  # The tests are still registered: without the fuzzers they fail, saying so, rather than vanish
  # from a ctest run that would then pass without them.
  message(WARNING "TESSERA_FUZZ is ON but clang/clang++ was not found: the fuzz targets are not built "
                  "and the store_reader_fuzz and server_request_fuzz tests will fail (tools/setup.sh "
                  "installs clang; -DTESSERA_FUZZ=OFF leaves them out)")
else()
  include(ExternalProject)
  set(TESSERA_FUZZ_FLAGS "-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer -O1 -gline-tables-only")
  ExternalProject_Add(tessera_fuzz
    SOURCE_DIR ${PROJECT_SOURCE_DIR}
    BINARY_DIR ${TESSERA_FUZZ_BUILD_DIR}
    PREFIX ${CMAKE_BINARY_DIR}/fuzz-build-ep
    CMAKE_GENERATOR Ninja
    CMAKE_ARGS
      -DCMAKE_C_COMPILER=${TESSERA_CLANG}
      -DCMAKE_CXX_COMPILER=${TESSERA_CLANGXX}
      -DCMAKE_BUILD_TYPE=Debug  # assertions on; -O1 comes from the flags
      "-DCMAKE_C_FLAGS=${TESSERA_FUZZ_FLAGS}"
      "-DCMAKE_CXX_FLAGS=${TESSERA_FUZZ_FLAGS}"
      -DTESSERA_FUZZ_ONLY=ON
      -DTESSERA_WERROR=${TESSERA_WERROR}
    BUILD_ALWAYS ON
    INSTALL_COMMAND ""
    BUILD_BYPRODUCTS ${TESSERA_FUZZ_BUILD_DIR}/fuzz/store_reader_fuzz ${TESSERA_FUZZ_BUILD_DIR}/fuzz/make_fuzz_corpus
                     ${TESSERA_FUZZ_BUILD_DIR}/fuzz/server_request_fuzz ${TESSERA_FUZZ_BUILD_DIR}/fuzz/make_server_fuzz_corpus
    USES_TERMINAL_CONFIGURE ON
    USES_TERMINAL_BUILD ON)
endif()

add_test(NAME store_reader_fuzz
  COMMAND ${CMAKE_COMMAND}
    -DFUZZER=${TESSERA_FUZZ_BUILD_DIR}/fuzz/store_reader_fuzz
    -DCORPUS_GEN=${TESSERA_FUZZ_BUILD_DIR}/fuzz/make_fuzz_corpus
    -DWORK_DIR=${CMAKE_BINARY_DIR}/fuzz-run/store_reader_fuzz
    -DREGRESSIONS_DIR=${CMAKE_CURRENT_LIST_DIR}/regressions
    -DCORPUS_ARCHIVE=${CMAKE_CURRENT_LIST_DIR}/corpus/store_reader.tar.zst
    -DFUZZ_SECONDS=30
    -P ${CMAKE_CURRENT_LIST_FILE})
set_tests_properties(store_reader_fuzz PROPERTIES TIMEOUT 300 LABELS fuzz)

add_test(NAME server_request_fuzz
  COMMAND ${CMAKE_COMMAND}
    -DFUZZER=${TESSERA_FUZZ_BUILD_DIR}/fuzz/server_request_fuzz
    -DCORPUS_GEN=${TESSERA_FUZZ_BUILD_DIR}/fuzz/make_server_fuzz_corpus
    -DWORK_DIR=${CMAKE_BINARY_DIR}/fuzz-run/server_request_fuzz
    -DREGRESSIONS_DIR=${CMAKE_CURRENT_LIST_DIR}/regressions-server
    -DCORPUS_ARCHIVE=${CMAKE_CURRENT_LIST_DIR}/corpus/server_request.tar.zst
    -DFUZZ_SECONDS=30
    -P ${CMAKE_CURRENT_LIST_FILE})
set_tests_properties(server_request_fuzz PROPERTIES TIMEOUT 300 LABELS fuzz)
