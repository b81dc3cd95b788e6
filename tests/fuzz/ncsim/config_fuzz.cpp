// Any bytes as ncsim's config text (the first line, if it starts with "--set ", as an override),
// as an extra file of the bus map (ncsim.bus_map_extra: merged into a small map, then the
// driver's parser), and as a lock-step datagram: errors are exceptions / false, never a crash.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "drivers/modbus/config.hpp"
#include "sim/ncsim/bus_map.hpp"
#include "sim/ncsim/config.hpp"
#include "sim/ncsim/lockstep.hpp"

namespace {

constexpr const char* kMap =
    "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = 1502\n"
    "[modbus.axis]\nx_mm = { table = \"input\", address = 0, type = \"int32\", scale = 0.0001 }\n"
    "[[modbus.offset]]\nregister_index = 0\naddress = 200\ntype = \"int32\"\nscale = 0.1\n";

}  // namespace

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
  } catch (const nccomp::formats::DiagnosticsError&) {
  }
  try {
    const toml::table root = merged_bus_map(kMap, "map.toml", {text}, {"extra.toml"});
    if (const toml::table* m = root["modbus"].as_table()) {
      (void)nccomp::drivers::modbus::parse_modbus_table(*m, "map.toml");
    }
  } catch (const std::exception&) {
  }
  LockstepMessage m{};
  std::string why;
  (void)parse_lockstep_message(data, size, m, why);
  return 0;
}
