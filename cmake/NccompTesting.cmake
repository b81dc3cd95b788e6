# nccomp_add_gtest(NAME test_x LABELS unit [TSAN] SOURCES ... LIBS ... [CORE_MODULES base creep])
# Labels: unit (fast, pure), hil (real bus stacks: vcan, loopback Modbus), e2e (virtual NC), fuzz.
# TSAN marks a test as one that matters under ThreadSanitizer (real-time primitives, drivers,
# daemon): only those are built in the tsan preset, which runs all it built. (One label per test:
# gtest_discover_tests in CMake 3.25 cannot carry a list-valued LABELS property.)
# NCCOMP_TEST_PCH: the test executables reuse one precompiled header (tests/support/CMakeLists.txt)
# instead of parsing GoogleTest and the standard headers again for every test file.
option(NCCOMP_TEST_PCH "Precompiled header (GoogleTest, Eigen, std) for the test executables" ON)

# With ccache as the compiler launcher, a file compiled with a precompiled header is only cached
# when ccache's sloppiness allows it (pch_defines, time_macros) and GCC is given -fpch-preprocess;
# otherwise ccache compiles it uncached. The test targets get both, without touching ccache.conf.
function(nccomp_test_pch_launcher target)
  # The property starts from CMAKE_CXX_COMPILER_LAUNCHER, the variable or the environment's.
  get_target_property(launcher ${target} CXX_COMPILER_LAUNCHER)
  if(launcher MATCHES "ccache" AND NOT launcher MATCHES "CCACHE_SLOPPINESS")
    set_target_properties(${target} PROPERTIES CXX_COMPILER_LAUNCHER
      "${CMAKE_COMMAND};-E;env;CCACHE_SLOPPINESS=pch_defines,time_macros,include_file_mtime,include_file_ctime;${launcher}")
    if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
      target_compile_options(${target} PRIVATE -fpch-preprocess)
    endif()
  endif()
endfunction()

function(nccomp_add_gtest)
  cmake_parse_arguments(T "TSAN" "NAME;TIMEOUT" "LABELS;SOURCES;LIBS;CORE_MODULES" ${ARGN})
  if(NCCOMP_TSAN_ONLY AND NOT T_TSAN)
    return()
  endif()
  add_executable(${T_NAME} ${T_SOURCES})
  set(objs "")
  if(T_CORE_MODULES)
    nccomp_core_objects(objs ${T_CORE_MODULES})
  endif()
  target_link_libraries(${T_NAME} PRIVATE ${objs} ${T_LIBS} GTest::gtest GTest::gtest_main
                                          GTest::gmock Threads::Threads)
  nccomp_set_warnings(${T_NAME})
  if(TARGET nccomp_test_pch)
    target_precompile_headers(${T_NAME} REUSE_FROM nccomp_test_pch)
    nccomp_test_pch_launcher(${T_NAME})
  endif()
  if(NOT T_TIMEOUT)
    set(T_TIMEOUT 300)
  endif()
  gtest_discover_tests(${T_NAME}
    PROPERTIES LABELS ${T_LABELS} TIMEOUT ${T_TIMEOUT}
    DISCOVERY_TIMEOUT 60)
endfunction()
