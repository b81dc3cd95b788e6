# nccomp_add_gtest(NAME test_x LABELS unit [TSAN] [SEPARATE_FILES] SOURCES ... LIBS ...
#                  [CORE_MODULES base creep] [SEPARATE file ...])
# Labels: unit (fast, pure), hil (real bus stacks: vcan, loopback Modbus), e2e (virtual NC), fuzz.
# TSAN marks a test as one that matters under ThreadSanitizer (real-time primitives, drivers,
# daemon): only those are built in the tsan preset, which runs all it built. (One label per test:
# gtest_discover_tests in CMake 3.25 cannot carry a list-valued LABELS property.)
# With NCCOMP_UNITY_TESTS (the default) a test's files under tests/ compile as one unit (sources
# from elsewhere, the code under test, always on their own). SEPARATE lists the files that
# compile on their own because they define helpers of the same names as another file of the test
# in their anonymous namespaces; SEPARATE_FILES compiles every file on its own.
function(nccomp_add_gtest)
  cmake_parse_arguments(T "TSAN;SEPARATE_FILES" "NAME;TIMEOUT"
                        "LABELS;SOURCES;LIBS;CORE_MODULES;SEPARATE" ${ARGN})
  if(NCCOMP_TSAN_ONLY AND NOT T_TSAN)
    return()
  endif()
  add_executable(${T_NAME} ${T_SOURCES})
  if(NCCOMP_UNITY_TESTS AND NOT T_SEPARATE_FILES)
    set_target_properties(${T_NAME} PROPERTIES UNITY_BUILD ON UNITY_BUILD_BATCH_SIZE 0)
    foreach(src IN LISTS T_SOURCES)
      cmake_path(ABSOLUTE_PATH src BASE_DIRECTORY ${CMAKE_CURRENT_SOURCE_DIR} OUTPUT_VARIABLE abs)
      string(FIND "${abs}" "${PROJECT_SOURCE_DIR}/tests/" at)
      if(NOT at EQUAL 0 OR src IN_LIST T_SEPARATE)
        set_source_files_properties(${src} PROPERTIES SKIP_UNITY_BUILD_INCLUSION ON)
      endif()
    endforeach()
  endif()
  set(objs "")
  if(T_CORE_MODULES)
    nccomp_core_objects(objs ${T_CORE_MODULES})
  endif()
  target_link_libraries(${T_NAME} PRIVATE ${objs} ${T_LIBS} GTest::gtest GTest::gtest_main
                                          GTest::gmock Threads::Threads)
  nccomp_set_warnings(${T_NAME})
  if(NOT T_TIMEOUT)
    set(T_TIMEOUT 300)
  endif()
  gtest_discover_tests(${T_NAME}
    PROPERTIES LABELS ${T_LABELS} TIMEOUT ${T_TIMEOUT}
    DISCOVERY_TIMEOUT 60)
endfunction()
