// toml++'s implementation, compiled in the `fuzz` preset only (cmake/NccompFuzz.cmake): from the
// same Debian headers as libtomlplusplus.so, but with the fuzzer's coverage, the sanitizers and
// toml++'s own assertions.
#define TOML_IMPLEMENTATION
#include <toml++/toml.h>
