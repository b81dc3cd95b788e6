// Facet chords from a measuring device (S3 test grinding): the device's CSV export instead of
// typed numbers (docs/calibration.md, "Facet chords from a measuring device").
//
//   # comment lines and blank lines are skipped
//   face,chord_plus_mm,chord_minus_mm[,any other columns]
//   lateral,1.9426,2.0357
//   end-face,1.9216,2.0557
//
// The separator is ',' or ';' (taken from the header line); decimal point '.'; the three named
// columns are required in any order, other columns (time, part, operator, ...) are ignored. Every
// data row must have as many fields as the header. face is lateral or end-face (any case); chords
// are finite, > 0 and at most 1000 mm. Quoted fields are not supported. One row = one test grind.
// Not real-time.
#pragma once

#include <cstddef>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "core/calib/calibrator.hpp"

namespace nccomp::formats::calib {

struct FacetMeasurement {
  core::calib::Face face{core::calib::Face::kLateral};
  double chord_plus_mm{0.0};
  double chord_minus_mm{0.0};
  /// Line of the row in the file (1-based).
  std::size_t line{0};
};

/// Largest export read [bytes] and rows taken: a device file, not a data dump.
inline constexpr std::size_t kMaxFacetExportBytes = 1 << 20;
inline constexpr std::size_t kMaxFacetRows = 10000;

/// Parses an export. Throws std::invalid_argument "<source>:<line>: <why>" (the first problem),
/// also for an export without a data row.
std::vector<FacetMeasurement> parse_facet_export(std::string_view text, const std::string& source);

/// Reads and parses a file (size limit checked before reading it all).
std::vector<FacetMeasurement> read_facet_export(const std::string& path);

}  // namespace nccomp::formats::calib
