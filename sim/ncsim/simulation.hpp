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

struct Results {
  std::vector<SurfaceRow> surface;
  std::vector<WallRow> walls;
  std::vector<CheckpointRow> checkpoints;
  std::vector<TouchRow> touches;
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
  /// Writes of a non-zero value to an alarm register.
  [[nodiscard]] std::int32_t alarms_seen() const noexcept { return alarms_seen_; }

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
  std::int32_t alarms_seen_{0};
};

/// The mould face's nominal height and outward unit normal at (x, y).
double mould_face_z_mm(const MouldFaceConfig& c, double x_mm, double y_mm);
Vec3 mould_face_normal(const MouldFaceConfig& c, double x_mm, double y_mm);

}  // namespace nccomp::sim::ncsim
