// ncsim's configuration (sim/ncsim/config/*.toml, config/ncsim.toml), parsed by config.hpp.
// One struct per TOML table, units in the names; docs/ncsim.md lists every key.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/checkpoint/plan.hpp"
#include "sim/ncsim/model.hpp"

namespace nccomp::sim::ncsim {

enum class ProgramKind : std::uint8_t { kMouldFace, kSideWall, kRoll, kTouch };
enum class BusKind : std::uint8_t { kModbus, kCan };

/// [nc]: the NC's offset registers and how they act on the cut (logical register indices, as in
/// the bus map's offset entries; -1 = the NC has no such register).
struct NcConfig {
  /// Time from an accepted offset write to the value being in force [s].
  double latency_s{0.02};
  /// The NC's own range check: |value| beyond this is refused [µm].
  double offset_limit_um{500.0};
  std::int32_t tool_length_register{0};
  std::int32_t tool_radius_register{1};
  std::int32_t axis_register[3]{6, 7, 8};
  /// First register of the S1 checkpoint table and how many there are (table mode).
  std::int32_t checkpoint_base_register{2};
  std::int32_t checkpoint_register_count{4};
  /// A non-zero value written here asks the NC to measure the tool at the laser (-1 = none).
  std::int32_t measure_request_register{-1};
  /// Registers whose non-zero value is an alarm / warning the NC shows: every change from 0 to a
  /// non-zero value is one alarm seen (alarms_seen and "alarms" in result.json).
  std::vector<std::int32_t> alarm_registers{};
  /// Tool number in the spindle.
  std::int32_t tool{1};
};

/// [program.mould_face]: a gently curved face finished in raster passes with a ball-end mill.
struct MouldFaceConfig {
  double size_x_mm{60.0};
  double size_y_mm{30.0};
  /// Heights of the two parabolic bulges over X and over Y [mm].
  double bulge_x_mm{3.0};
  double bulge_y_mm{1.5};
  /// Height of the face's lowest corner [mm] (above the clamp: see effects.pushoff.clamp_z_mm).
  double base_z_mm{0.0};
  double stepover_mm{1.0};
  double feed_mm_per_min{3000.0};
  double ball_radius_mm{3.0};
  /// Laser measurement every this much cut path [mm]; 0 = only when the daemon asks.
  double measure_interval_mm{1000.0};
  /// Duration of a trip to the laser and back [s].
  double laser_trip_s{4.0};
  /// Laser position [mm] (where the axes are during the trip).
  Vec3 laser_position_mm{-50.0, 0.0, 50.0};
  /// In-process gauging after each part: the probe touches this many points of the finished
  /// face (0 = no probe cycle), at mid-X on passes spread evenly from the first to the last.
  std::int32_t probe_points{0};
  /// Time per probed point [s].
  double probe_time_s{1.0};
  /// At each part start the tool waits this long at the first pass's start, not cutting (the
  /// approach), before the first cut [s]; 0 = the first cut starts with the part.
  double approach_s{0.0};
};

/// [program.side_wall]: a side wall finished level by level, probed at the checkpoints of the
/// [checkpoints] plan, part after part.
struct SideWallConfig {
  /// File with the [checkpoints] table (relative to the ncsim config); parsed into `plan`.
  std::string checkpoints_file{};
  core::checkpoint::PlanConfig plan{};
  double feed_mm_per_min{2000.0};
  /// Time per probed checkpoint [s].
  double probe_time_s{1.0};
  /// Approach from the part start to the first cut (not cutting, the program path at its start)
  /// [s]: an offset the daemon writes at the part start is in force before the tool cuts.
  double approach_s{0.5};
  /// The NC program selects the table register of the nearest checkpoint (table mode) in
  /// addition to the live radius-wear register.
  bool table_registers{false};
};

/// [program.touch]: touch cycles on the reference disk (reference probe) and on the test body
/// (machine probe) while the machine warms up, and the test grinds of the initial calibration
/// (S3). Fixed plan (request_register = -1): reference touches, the nominal set, then a set every
/// cycle_interval_s. With a request register the program does what the daemon's calibrator asks
/// (core::calib::RequestCode): reference touches, lateral / end-face test grinds with the X
/// offset in force (the chords go to the measuring device's export), nominal touches,
/// recalibration sets.
struct TouchConfig {
  /// Recalibration cycles after the nominals, and their spacing [s]: the run lasts
  /// cycles × cycle_interval_s after the warm-up start (both modes).
  std::int32_t cycles{6};
  double cycle_interval_s{300.0};
  /// Reference disk: centre [mm], centre distance at the lateral trigger (radius) [mm] and at the
  /// axial X trigger (A at 90°) [mm].
  Vec3 reference_center_mm{100.0, 50.0, 40.0};
  double reference_radius_mm{25.0};
  double reference_axial_radius_mm{30.0};
  /// Test body: centre [mm] and the centre distance at the trigger [mm] (X lateral, Y, Z) and
  /// along the stylus (X axial).
  Vec3 body_center_mm{200.0, 50.0, 40.0};
  double body_radius_mm{10.0};
  double body_axial_radius_mm{12.0};
  /// Seconds between two touches of one set.
  double touch_time_s{2.0};
  /// Touches per slot (X lateral, X axial, Y, Z) in one set.
  std::int32_t touches_per_axis{1};
  /// true: trigger positions in program coordinates (machine position − the axis offset in
  /// force); false: machine coordinates (the offsets do not enter).
  bool program_coordinates{true};
  /// Static errors of the machine at the calibration positions [µm]: X (lateral), Y, Z, and X
  /// along the stylus. An error e displaces the tool by +e; the offset that cancels it is −e.
  Vec3 axis_error_um{0.0, 0.0, 0.0};
  double x_axial_error_um{0.0};
  /// The reference probe triggers this much late in the approach direction [µm].
  double reference_pretravel_um{0.0};
  double reference_axial_pretravel_um{0.0};
  /// Test grinding: blank radius, nominal facet depth, the measuring device's noise (σ of a
  /// chord), and the time a grind and its measurement take.
  double blank_radius_mm{5.0};
  double grind_depth_mm{0.1};
  double chord_noise_um{0.5};
  double grind_time_s{300.0};
  /// The measuring device's CSV export (face,chord_plus_mm,chord_minus_mm, one row per grind,
  /// flushed at once); empty = none.
  std::string facet_export_path{};
  /// Logical register with the daemon's request code; -1 = the fixed plan.
  std::int32_t request_register{-1};
  /// The thermal drift (effects.thermal) starts at the program start (false) or once the nominal
  /// set is touched (true: a cold machine is calibrated, then warms up).
  bool warm_up_after_nominals{false};
  /// Request mode: the run ends after this much sim time even if the warm-up never started [s].
  double give_up_s{86400.0};
};

/// [program.roll]: a roll ground along Z following a trajectory (nccomp grind-path output).
struct RollConfig {
  std::string trajectory_file{};
  /// z_mm, u_mm of the wheel's reference point T (the trajectory) and the target profile.
  std::vector<double> z_mm{};
  std::vector<double> u_mm{};
  std::vector<double> target_z_mm{};
  std::vector<double> target_u_mm{};
  double feed_mm_per_min{1000.0};
  double wheel_width_mm{100.0};
  double wheel_height_mm{0.2};
  std::int32_t passes{2};
};

struct SimConfig {
  std::string file{};
  /// The bus map (daemon's format) and its text.
  std::string bus_map_file{};
  std::string bus_map_text{};
  /// More files of the map (ncsim.bus_map_extra: e.g. flag registers the reference map lacks),
  /// appended to it as the daemon's `include` does: path and text of each.
  std::vector<std::string> bus_map_extra_files{};
  std::vector<std::string> bus_map_extra_texts{};
  /// The daemon's CAN map (reference-nc-can.toml) for --bus can, and its text.
  std::string can_bus_map_file{};
  std::string can_bus_map_text{};
  std::vector<std::string> can_bus_map_extra_files{};
  std::vector<std::string> can_bus_map_extra_texts{};
  /// CAN: the interface ncsim sends on.
  std::string can_interface{"vcan0"};
  /// Modbus: the TCP port ncsim serves (the map's port unless overridden; 0 = ephemeral).
  std::int32_t modbus_port{-1};
  /// Rate of the daemon's loop in lock-step, and ncsim's publish rate otherwise [Hz].
  double lockstep_rate_hz{1000.0};
  /// Largest model step along the path [mm] (the spacing of surface.csv / walls.csv).
  double step_mm{0.05};
  std::uint64_t seed{1};
  std::int32_t parts{1};
  /// Continuation of an earlier run (mould_face, side_wall; `ncsim --continue DIR`): the number
  /// of the first part, and the cut path the tool in the spindle has behind it [mm] (its wear
  /// continues from there).
  std::int32_t first_part{1};
  double tool_cut_path_mm{0.0};
  /// Offset registers in force at the start (a continued run: what the NC held at the end of
  /// the run it continues), by logical index; the two lists have the same length.
  std::vector<std::int32_t> initial_register_indices;
  std::vector<double> initial_registers_um;
  NcConfig nc{};
  EffectsConfig effects{};
  MouldFaceConfig mould_face{};
  SideWallConfig side_wall{};
  TouchConfig touch{};
  RollConfig roll{};
  /// The effects table as JSON (for result.json), after --set overrides.
  std::string effects_json{};
};

}  // namespace nccomp::sim::ncsim
