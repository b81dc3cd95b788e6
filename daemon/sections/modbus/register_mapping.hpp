// Shared by the bus sections ([modbus], [can]): every [[registers]] entry that names a bus must
// have an offset mapping in that bus's section, and every offset mapping of the bus must belong
// to a [[registers]] entry that names the bus. Either mistake would otherwise show up only at run
// time, as writes the driver drops (an unmapped register) or a map entry nobody ever writes (a
// register list and a map that drifted apart). Not real-time.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"

namespace nccomp::daemon::config {

/// One offset mapping of a bus section: the logical register it writes, and where it is.
struct MappedRegister {
  std::uint32_t register_index{0};
  formats::Where where;
};

/// Reports both directions of a register / mapping mismatch for bus `bus`. `map_key` names the
/// mapping entries in messages (e.g. "[[modbus.offset]] register_index").
inline void check_register_mapping(const Config& config, std::string_view bus,
                                   std::string_view map_key,
                                   const std::vector<MappedRegister>& mapped,
                                   formats::Diagnostics& diag) {
  const auto& regs = registers_section(config).registers;
  std::map<std::uint32_t, const MappedRegister*> by_index;
  for (const MappedRegister& m : mapped) {
    by_index.emplace(m.register_index, &m);
  }
  for (std::size_t i = 0; i < regs.size(); ++i) {
    if (regs[i].bus == bus && by_index.find(static_cast<std::uint32_t>(i)) == by_index.end()) {
      formats::Where w = regs[i].where;
      w.key_path += ".bus";
      diag.error(std::move(w), "register '" + regs[i].spec.name + "' (index " + std::to_string(i) +
                                   ") goes to bus '" + std::string(bus) + "', but no " +
                                   std::string(map_key) + " = " + std::to_string(i) +
                                   " maps it to the NC");
    }
  }
  for (const MappedRegister& m : mapped) {
    if (m.register_index >= regs.size()) {
      diag.error(m.where, std::string(map_key) + " " + std::to_string(m.register_index) +
                              ": no [[registers]] entry has that index (the config declares " +
                              std::to_string(regs.size()) +
                              " registers; index = position in the list)");
    } else if (regs[m.register_index].bus != bus) {
      const auto& r = regs[m.register_index];
      diag.error(m.where, std::string(map_key) + " " + std::to_string(m.register_index) +
                              " is register '" + r.spec.name + "', whose bus is '" + r.bus +
                              "', not '" + std::string(bus) + "'");
    }
  }
}

}  // namespace nccomp::daemon::config
