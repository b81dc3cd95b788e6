// Host of the precompiled header shared by the GoogleTest executables (tests/support/CMakeLists.txt):
// the header is built once for this target and reused by every nccomp_add_gtest target.
