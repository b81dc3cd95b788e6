# libFuzzer build (preset `fuzz`, NCCOMP_LIBFUZZER=ON): clang only. Every project object is
# instrumented for coverage (-fsanitize=fuzzer-no-link); the fuzz targets link libFuzzer's own
# main (-fsanitize=fuzzer) instead of tests/fuzz/fuzz_driver.cpp (tests/fuzz/CMakeLists.txt).
option(NCCOMP_LIBFUZZER "Link the fuzz targets with libFuzzer (clang) for coverage-guided runs" OFF)
if(NOT NCCOMP_LIBFUZZER)
  return()
endif()
if(NOT CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
  message(FATAL_ERROR "NCCOMP_LIBFUZZER needs clang (preset `fuzz`: /usr/bin/clang++-14)")
endif()
add_compile_options(-fsanitize=fuzzer-no-link)
# C++14 sized deallocation, on in g++ and off by default in clang 14: the same operators (and the
# allocation counter's replacements of them) in both.
add_compile_options(-fsized-deallocation)

# toml++ compiled from Debian's headers into the build instead of linking libtomlplusplus.so:
# the shared library is neither instrumented nor built with assertions, so a coverage-guided run
# would see no coverage inside the TOML parser and none of its assertions. Defining the imported
# target first makes find_package(tomlplusplus) keep it.
add_library(nccomp_tomlplusplus_impl STATIC ${PROJECT_SOURCE_DIR}/tests/fuzz/tomlplusplus_impl.cpp)
target_compile_definitions(nccomp_tomlplusplus_impl PUBLIC TOML_HEADER_ONLY=0)
add_library(tomlplusplus::tomlplusplus INTERFACE IMPORTED GLOBAL)
target_link_libraries(tomlplusplus::tomlplusplus INTERFACE nccomp_tomlplusplus_impl)
