# nccomp_add_gtest(NAME test_x LABELS unit [TSAN] SOURCES ... LIBS ... [CORE_MODULES base creep])
# Labels: unit (fast, pure), hil (real bus stacks: vcan, loopback Modbus), e2e (virtual NC), fuzz.
# TSAN marks a test as one that matters under ThreadSanitizer (real-time primitives, drivers,
# daemon): only those are built in the tsan preset, which runs all it built. (One label per test:
# gtest_discover_tests in CMake 3.25 cannot carry a list-valued LABELS property.)
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
  if(NOT T_TIMEOUT)
    set(T_TIMEOUT 300)
  endif()
  gtest_discover_tests(${T_NAME}
    PROPERTIES LABELS ${T_LABELS} TIMEOUT ${T_TIMEOUT}
    DISCOVERY_TIMEOUT 60)
endfunction()
