// The bus map ncsim serves: the daemon's map file (ncsim.bus_map / can_bus_map) and the extra
// files of ncsim.bus_map_extra / can_bus_map_extra (e.g. flag registers the reference map lacks),
// merged the way the daemon merges its `include`d files: tables key by key, arrays of tables
// (e.g. [[modbus.offset]]) appended in file order, anything else defined twice is an error naming
// both places. Moved nodes keep their file and line, so the driver's parser still names the
// file a bad entry came from. Not real-time.
#pragma once

#include <toml++/toml.h>

#include <string>
#include <vector>

namespace nccomp::sim::ncsim {

/// Parses the map and appends the extras (texts[i] read from files[i]). Throws
/// formats::DiagnosticsError with file:line:column.
toml::table merged_bus_map(const std::string& text, const std::string& file,
                           const std::vector<std::string>& extra_texts,
                           const std::vector<std::string>& extra_files);

}  // namespace nccomp::sim::ncsim
