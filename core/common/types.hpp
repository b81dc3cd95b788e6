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

/// Where a numbered event came from. A bus whose NC numbers its events (Modbus: a sequence
/// counter per event group) sets `numbered` and the counter's value; the loop sets `bus` (its
/// index in the loop's bus list). The engine keeps the last one it took per bus and kind with
/// its state, so that a restart resumes the bus's events from there (docs/daemon.md, "Events
/// while nccompd was down").
struct EventOrigin {
  std::uint32_t sequence{0};
  std::uint8_t bus{0};
  bool numbered{false};
  /// Not an event: the bus consumed the counter without one to deliver (its first read, an NC
  /// restart with no event since). The engine moves its cursor and passes nothing on.
  bool counter_only{false};
};

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

/// Why a driver could not use the values of a measurement the NC reported (ToolMeasurement,
/// ProbeMeasurement, CalibrationTouch). The measurement happened, so it is not dropped in
/// silence: the event reaches its method, which raises its alarm and changes nothing. A faulted
/// event's value fields (wear, deviation, angle, radius, positions) are 0 and never a measurement.
enum class InputFault : std::uint8_t {
  kNone = 0,
  kInvalid = 1,     // NaN / inf, not integral, not a valid code, a malformed frame
  kOutOfRange = 2,  // finite but outside the map's min / max
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
  /// tool is 0 when the fault is in the tool number itself.
  InputFault fault{InputFault::kNone};
  EventOrigin origin{};
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
  /// checkpoint is -1 when the fault is in the checkpoint number itself.
  InputFault fault{InputFault::kNone};
  EventOrigin origin{};
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
  /// probe, axis, direction and variant are as received where valid, else their defaults.
  InputFault fault{InputFault::kNone};
  EventOrigin origin{};
};

struct ToolChange {
  TimeNs time_ns{0};
  std::int32_t tool{0};
  /// The new tool is a sister of the previous one (same geometry).
  bool sister{false};
  EventOrigin origin{};
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
  EventOrigin origin{};
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
  // The engine's start-up holds (core/engine/engine.hpp): `nccomp register release NAME|all`.
  kRegisterRelease = 9,  // code all 0; value[0] = the register's index, or -1 = every register
                         // held; value[1] unused (0)
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

/// The fault of a measurement event (ToolMeasurement, ProbeMeasurement, CalibrationTouch); kNone
/// for every other event.
inline InputFault fault_of(const Event& e) noexcept {
  return std::visit(
      [](const auto& ev) {
        using T = std::decay_t<decltype(ev)>;
        if constexpr (std::is_same_v<T, ToolMeasurement> || std::is_same_v<T, ProbeMeasurement> ||
                      std::is_same_v<T, CalibrationTouch>) {
          return ev.fault;
        } else {
          return InputFault::kNone;
        }
      },
      e);
}

/// The event kinds a bus may number (EventOrigin), in this order: ToolMeasurement,
/// ProbeMeasurement, CalibrationTouch, ToolChange, ProgramEvent.
inline constexpr std::size_t kNumberedKinds = 5;

static_assert(std::is_same_v<std::variant_alternative_t<1, Event>, ToolMeasurement> &&
              std::is_same_v<std::variant_alternative_t<5, Event>, ProgramEvent>);

/// Index of e's kind among the numbered kinds, or -1 for a kind that is never numbered.
constexpr int numbered_kind(const Event& e) noexcept {
  const std::size_t i = e.index();
  return i >= 1 && i <= kNumberedKinds ? static_cast<int>(i) - 1 : -1;
}

/// e's origin, or nullptr for a kind that is never numbered. Real-time safe.
template <typename E>
requires std::is_same_v<std::remove_const_t<E>, Event>
auto* origin_of(E& e) noexcept {
  using Origin = std::conditional_t<std::is_const_v<E>, const EventOrigin, EventOrigin>;
  return std::visit(
      [](auto& ev) -> Origin* {
        if constexpr (requires { ev.origin; }) {
          return &ev.origin;
        } else {
          return nullptr;
        }
      },
      e);
}

/// Marks a measurement event faulted (fault != kNone) and sets every value field to 0, so that
/// no value of it can be taken for a measurement; other events are left as they are.
inline void set_fault(Event& e, InputFault fault) noexcept {
  if (fault == InputFault::kNone) {
    return;
  }
  if (auto* t = std::get_if<ToolMeasurement>(&e)) {
    t->fault = fault;
    t->wear_um.fill(0.0);
  } else if (auto* p = std::get_if<ProbeMeasurement>(&e)) {
    p->fault = fault;
    p->raw_deviation_um = 0.0;
    p->wall_angle_deg = 0.0;
    p->ball_radius_mm = 0.0;
    p->position_mm.fill(0.0);
  } else if (auto* c = std::get_if<CalibrationTouch>(&e)) {
    c->fault = fault;
    c->trigger_position_mm = 0.0;
  }
}
/// The last numbered event of one kind that the engine took from one bus (its NC's counter).
struct EventCursor {
  bool known{false};
  std::uint32_t sequence{0};
};
/// One bus's cursors, indexed by numbered_kind().
using EventCursorSet = std::array<EventCursor, kNumberedKinds>;

// ---------------------------------------------------------------------------------------------
// Out: commands to the NC, alarms, measurement records.

/// An absolute offset value for one logical register. The config maps register indices to the
/// bus (CAN frame layout or Modbus address); values are never increments.
struct OffsetWrite {
  TimeNs time_ns{0};
  std::uint16_t register_index{0};
  double value_um{0.0};
  /// The engine's number of this write (counting up, never reused while nccompd runs), which
  /// the bus's WriteReceipt names; 0 = no receipt wanted.
  std::uint64_t sequence{0};
};

/// What became of an offset write on its way to the NC (drivers::Bus::write_receipt()).
enum class WriteOutcome : std::uint8_t {
  /// Not finished: queued, on its way, or being retried (a reconnect, a read-back mismatch).
  kPending = 0,
  /// The NC took the value: answered (Modbus, and read back equal with verify_writes),
  /// acknowledged, or sent where the map has no acknowledge (CAN).
  kReached = 1,
  /// Never sent: not encodable, no mapping, or no room in the bus's queue. The NC keeps what it
  /// held before.
  kRefused = 2,
  /// Sent but never confirmed (CAN: no acknowledge after ack_retries): the NC holds this value or
  /// the one before.
  kUnknown = 3,
};

/// The newest write of one register a bus finished with.
struct WriteReceipt {
  std::uint64_t sequence{0};  // OffsetWrite::sequence; 0 = none finished yet
  WriteOutcome outcome{WriteOutcome::kPending};
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
  // The estimator's normalised innovations disagree with the configured measurement σ (or the
  // process noise): value = their mean, subject = the tool (docs/estimation.md, "Checking σ").
  kMeasurementNoiseInconsistent = 25,
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
  // Start-up: what the NC holds in a register against the limits and the daemon's state
  // (core/engine/engine.hpp, "Start-up holds"); subject = the register, value = what it holds.
  // The NC holds a value beyond max_abs_um (read back, or restored / carried over a reload that
  // narrowed the limit): nothing is written to it until the operator releases it.
  kRegisterBeyondLimit = 60,
  // The module writing it has no usable state: the NC's value is adopted as the starting point
  // of its compensation (nothing written until a new measurement or an operator decision).
  kRegisterAdopted = 61,
  // No usable state and no adoption (the module cannot adopt the value, or the NC did not
  // answer the read-back; value NaN then): held, nothing written until the operator releases it.
  kRegisterHeldWithoutState = 62,
  // A bus's input is stale (drivers::BusStatus::input_stale): for longer than the bus's
  // degraded_alarm_after_s no intact poll (Modbus) / the link not up (CAN), or no valid axis
  // sample. Raised by the daemon's main thread like kBusAlarm: subject = the bus's index, value 1
  // when it rises (kAlarm), 0 when it clears (kInfo).
  kBusInputStale = 55,
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
