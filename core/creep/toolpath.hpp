// The toolpath file of [creep.edge] toolpath_file: per program position the surface normal (for
// NCs that do not publish one with the axis sample: S0 claim 10, the engagement point from the
// machining program's surface-normal vectors) and / or the removal cross-section of the segment
// that starts there (measurement interval by material removed).
//
// Format: CSV with one of the headers
//   path_mm,nx,ny,nz
//   path_mm,nx,ny,nz,removal_mm2
//   path_mm,removal_mm2
// one row per program position, path_mm strictly increasing, (nx, ny, nz) the outward unit surface
// normal (|n| within 1 % of 1; normalised), removal_mm2 the cross-section a_e·a_p [mm²] removed
// from this row's path_mm up to the next row's (>= 0). Blank lines and lines starting with '#'
// are ignored; CRLF line ends are accepted.
#pragma once

#include <cstddef>
#include <string_view>
#include <vector>

#include "core/creep/config.hpp"

namespace nccomp::core::creep {

/// Largest number of rows accepted (bounds memory for a hostile file).
inline constexpr std::size_t kMaxToolpathRows = 1'000'000;
/// Largest accepted removal cross-section [mm²] (catches a unit mistake, e.g. mm³ or µm²).
inline constexpr double kMaxRemovalMm2 = 1e4;

/// Parses the text of a toolpath file. Throws std::invalid_argument "<source>:<line>: <what>" on
/// the first problem. Not real-time (core stays pure: the caller reads the file).
ToolpathTable parse_toolpath(std::string_view text, std::string_view source);

}  // namespace nccomp::core::creep
