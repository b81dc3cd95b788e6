// Configuration of the creeping wear correction (S0). The structs map 1:1 onto the `[creep]`
// TOML table documented in docs/creep.md: one struct per sub-table, one field per key, units in
// the names. validate() is the single place where a config is judged; it names each offending key
// by its TOML path (e.g. "creep.edge.edge_points") in a core::ConfigIssue.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/common/limiter.hpp"
#include "core/common/profile.hpp"
#include "core/common/types.hpp"

namespace nccomp::core::creep {

/// Creeps that can be in progress at once (superposed measurements, S0 feature 2).
inline constexpr std::size_t kMaxCreeps = 8;
/// Rows of a deflection table (wear → deflection).
inline constexpr std::size_t kMaxDeflectionRows = 16;
/// Smaller-tool transitions (creep-in / creep-out regions) per config.
inline constexpr std::size_t kMaxTransitions = 16;
/// Measurements kept for fitting the wear rate (adaptive interval, predictive creeping).
inline constexpr std::size_t kMaxRateWindow = 8;
/// Upper bound of [creep.estimator] family_min_tools.
inline constexpr std::size_t kMaxFamilyMinTools = 1000;
/// Slope continuity at a measurement while the offset moves (superpose): the new increment's
/// profile is entered with zero slope over this fraction of its span (its steepest slope is then
/// 1 / (1 − kBlendFraction / 2) = 1.11 times the profile's); a folded creep's slope fades out over
/// the same fraction; the prediction's rate blends to the new fitted rate over this fraction of
/// the path since the previous measurement.
inline constexpr double kBlendFraction = 0.2;

/// What the creep length is measured in (S0 feature 1, claims 2–4).
enum class CreepBasis : std::uint8_t {
  kPath = 0,      // over creep_length_mm of cut path
  kTime = 1,      // over creep_time_s of cutting time
  kRateTime = 2,  // at creep_rate_um_per_min (duration = |wear| / rate, per support point)
  kRatePath = 3,  // at creep_rate_um_per_mm of cut path (length = |wear| / rate, per point)
};

/// What happens when a measurement arrives while a creep is unfinished (S0 feature 2).
enum class UnfinishedPolicy : std::uint8_t {
  kSuperpose = 0,  // keep creeping, the new increment creeps on top (logged as info)
  kWarn = 1,       // superpose and raise the warning register
  kAlarm = 2,      // stop applying (offsets frozen), raise the alarm register
};

/// Cutter geometry: where the edge support points lie.
enum class ToolShape : std::uint8_t {
  kTip = 0,       // one value (wear at the tip / the envelope's maximum)
  kBall = 1,      // ball-end mill: support points at engagement angles 0..90°
  kBullNose = 2,  // bull-nose (torus) mill: corner radius points at 0..90°
};

/// Where the surface normal (and so the engagement angle) comes from (S0 feature 4).
enum class NormalSource : std::uint8_t {
  kAxisSample = 0,  // AxisSample::normal when has_normal, else the fallback
  kToolpath = 1,    // table program path → normal (toolpath file), else the fallback
  kNone = 2,        // always the fallback: the mean wear along the edge on one channel
};

/// Output channels: logical offsets this module drives.
enum class Channel : std::uint8_t { kX = 0, kY = 1, kZ = 2, kRadius = 3, kLength = 4 };
inline constexpr std::size_t kChannelCount = 5;

/// How the correction reaches the NC.
enum class OutputMode : std::uint8_t {
  kAxes = 0,           // along the surface normal, split into X/Y/Z axis offsets
  kToolRegisters = 1,  // split into the tool's radius-wear and length-wear registers
};

enum class IntervalBasis : std::uint8_t {
  kOff = 0,
  kPath = 1,      // every interval_mm of cut path
  kTime = 2,      // every interval_s of cutting time
  kAdaptive = 3,  // target_increment_um / fitted wear rate, within [min, max]_interval_mm
  kMaterial = 4,  // every interval_mm3 of material removed (cross-section × cut path)
  /// When the estimator's σ predicted to the cut path now exceeds max_sigma_um, within
  /// [min, max]_interval_mm (needs [creep.estimator]).
  kUncertainty = 5,
};

/// Where the removal cross-section of the interval basis "material" comes from.
enum class RemovalSource : std::uint8_t {
  kConstant = 0,  // removal_mm3_per_mm everywhere
  kToolpath = 1,  // the toolpath file's removal_mm2 column by program position (constant outside)
};

/// Without a surface normal: on which side of the feed direction the material lies (as seen
/// along the feed with the tool axis pointing up), i.e. where the lateral deflection
/// compensation pushes the tool. kNone: no lateral compensation without a normal (mode axes).
enum class MaterialSide : std::uint8_t { kNone = 0, kLeft = 1, kRight = 2 };

enum class ExcessivePolicy : std::uint8_t {
  kStop = 0,    // alarm: stop, nothing applied
  kSister = 1,  // warning: request the sister tool, nothing applied to the worn tool
};

/// [creep.edge]
struct EdgeConfig {
  ToolShape tool_shape{ToolShape::kBall};
  /// Support points along the edge, equally spaced in engagement angle 0..90° (1 for kTip).
  std::size_t edge_points{1};
  NormalSource normal_source{NormalSource::kAxisSample};
  /// Tool axis (unit vector, machine coordinates): the engagement angle is acos(n · axis).
  std::array<double, 3> tool_axis{0.0, 0.0, 1.0};
  /// Channel that carries the mean wear when no normal is known, and its sign.
  Channel fallback_channel{Channel::kZ};
  double fallback_sign{-1.0};
  /// Lateral deflection without a normal (mode axes): across the feed direction toward this
  /// side. In mode tool_registers it goes on the radius register (no direction needed).
  MaterialSide material_side{MaterialSide::kNone};
};

/// One row of the toolpath file: program path position → unit surface normal and / or the
/// removal cross-section (a_e·a_p) of the segment that starts here.
struct ToolpathRow {
  double path_mm{0.0};
  std::array<double, 3> normal{0.0, 0.0, 1.0};
  /// Removal cross-section [mm²] from this row's path_mm to the next row's (NaN: no column).
  double removal_mm2{kNaN};
};

/// The parsed toolpath file: which columns it has, and its rows (path strictly increasing).
struct ToolpathTable {
  bool has_normals{false};
  bool has_removal{false};
  std::vector<ToolpathRow> rows;
};

/// [creep.output]
struct OutputConfig {
  OutputMode mode{OutputMode::kAxes};
  /// Logical register index per channel X, Y, Z, radius wear, length wear (-1 = not written).
  std::array<std::int32_t, kChannelCount> channel_register{-1, -1, -1, -1, -1};
  /// Sign of a wear correction in the NC's radius/length wear registers: a worn tool is smaller,
  /// which most NCs (Fanuc, Sinumerik) take as a negative wear value.
  double tool_register_sign{-1.0};
  /// Flag registers (value 0 or 1; -1 = not written).
  std::int32_t warning_register{-1};
  std::int32_t alarm_register{-1};
  std::int32_t measurement_due_register{-1};
  std::int32_t tool_change_register{-1};
  /// Program path [µm] where a sister tool should restart (-1 = not written).
  std::int32_t restart_path_register{-1};
  /// An offset is written when it moved by at least this much since the last write [µm], or
  /// when it reaches its target.
  double write_resolution_um{0.1};
  /// Every value is re-sent at this interval, so a lost write heals [s]; 0 = never.
  double refresh_interval_s{1.0};
  /// A measurement request restored high at start-up while the NC still holds it high is
  /// written 0 for this long and then 1 again (WearCompensator::rearm_request()), so that an NC
  /// that reacts to the rising edge sees one [s]; 0 = never.
  double request_rearm_s{1.0};
};

/// [creep.interval]
struct IntervalConfig {
  IntervalBasis basis{IntervalBasis::kOff};
  double interval_mm{1000.0};
  double interval_s{600.0};
  double target_increment_um{5.0};
  double min_interval_mm{100.0};
  double max_interval_mm{5000.0};
  /// Removal cross-section [mm²] = removed volume per mm of cut path: everywhere (source
  /// constant), or where the toolpath file has no value (outside its rows, no program path).
  double removal_mm3_per_mm{0.025};
  RemovalSource removal_source{RemovalSource::kConstant};
  double interval_mm3{50.0};
  /// basis uncertainty: a measurement is requested when the estimate's standard deviation
  /// predicted to the cut path now exceeds this [µm].
  double max_sigma_um{2.0};
};

/// [creep.tool_life]
struct ToolLifeConfig {
  /// Total wear (max over the edge) at which the sister tool is requested [µm]; 0 = off.
  double wear_limit_um{0.0};
  /// Increment between two measurements that marks the tool excessively worn [µm]; 0 = off.
  double excessive_increment_um{0.0};
  ExcessivePolicy on_excessive{ExcessivePolicy::kStop};
  /// A jump beyond implausible_factor × the expected increment is a broken / mis-measured tool.
  double implausible_factor{5.0};
  /// Floor of the expected increment (before a rate is known, or for slow wear) [µm].
  double min_expected_increment_um{10.0};
  /// Wear may shrink by this much between measurements (measurement noise) [µm].
  double noise_um{2.0};
};

/// [creep.predict]: predictive creeping (beyond the seed).
struct PredictConfig {
  bool enabled{false};
  /// Measurements used to fit the wear rate (2..kMaxRateWindow): more averages the measuring
  /// noise, fewer follows a changing wear rate sooner.
  std::size_t window{5};
  /// Cap on the predicted growth between two measurements [µm].
  double max_um{20.0};
};

/// [creep.estimator]: a Kalman filter per support point (issue 22) estimates the wear and its
/// rate per mm of cut path from the noisy laser measurements; the creep (and the prediction)
/// then goes toward the estimate instead of the raw measurement. Off: today's strategies.
struct EstimatorConfig {
  bool enabled{false};
  /// Standard deviation of one laser measurement [µm].
  double measurement_sigma_um{1.0};
  /// Process noise: random walk of the wear itself, the standard deviation of the change the
  /// rate does not explain over 1 m of cut path [µm per sqrt(m)].
  double wear_noise_um_per_sqrt_m{0.0};
  /// Random walk of the wear rate: its standard deviation after 1 m of cut path
  /// [µm/mm per sqrt(m)].
  double rate_noise_um_per_mm_per_sqrt_m{0.0005};
  /// Prior of a new tool's wear rate: its standard deviation [µm/mm] (the mean is 0, or the
  /// rate fitted before the estimator was switched on).
  double initial_rate_sigma_um_per_mm{0.01};
  /// A measurement whose innovation exceeds this many standard deviations of the predicted one
  /// is refused (plausibility alarm 23, nothing changes); 0 = no gate.
  double gate_sigmas{5.0};
  /// Learn the rate's process noise from the tool family's finished tools (every tool of this
  /// module; a tool is finished when a sister replaces it): a new tool's filter starts with the
  /// family's estimate once family_min_tools tools are finished, with
  /// rate_noise_um_per_mm_per_sqrt_m until then.
  bool learn_rate_noise{false};
  std::size_t family_min_tools{3};
  /// Learn a new tool's rate prior from the family: each finished tool adds its start rate (the
  /// least-squares line through the origin over its measurements within family_prior_path_mm
  /// of cut path, at least its first); a new tool's filter starts from their mean and spread
  /// instead of 0 ± initial_rate_sigma_um_per_mm once family_min_tools (at least 2) are finished.
  bool learn_rate_prior{false};
  double family_prior_path_mm{1000.0};
  /// Adapt the rate's process noise within a tool's life from the filter's normalised innovation
  /// squares (estimation::adapt_process_noise()): starts at the configured or learned value, moves
  /// with an exponential window of adapt_window_measurements measurements, and stays within
  /// [min_rate_noise_um_per_mm_per_sqrt_m, max_rate_noise_um_per_mm_per_sqrt_m].
  bool adapt_rate_noise{false};
  double adapt_window_measurements{20.0};
  double min_rate_noise_um_per_mm_per_sqrt_m{0.00005};
  double max_rate_noise_um_per_mm_per_sqrt_m{0.005};
};

/// [creep.entry]: tangential entry of a sister tool and retract / re-feed (claims 14, feature 11).
struct EntryConfig {
  /// Positive offset (away from the surface) a sister tool starts with [µm]; 0 = off.
  double sister_offset_um{0.0};
  /// Path over which that offset creeps to zero [mm].
  double sister_length_mm{10.0};
  /// How far before the last measurement's program position the sister restarts [mm].
  double sister_restart_back_mm{0.0};
  /// Retract after a measurement or tool change, re-fed over refeed_length_mm [µm]; 0 = off.
  double retract_um{0.0};
  double refeed_length_mm{5.0};
};

/// [[creep.deflection]]: wear-dependent over-compensation of a long tool (claims 15, 16).
struct DeflectionTable {
  /// Tool number (0 = every tool without its own table).
  std::int32_t tool{0};
  std::vector<double> wear_um;
  std::vector<double> normal_um;
  std::vector<double> lateral_um;
};

/// [[creep.transition]]: smaller tool next to a surface cut by a larger tool (feature 10), by
/// program path position of that tool.
struct Transition {
  std::int32_t tool{0};
  double start_path_mm{0.0};
  double end_path_mm{0.0};
  /// Offset above the surface at start_path_mm, creeping to 0 over in_length_mm [µm].
  double in_offset_um{0.0};
  double in_length_mm{0.0};
  /// Offset growing from 0 to out_offset_um over the last out_length_mm before end_path_mm [µm].
  double out_offset_um{0.0};
  double out_length_mm{0.0};
};

/// [creep]
struct CreepConfig {
  CreepBasis creep_basis{CreepBasis::kPath};
  double creep_length_mm{50.0};
  double creep_time_s{60.0};
  double creep_rate_um_per_min{1.0};
  double creep_rate_um_per_mm{0.02};
  ProfileShape profile{ProfileShape::kLinear};
  /// Only for profile = table: f at equally spaced progress, 0 → 1, non-decreasing.
  std::vector<double> profile_table;
  UnfinishedPolicy on_unfinished{UnfinishedPolicy::kSuperpose};
  /// Creeps in progress at once (1..kMaxCreeps); beyond it the oldest is folded into the newest.
  std::size_t max_creeps{4};

  EdgeConfig edge{};
  /// Filled by the loader from creep.edge.toolpath_file: normals (normal_source = toolpath)
  /// and / or removal cross-sections (interval removal_source = toolpath), sorted by path_mm.
  ToolpathTable toolpath;
  OutputConfig output{};
  LimiterConfig limiter{};
  IntervalConfig interval{};
  ToolLifeConfig tool_life{};
  PredictConfig predict{};
  EstimatorConfig estimator{};
  EntryConfig entry{};
  std::vector<DeflectionTable> deflection;
  std::vector<Transition> transitions;
};

/// Throws core::ConfigInvalid (a std::invalid_argument) with every refused key (TOML path) and
/// why. Not real-time.
void validate(const CreepConfig& config);

/// Engagement angle [deg] of support point i of n (0° = tool axis / tip, 90° = side).
inline double support_angle_deg(std::size_t i, std::size_t n) {
  return n < 2 ? 0.0 : 90.0 * static_cast<double>(i) / static_cast<double>(n - 1);
}

}  // namespace nccomp::core::creep
