// Positions of every key of a TOML table, so that errors found after parsing (by a core
// validate(), by a module's attach()) point at the key they name: an exact lookup of the key
// path, else its nearest recorded parent ("creep.deflection[0].wear_um[7]" →
// "creep.deflection[0].wear_um" → "creep.deflection[0]" → "creep.deflection" → "creep"), for a
// key that is absent from the file (its default was refused) or an array element. Not real-time.
#pragma once

#include <toml++/toml.h>

#include <map>
#include <string>
#include <string_view>

#include "core/common/config_issue.hpp"
#include "formats/toml/diagnostics.hpp"

namespace nccomp::formats {

/// Key path → position, e.g. "creep.edge.edge_points", "creep.deflection[0].wear_um[2]".
using KeyPositions = std::map<std::string, Where, std::less<>>;

/// Records the position of node (as `path`) and of every key below it (tables and arrays).
void record_positions(const toml::node& node, const std::string& path, KeyPositions& out);

/// The key path one level up: "a.b[2]" → "a.b", "a.b" → "a", "a" → "".
[[nodiscard]] std::string_view parent_key(std::string_view key) noexcept;

/// Where `key` is: the position of the key or of its nearest recorded parent, with `key` as the
/// key path; fallback's position if none of them is recorded.
[[nodiscard]] Where position_of(const KeyPositions& positions, std::string_view key,
                                const Where& fallback);

/// Reports every issue at its key's position.
void report(const KeyPositions& positions, const Where& fallback, const core::ConfigInvalid& e,
            Diagnostics& diag);

}  // namespace nccomp::formats
