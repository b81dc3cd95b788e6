// Checkpoint plan of S1 (seeds.md, S1 method A step 2 and method B step 5): probing positions on
// a side wall at several heights, equally spaced by a depth step, near the corners of the contour
// (the intersections of its sub-curves), plus extra points in locally flexible regions, in
// machining order. Not real-time: planning runs in the operator tool and at configure time.
//
// Conventions:
// - The contour is a polyline in XY [mm], given in the machining direction, at height
//   contour_z_mm. Closed contours are closed implicitly (last point → first point).
// - material says on which side of the contour the part is: left / right of the machining
//   direction, or inside / outside of a closed contour. The "air side" normal n_air points away
//   from the material; the probe moves along −n_air (into the wall).
// - α is the wall's normal inclination: a positive α is a draft that makes the material grow
//   toward the bottom, so at height z the wall lies (contour_z_mm − z)·tan α further toward the
//   air side than the contour. α belongs to the contour's segments: a vertex that gives alpha_deg
//   sets it for the segments from that vertex on, until a later vertex gives another; segments
//   before the first such vertex have wall_angle_deg. So each sub-curve (or any region) can have
//   its own α, and every checkpoint carries the α of the segment it lies on.
// - A corner is the intersection of two sub-curves: a vertex marked corner (e.g. the tangent
//   junction of a line and an arc, which no turn angle reveals), or, unless it is marked as no
//   corner, a vertex where the direction turns by more than corner_angle_deg. Each corner gets a
//   point corner_offset_mm before it and one corner_offset_mm after it along the contour (at the
//   corner itself the normal is undefined or the wall changes its shape).
// - The finishing program is assumed to cut the contour once per level, top level first, each
//   level starting at the contour's first point; between levels it travels level_link_mm. This
//   gives each checkpoint its program path position path_mm (used by trigger = "path").
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

namespace nccomp::core::checkpoint {

struct Point2 {
  double x_mm{0.0};
  double y_mm{0.0};
};

/// Whether a contour vertex is a sub-curve boundary (a corner of the plan).
enum class CornerMark : std::uint8_t {
  kAuto = 0,      // a corner if the contour turns there by more than corner_angle_deg
  kCorner = 1,    // always a corner (sub-curve boundary), e.g. a tangent line → arc junction
  kNoCorner = 2,  // never a corner (e.g. a coarse polyline of an arc)
};

/// A vertex of the contour polyline with the attributes the contour CSV / config may give it.
struct ContourPoint {
  double x_mm{0.0};
  double y_mm{0.0};
  /// Wall angle α [deg] from this vertex on (until a later vertex gives another); NaN = not given
  /// (the previous vertex's α carries on; before the first given one, wall_angle_deg).
  double alpha_deg{std::numeric_limits<double>::quiet_NaN()};
  CornerMark corner{CornerMark::kAuto};
};

enum class MaterialSide : std::uint8_t { kLeft = 0, kRight = 1, kInside = 2, kOutside = 3 };

/// A flexible region along the contour [from_mm, to_mm] (contour arc length) that gets a
/// checkpoint every spacing_mm.
struct ExtraRegion {
  double from_mm{0.0};
  double to_mm{0.0};
  double spacing_mm{0.0};
};

/// Largest number of checkpoints in a plan (Fanuc offset memory C holds 400 offsets; 4096 leaves
/// room for NCs with larger tables while bounding the real-time state).
inline constexpr std::size_t kMaxCheckpoints = 4096;
inline constexpr std::size_t kMaxContourPoints = 100000;
inline constexpr std::size_t kMaxLevels = 1000;

struct PlanConfig {
  std::vector<ContourPoint> contour;
  bool closed{true};
  MaterialSide material{MaterialSide::kInside};
  /// Height at which the contour is given [mm].
  double contour_z_mm{0.0};
  /// First (highest) probing level and lowest level [mm]; levels every depth_step_mm downward.
  double z_start_mm{-2.0};
  double z_end_mm{-20.0};
  double depth_step_mm{5.0};
  /// Wall normal inclination α [deg], |α| < 89, where the contour's vertices give none.
  double wall_angle_deg{0.0};
  /// Direction change above which a vertex is a corner [deg], in (0, 180).
  double corner_angle_deg{20.0};
  /// Distance of the corner points from the corner along the contour [mm].
  double corner_offset_mm{5.0};
  /// Extra checkpoints at these contour positions [mm of arc length from the first point].
  std::vector<double> extra_points_mm;
  std::vector<ExtraRegion> extra_regions;
  /// Radius of the finishing tool [mm]: the tool centre passes the checkpoint at
  /// wall point + n_air·tool_radius_mm (the trigger position of trigger = "position").
  double tool_radius_mm{0.0};
  /// Probe ball radius r [mm] and its approach distance from the wall [mm].
  double ball_radius_mm{1.0};
  double probe_approach_mm{5.0};
  /// Program path position of the first level's start [mm], and the path between the end of one
  /// level and the start of the next [mm]; a negative link means "depth_step_mm" (a plunge).
  double program_path_start_mm{0.0};
  double level_link_mm{-1.0};
};

enum class CheckpointSource : std::uint8_t { kCorner = 0, kExtra = 1 };

struct Checkpoint {
  /// Index in machining order (0-based); register = register_base + id.
  std::int32_t id{0};
  std::int32_t level{0};
  CheckpointSource source{CheckpointSource::kCorner};
  /// Arc length along the contour [mm] and program path position [mm].
  double s_mm{0.0};
  double path_mm{0.0};
  /// Wall point at this level [mm].
  double x_mm{0.0};
  double y_mm{0.0};
  double z_mm{0.0};
  /// Unit probing direction in XY (into the wall, −n_air).
  double dir_x{0.0};
  double dir_y{0.0};
  /// Wall normal inclination α [deg] of the contour segment this point lies on.
  double alpha_deg{0.0};
  /// Tool centre when the finishing tool cuts this point [mm].
  double tool_x_mm{0.0};
  double tool_y_mm{0.0};
  /// Probe start point: wall point + n_air·(ball radius + approach) [mm].
  double start_x_mm{0.0};
  double start_y_mm{0.0};
  /// The pass of this level along the contour [mm] (the contour length; 0 = unknown) and whether
  /// it is closed (the pass ends where it started). The compensator keeps creep within a level:
  /// on a closed pass it ramps from the level's last checkpoint through the seam to its first,
  /// on an open (or unknown) one it holds the first / last value before / after them. The
  /// level's pass starts at program path position path_mm − s_mm.
  double pass_length_mm{0.0};
  bool closed{false};
};

struct Plan {
  std::vector<Checkpoint> checkpoints;
  std::vector<double> levels_z_mm;
  /// Contour arc length [mm] and the number of corners found.
  double contour_length_mm{0.0};
  std::size_t corner_count{0};
  /// Corners that are sub-curve boundaries marked in the contour (CornerMark::kCorner).
  std::size_t marked_corner_count{0};
  /// Smallest and largest α of the checkpoints [deg].
  double alpha_min_deg{0.0};
  double alpha_max_deg{0.0};
};

/// Validates the config and builds the plan. Throws core::ConfigInvalid (a std::invalid_argument)
/// naming the key (e.g. "checkpoints.depth_step_mm") and why, with the offending value.
Plan make_plan(const PlanConfig& config);

/// Parses a contour CSV: a header row starting with `x_mm,y_mm`, optionally followed by the
/// columns `alpha_deg` and / or `corner` (in either order), then one vertex per row with as many
/// fields as the header; blank lines and lines starting with '#' are skipped. `alpha_deg`: the
/// wall angle from this vertex on (empty = carried on from the previous vertex). `corner`: 1 =
/// the vertex is a sub-curve boundary, 0 = never a corner, empty = by the turn angle.
/// Throws std::invalid_argument as "<source>:<line>: <reason>".
std::vector<ContourPoint> parse_contour_csv(std::string_view text, std::string_view source);

const char* material_side_name(MaterialSide side) noexcept;

}  // namespace nccomp::core::checkpoint
