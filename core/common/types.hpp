// The core's vocabulary (architecture.md, "Events and commands"): bus-neutral, fixed-size,
// trivially copyable structs, so that they travel through SPSC rings and seqlock snapshots
// without allocation. Drivers decode bytes into these; the core never sees a bus.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <variant>

namespace nccomp::core {

/// Monotonic time [ns], supplied by the caller (the loop thread, a test's fake clock).
using TimeNs = std::int64_t;

inline constexpr double kNsPerS = 1e9;
inline constexpr double kUmPerMm = 1000.0;
inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Axis slots in an AxisSample. Linear axes in mm, rotary axes in degrees.
enum class Axis : std::uint8_t { X = 0, Y = 1, Z = 2, A = 3, B = 4, C = 5 };
inline constexpr std::size_t kMaxAxes = 6;
/// Support points of an edge-wear profile (S0: engagement angle 0–90° in steps).
inline constexpr std::size_t kMaxEdgePoints = 32;

constexpr double seconds(TimeNs t_ns) { return static_cast<double>(t_ns) / kNsPerS; }
constexpr TimeNs from_seconds(double t_s) { return static_cast<TimeNs>(t_s * kNsPerS); }

// ---------------------------------------------------------------------------------------------
// In: events from the NC / PLC / operator.

/// One sample of the machine state, published by the NC at (up to) the loop rate.
struct AxisSample {
  TimeNs time_ns{0};
  /// Machine positions [mm] (linear) or [deg] (rotary); only the first axis_count are valid.
  std::array<double, kMaxAxes> position_mm{};
  std::uint8_t axis_count{3};
  /// Program path position [mm] of the active program; NaN where the NC does not publish it.
  double program_path_mm{kNaN};
  /// Active tool number (0 = none).
  std::int32_t tool{0};
  /// Unit surface normal at the cutting point (workpiece coordinates), if has_normal.
  bool has_normal{false};
  std::array<double, 3> normal{0.0, 0.0, 1.0};
  /// True while the tool is cutting (feed move in material), as far as the NC tells.
  bool cutting{true};
};

/// A tool measurement (laser light barrier, measuring diamond).
struct ToolMeasurement {
  TimeNs time_ns{0};
  std::int32_t tool{0};
  /// The device reported a broken tool (no beam interruption, or out of range).
  bool broken{false};
  /// Wear [µm] per edge support point; point_count == 1 means wear at the tip / one value.
  std::uint8_t point_count{1};
  std::array<double, kMaxEdgePoints> wear_um{};
};

/// A probe measurement of the part at a checkpoint (S1).
struct ProbeMeasurement {
  TimeNs time_ns{0};
  std::int32_t part{0};
  std::int32_t checkpoint{0};
  /// The probe's displayed deviation δ [µm], uncorrected for the ball geometry.
  double raw_deviation_um{0.0};
  /// Wall normal inclination angle α [deg].
  double wall_angle_deg{0.0};
  /// Probe ball radius r [mm].
  double ball_radius_mm{0.0};
  std::array<double, 3> position_mm{};
};

/// Which probe produced a calibration touch (S3).
enum class ProbeKind : std::uint8_t { kMachineProbe = 0, kReferenceProbe = 1 };

/// A touch-trigger event during calibration / recalibration (S3).
struct CalibrationTouch {
  TimeNs time_ns{0};
  ProbeKind probe{ProbeKind::kMachineProbe};
  /// 0/1/2 = X/Y/Z.
  std::uint8_t axis{0};
  /// Approach direction: +1 or −1.
  std::int8_t direction{1};
  /// Variant of the touch: 0 = lateral, 1 = axial (X touched along the stylus, A rotated 90°).
  std::uint8_t variant{0};
  /// Axis position at the trigger [mm].
  double trigger_position_mm{0.0};
};

struct ToolChange {
  TimeNs time_ns{0};
  std::int32_t tool{0};
  /// The new tool is a sister of the previous one (same geometry).
  bool sister{false};
};

enum class ProgramEventKind : std::uint8_t {
  kPartStart = 0,
  kPartEnd = 1,
  kInterruption = 2,
  kResume = 3,
};

struct ProgramEvent {
  TimeNs time_ns{0};
  ProgramEventKind kind{ProgramEventKind::kPartStart};
  std::int32_t part{0};
};

struct TemperatureSample {
  TimeNs time_ns{0};
  std::uint8_t sensor{0};
  double temperature_c{0.0};
};

/// What an operator command asks (OperatorCommand::kind). Numbers are stable.
enum class OperatorCommandKind : std::uint8_t {
  kNone = 0,
  // S3 calibration (core/calib): `nccomp calibrate --daemon`.
  kCalibrationBegin = 1,        // start an initial calibration
  kCalibrationFacets = 2,       // code[0] = face (0 lateral, 1 end face); value = {c+, c-} [mm]
  kCalibrationDiscard = 3,      // drop a touch set in progress
  kCalibrationRecalibrate = 4,  // request a recalibration touch cycle now (on demand)
  kCalibrationTouch = 5,        // a touch typed by the operator: code = {probe, axis, direction,
                                // variant} as in CalibrationTouch, value[0] = trigger [mm]
  kCalibrationStatus = 6,       // no change: publish the state (the reply shows it)
  // The engine's machine context (core/engine/context.hpp): `nccomp warm-start`.
  kWarmStart = 7,  // code[0] = 0: the machine's warm start is now (time_s counts from this
                   // cycle); 1: the machine is cold, its next axis motion is the warm start
  // Every module with a latched alarm (today the creep module, core/creep): `nccomp acknowledge`.
  kAcknowledge = 8,  // the operator acknowledges the latched alarms: code all 0 (every module;
                     // other codes are reserved and refused), values unused
};

/// An operator command (status socket → SPSC ring → the loop): validated by the daemon before it
/// is queued and again by the module that takes it. `sequence` (> 0) lets the sender find the
/// module's answer to exactly this command.
struct OperatorCommand {
  TimeNs time_ns{0};
  std::uint32_t sequence{0};
  OperatorCommandKind kind{OperatorCommandKind::kNone};
  std::array<std::int8_t, 4> code{};
  std::array<double, 2> value{};
};

using Event = std::variant<AxisSample, ToolMeasurement, ProbeMeasurement, CalibrationTouch,
                           ToolChange, ProgramEvent, TemperatureSample, OperatorCommand>;

// ---------------------------------------------------------------------------------------------
// Out: commands to the NC, alarms, measurement records.

/// An absolute offset value for one logical register. The config maps register indices to the
/// bus (CAN frame layout or Modbus address); values are never increments.
struct OffsetWrite {
  TimeNs time_ns{0};
  std::uint16_t register_index{0};
  double value_um{0.0};
};

enum class Severity : std::uint8_t { kInfo = 0, kWarning = 1, kAlarm = 2 };

/// Alarm and warning codes. Stable numbers: they reach the NC's alarm register and the log.
enum class AlarmCode : std::uint16_t {
  kNone = 0,
  // limiter
  kOffsetNonFinite = 10,
  kOffsetBeyondAbsoluteLimit = 11,
  kOffsetSlewLimited = 12,
  // S0 creeping wear correction
  kCreepUnfinished = 20,
  kToolLifeReached = 21,
  kToolExcessivelyWorn = 22,
  kToolBrokenOrMismeasured = 23,
  kMeasurementDue = 24,
  // S1 checkpoints
  kProbeImplausible = 30,
  kProbeOutlier = 31,
  kProbeInvalidInput = 32,
  kCheckpointRegisterMismatch = 33,  // NC registers read back differ from the learned table
  kCheckpointMissed = 34,            // a checkpoint was passed without its trigger
  // S3 calibration
  kRecalibrationImplausible = 40,
  kTouchScatter = 41,
  kRecalibrationDue = 42,
  kTouchSetIncomplete = 43,
  kCalibrationOutOfRange = 44,
  kTouchUnexpected = 45,
  kTestGrindNotConverging = 46,
  kRecalibrationApplied = 47,
  kCalibrationComplete = 48,
  kCalibrationInvalidInput = 49,
  // engine / state
  kStateCorrupt = 50,
  kEventInvalid = 51,
  kRegisterUnknown = 52,     // a module wrote a register index the engine does not have
  kOffsetWriteDropped = 53,  // the bus TX ring was full or no bus takes the register
  // A bus cannot deliver offsets (a write rejected, or undelivered longer than the bus's
  // alarm_after_s) or its link is down beyond alarm_after_s (drivers::BusStatus::alarm). Raised
  // by the daemon's main thread, not by the core: subject = the bus's index, value 1 when it
  // rises (Severity::kAlarm), 0 when it clears (Severity::kInfo).
  kBusAlarm = 54,
};

struct AlarmEvent {
  TimeNs time_ns{0};
  Severity severity{Severity::kInfo};
  AlarmCode code{AlarmCode::kNone};
  /// Tool, checkpoint, axis or register the alarm is about (-1 = none).
  std::int32_t subject{-1};
  /// The offending value (µm unless the code says otherwise).
  double value{0.0};
};

/// Measurement kinds of the measurement log (architecture.md, "Measurement log").
enum class MeasurementKind : std::uint8_t { kToolWear = 0, kContour = 1, kCalib = 2 };

/// Context values a measurement record carries for the log's named context columns (v2).
inline constexpr std::size_t kMaxContextValues = 8;

/// One row of the measurement log.
struct MeasurementRecord {
  TimeNs time_ns{0};
  std::int32_t part{0};
  std::int32_t tool{0};
  MeasurementKind kind{MeasurementKind::kToolWear};
  std::int32_t point{0};
  std::array<double, 3> position_mm{};
  double angle_deg{kNaN};
  double path_mm{kNaN};
  double temp_c{kNaN};
  double measured_um{0.0};
  double applied_um{0.0};
  // v2 of the log (architecture.md, "Measurement log").
  /// The warm start time_ns counts from (the machine's warm-start count, saved with the state).
  std::uint64_t session{0};
  /// The step clock's time of the record [ns]: time_ns before the engine made it machine time
  /// (the log writer converts it to UTC).
  TimeNs clock_ns{0};
  /// Values of the log's context columns, filled by the daemon (NaN = unknown).
  std::array<double, kMaxContextValues> context{kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN};
  static_assert(kMaxContextValues == 8, "the initializer above lists one NaN per value");
};

static_assert(std::is_trivially_copyable_v<Event>);
static_assert(std::is_trivially_copyable_v<OffsetWrite>);
static_assert(std::is_trivially_copyable_v<AlarmEvent>);
static_assert(std::is_trivially_copyable_v<MeasurementRecord>);

inline bool is_finite(double v) { return std::isfinite(v); }

}  // namespace nccomp::core
