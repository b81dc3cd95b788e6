// The toolpath normal file of [creep.edge] toolpath_file: the surface normal along the program
// path, for NCs that do not publish a normal with the axis sample (S0 claim 10: the engagement
// point from the machining program's surface-normal vectors).
//
// Format: CSV, header `path_mm,nx,ny,nz`, one row per program position, path_mm strictly
// increasing, (nx, ny, nz) the outward unit surface normal (|n| within 1 % of 1; normalised).
// Blank lines and lines starting with '#' are ignored; CRLF line ends are accepted.
#pragma once

#include <cstddef>
#include <string_view>
#include <vector>

#include "core/creep/config.hpp"

namespace nccomp::core::creep {

/// Largest number of rows accepted (bounds memory for a hostile file).
inline constexpr std::size_t kMaxToolpathRows = 1'000'000;

/// Parses the text of a toolpath normal file. Throws std::invalid_argument "<source>:<line>:
/// <what>" on the first problem. Not real-time (core stays pure: the caller reads the file).
std::vector<ToolpathNormal> parse_toolpath_normals(std::string_view text, std::string_view source);

}  // namespace nccomp::core::creep
