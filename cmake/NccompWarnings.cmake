# One warnings function, applied to every project target (style.md).
function(nccomp_set_warnings target)
  get_target_property(type ${target} TYPE)
  if(type STREQUAL "INTERFACE_LIBRARY")
    set(scope INTERFACE)
  else()
    set(scope PRIVATE)
  endif()
  target_compile_options(${target} ${scope}
    -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wsign-conversion -Wdouble-promotion
    -Wfloat-equal -Wnon-virtual-dtor -Wold-style-cast -Wcast-align -Wnull-dereference
    -Wimplicit-fallthrough -Wformat=2)
  # GCC 12 at -O1 with ASan (the dev preset) reports a false maybe-uninitialized inside
  # libstdc++'s std::regex (the std::function moved in _State, GCC PR 105562) wherever a regex is
  # built. Off only in the files that include <regex> (themselves or through a header of ours:
  # tests and a benchmark, no shipped code); every other file, and every file in tsan, release
  # and the packages, keeps the warning.
  if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND CMAKE_CXX_COMPILER_VERSION VERSION_LESS 13
     AND "address" IN_LIST NCCOMP_SANITIZE AND NOT scope STREQUAL "INTERFACE")
    get_target_property(sources ${target} SOURCES)
    get_target_property(source_dir ${target} SOURCE_DIR)
    foreach(src ${sources})
      if(NOT IS_ABSOLUTE "${src}")
        set(src "${source_dir}/${src}")
      endif()
      if(NOT src MATCHES "\\.(cpp|cc)$" OR NOT EXISTS "${src}")
        continue()
      endif()
      file(STRINGS "${src}" includes REGEX "^#include [<\"]")
      set(uses_regex FALSE)
      foreach(line ${includes})
        if(line MATCHES "^#include <regex>")
          set(uses_regex TRUE)
        elseif(line MATCHES "^#include \"([^\"]+)\"")
          set(header "${PROJECT_SOURCE_DIR}/${CMAKE_MATCH_1}")
          if(EXISTS "${header}")
            file(STRINGS "${header}" header_regex REGEX "^#include <regex>")
            if(header_regex)
              set(uses_regex TRUE)
            endif()
          endif()
        endif()
      endforeach()
      if(uses_regex)
        set_property(SOURCE "${src}" TARGET_DIRECTORY ${target} APPEND PROPERTY COMPILE_OPTIONS
                     -Wno-maybe-uninitialized)
      endif()
    endforeach()
  endif()
  # GCC 12 at -O3 (the release preset: optimised build of everything, tests included) reports
  # false positives in test code that no other build reports: -Wrestrict inside libstdc++'s
  # std::string operator+ (GCC PR 105329), and -Wnull-dereference on a pointer a gtest
  # ASSERT_NE(p, nullptr) has checked (the assertion returns, which the inliner does not see).
  # Off for the targets under tests/ in that build only; shipped code, benchmarks and every
  # other build keep both warnings.
  get_target_property(target_dir ${target} SOURCE_DIR)
  if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND CMAKE_CXX_COMPILER_VERSION VERSION_LESS 13
     AND NOT scope STREQUAL "INTERFACE" AND target_dir MATCHES "^${PROJECT_SOURCE_DIR}/tests(/|$)")
    target_compile_options(${target} PRIVATE
                           "$<$<CONFIG:Release>:-Wno-restrict;-Wno-null-dereference>")
  endif()
  if(NCCOMP_WERROR)
    target_compile_options(${target} ${scope} -Werror)
  endif()
endfunction()
