// NC output of a trajectory on a grid: a polyline of short linear moves within a chord
// tolerance (with the chord error actually reached reported), a G-code block list, and a table
// of U corrections against Z at a chosen spacing. Not real-time.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include "core/grind/envelope.hpp"
#include "core/grind/local_rule.hpp"

namespace nccomp::core::grind {

/// Vertices of a polyline through the grid trajectory's points (first and last kept) such that
/// every grid point lies within the band [U_t − below_mm, U_t + above_mm] of it, measured in U
/// (the radial direction, which is what the roll shows). below_mm = 0 gives a gouge-free path:
/// the chords never dip below the trajectory, they only leave up to above_mm of material.
/// Greedy with a slope cone per vertex: O(N). NaN points (no trajectory) are skipped at the ends;
/// a NaN inside throws. max_move_mm > 0 caps a move's Z length.
std::vector<TrajectoryPoint> simplify_polyline(const GridTrajectory& t, double below_mm,
                                               double above_mm, double max_move_mm);

/// Chord error of a polyline against the grid points it covers: the largest deviation below
/// (polyline under the trajectory: the wheel cuts deeper) and above.
struct ChordError {
  double below_mm{0.0};
  double above_mm{0.0};
  [[nodiscard]] double max_mm() const noexcept { return below_mm > above_mm ? below_mm : above_mm; }
};
ChordError chord_error(const GridTrajectory& t, std::span<const TrajectoryPoint> polyline);
/// max of chord_error().
double chord_error_mm(const GridTrajectory& t, std::span<const TrajectoryPoint> polyline);

/// Rounds every vertex to `decimals` places (what the G-code will carry); U upward if
/// `u_up` (keeps a gouge-free polyline gouge-free), to nearest otherwise.
std::vector<TrajectoryPoint> round_vertices(std::span<const TrajectoryPoint> polyline, int decimals,
                                            bool u_up = false);

struct GcodeSpec {
  char z_axis{'Z'};
  char u_axis{'X'};
  double feed_mm_per_min{0.0};  ///< 0: no F word
  int decimals{4};
  int first_block{10};
  int block_step{10};
  std::vector<std::string> header_comments;
};
/// `N10 G90 G01 ...` block list of linear moves through the vertices, one per line.
std::string gcode_blocks(std::span<const TrajectoryPoint> polyline, const GcodeSpec& spec);

struct TableRow {
  double z_mm;
  double u_target_mm;    ///< P(z)
  double u_wheel_mm;     ///< U_T(z)
  double correction_um;  ///< U_T − P: what the NC adds to a path that follows P
};
/// Rows every spacing_mm over the profile's range (the last row at the profile's end).
std::vector<TableRow> correction_table(const GridTrajectory& t, const UniformProfile& p,
                                       double spacing_mm);

/// Max |U_T(Z_t) − table interpolation| over the grid points inside the profile's range: the
/// error of an NC that interpolates the table linearly.
double table_interpolation_error_mm(const GridTrajectory& t, const UniformProfile& p,
                                    std::span<const TableRow> table);

/// Linear interpolation of a grid trajectory (end values outside; NaN propagates).
double interpolate(const GridTrajectory& t, double z_mm) noexcept;

}  // namespace nccomp::core::grind
