// The virtual NC's programs on the machine model (issue 10 item 2): pure and deterministic.
// advance_to(t) moves the machine along the program up to sim time t, in steps of at most
// step_mm of path; the NC's published state (axis sample, temperatures) and the events it raised
// are read after each call; offset writes come in through write_offset(). Rows of the machined
// result are collected as the tool cuts.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/common/types.hpp"
#include "sim/ncsim/model.hpp"
#include "sim/ncsim/nc_registers.hpp"
#include "sim/ncsim/sim_config.hpp"

namespace nccomp::sim::ncsim {

struct SurfaceRow {
  std::int32_t pass;
  double path_mm, x_mm, y_mm, z_mm, error_um, offset_um;
};
struct WallRow {
  std::int32_t part, layer;
  double z_mm, s_mm, error_um, offset_um;
};
struct CheckpointRow {
  std::int32_t part, checkpoint, layer;
  double z_mm, s_mm, error_um, probed_um;
};
struct TouchRow {
  std::int32_t cycle, probe, axis, direction, variant;
  double trigger_position_mm, true_drift_um;
};

/// A reading the NC produced: the laser's tool measurement or a probe reading, with the true
/// value it measured (measurements.csv).
enum class MeasurementKind : std::uint8_t { kLaser, kProbe };
struct MeasurementRow {
  double t_s;
  MeasurementKind kind;
  std::int32_t part;
  /// Probe: the checkpoint id; laser: -1.
  std::int32_t checkpoint;
  /// The tool's cut path when it was measured [mm].
  double cut_path_mm;
  /// Laser: the true radial wear (broken edge included); probe: the deviation a noise-free
  /// probe would show (wall error + the ball's geometric δ0) [µm].
  double true_um;
  /// What the NC published [µm].
  double reading_um;
  /// Laser: the broken flag the NC published.
  bool broken;
};
/// A change of an alarm register (nc.alarm_registers) from 0 to a non-zero value.
struct AlarmRow {
  double t_s;
  std::int32_t register_index;
  double value;
};

struct Results {
  std::vector<SurfaceRow> surface;
  std::vector<WallRow> walls;
  std::vector<CheckpointRow> checkpoints;
  std::vector<TouchRow> touches;
  std::vector<MeasurementRow> measurements;
  std::vector<AlarmRow> alarms;
};

/// Where a program left the machine, for a run that continues it (`ncsim --continue`).
struct EndState {
  bool valid{false};
  std::int32_t next_part{1};
  double tool_cut_path_mm{0.0};
};

class Simulation;

/// One NC program (mould_face, side_wall, touch, roll).
class Program {
 public:
  virtual ~Program() = default;
  /// Advances by h_s of sim time (at most one model step). Returns false when done.
  virtual bool step(Simulation& sim, double h_s) = 0;
  /// Largest step [s] (step_mm at the program's feed).
  [[nodiscard]] virtual double max_step_s() const = 0;
  /// The part a continuing run starts with and the tool's cut path; invalid for programs that
  /// cannot be continued (touch, roll).
  [[nodiscard]] virtual EndState end_state() const { return {}; }
};

class Simulation {
 public:
  /// known_registers: the logical offset registers of the bus map.
  Simulation(const SimConfig& config, ProgramKind program,
             const std::vector<std::uint16_t>& known_registers);
  ~Simulation();

  /// Runs the program up to sim time t_ns (no-op once done). Not real-time (rows are appended).
  void advance_to(core::TimeNs t_ns);
  [[nodiscard]] bool done() const noexcept { return done_; }
  [[nodiscard]] double time_s() const noexcept { return t_s_; }

  /// The NC's published state now.
  [[nodiscard]] const core::AxisSample& axis() const noexcept { return axis_; }
  [[nodiscard]] std::array<double, 2> temperatures_c() const;
  /// Events raised since the last call, oldest first.
  std::vector<core::Event> take_events();

  /// An offset write that reached the NC at sim time t.
  WriteResult write_offset(double t_s, std::uint16_t register_index, double value_um);

  [[nodiscard]] const Results& results() const noexcept { return results_; }
  [[nodiscard]] const OffsetRegisters& registers() const noexcept { return registers_; }
  [[nodiscard]] const SimConfig& config() const noexcept { return config_; }
  [[nodiscard]] MachineModel& model() noexcept { return model_; }
  /// Alarms the NC showed: changes of an alarm register from 0 to a non-zero value.
  [[nodiscard]] std::int32_t alarms_seen() const noexcept {
    return static_cast<std::int32_t>(results_.alarms.size());
  }
  [[nodiscard]] EndState end_state() const { return program_->end_state(); }

  // --- for the programs ---
  Results& mutable_results() noexcept { return results_; }
  core::AxisSample& mutable_axis() noexcept { return axis_; }
  void emit(const core::Event& e) { events_.push_back(e); }
  [[nodiscard]] core::TimeNs now_ns() const noexcept { return core::from_seconds(t_s_); }
  /// Offset in force of a register (0 when the NC has none).
  [[nodiscard]] double reg(std::int32_t index) const { return registers_.value(index); }

 private:
  SimConfig config_;
  MachineModel model_;
  OffsetRegisters registers_;
  std::unique_ptr<Program> program_;
  core::AxisSample axis_{};
  std::vector<core::Event> events_;
  Results results_;
  double t_s_{0.0};
  bool done_{false};
  /// Last value written to each alarm register (edge detection).
  std::vector<std::pair<std::int32_t, double>> alarm_values_;
};

/// The mould face's nominal height and outward unit normal at (x, y).
double mould_face_z_mm(const MouldFaceConfig& c, double x_mm, double y_mm);
Vec3 mould_face_normal(const MouldFaceConfig& c, double x_mm, double y_mm);

}  // namespace nccomp::sim::ncsim
