// Any bytes as ncsim's config text (the first line, if it starts with "--set ", as an override),
// and the same bytes as a lock-step datagram: errors are ConfigError / false, never a crash.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "sim/ncsim/config.hpp"
#include "sim/ncsim/lockstep.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace nccomp::sim::ncsim;
  std::string text(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> sets;
  if (text.rfind("--set ", 0) == 0) {
    const auto nl = text.find('\n');
    sets.push_back(text.substr(6, nl == std::string::npos ? std::string::npos : nl - 6));
    text = nl == std::string::npos ? "" : text.substr(nl + 1);
  }
  try {
    (void)parse_sim_config(text, "fuzz.toml", "/nonexistent", sets, false);
  } catch (const ConfigError&) {
  }
  LockstepMessage m{};
  std::string why;
  (void)parse_lockstep_message(data, size, m, why);
  return 0;
}
