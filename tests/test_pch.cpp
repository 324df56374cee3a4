// The precompiled header's own source (tests/CMakeLists.txt, tessera_test_pch): nothing else.
