// A plain-data picture of the calibrator at one instant, for the operator's side: the daemon's
// loop publishes it (CalibrationModule → SnapshotSink, e.g. a seqlock) and the status thread
// answers `nccomp calibrate --daemon` from it; the offline session renders the same picture, so
// both show the same prompts. Trivially copyable; make_snapshot() is allocation-free.
#pragma once

#include <array>
#include <cstdint>
#include <type_traits>

#include "core/calib/calibrator.hpp"
#include "core/calib/state.hpp"
#include "core/common/types.hpp"

namespace nccomp::core::calib {

/// How an operator command ended.
enum class CommandStatus : std::uint8_t {
  kNone = 0,          // no command yet
  kOk = 1,            // done (for facets: see CommandOutcome::facet)
  kWrongPhase = 2,    // not possible in this phase (nothing changed)
  kInvalidInput = 3,  // a value out of range (nothing changed)
  kUnknown = 4,       // a command kind this module does not know
};
const char* to_string(CommandStatus status) noexcept;

/// The answer to one operator command.
struct CommandOutcome {
  std::uint32_t sequence{0};
  OperatorCommandKind kind{OperatorCommandKind::kNone};
  CommandStatus status{CommandStatus::kNone};
  Phase phase_before{Phase::kUncalibrated};
  /// kCalibrationFacets: the test grind's result.
  FacetResult facet{};
  /// Alarms the command raised (a touch completing a set, a facet that ends the calibration).
  std::uint32_t alarm_count{0};
  std::array<AlarmEvent, 8> alarms{};
};

struct CalibSnapshot {
  /// Advances with every publication.
  std::uint64_t publishes{0};
  /// The loop's clock at the snapshot [s] and the same on the wall clock [Unix s].
  double time_s{0.0};
  double wall_time_s{0.0};
  CommandOutcome last_command{};
  /// Operator commands taken by the module, and refused by it (kWrongPhase, kInvalidInput,
  /// kUnknown); status requests are not counted.
  std::uint64_t commands_taken{0};
  std::uint64_t commands_refused{0};
  RequestCode request{RequestCode::kNone};
  TouchProgress progress{};
  /// Register targets (NaN where none) and values written [µm], axes X, Y, Z.
  std::array<double, kAxisCount> target_um{};
  std::array<double, kAxisCount> written_um{};
  std::array<std::uint16_t, kAxisCount> registers{};
  /// Per slot: the correction in force (prediction + creep) and the prediction [µm].
  std::array<double, kSlotCount> correction_um{};
  std::array<double, kSlotCount> predicted_um{};
  double temperature_c{kNaN};
  double recalibration_interval_s{0.0};
  FacetRule facet_rule{FacetRule::kExact};
  std::int32_t temperature_sensor{-1};
  /// The calibration itself; times on the wall clock (Calibrator::export_state()).
  CalibState state{};
};
static_assert(std::is_trivially_copyable_v<CalibSnapshot>);

/// Fills everything but publishes, last_command and the command counters. Allocation-free.
void make_snapshot(const Calibrator& c, TimeNs now_ns, CalibSnapshot& out) noexcept;

/// Where a CalibrationModule publishes its snapshots (the daemon: a seqlock the status thread
/// reads). publish() is called on the loop thread: it must be real-time safe.
class SnapshotSink {
 public:
  virtual ~SnapshotSink() = default;
  virtual void publish(const CalibSnapshot& snapshot) noexcept = 0;
};

}  // namespace nccomp::core::calib
