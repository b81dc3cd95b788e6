// The CAN signal map: which CAN frames carry which of the core's event fields (the DBC model of a
// signal: start bit, length, signedness, byte order, scale, offset), and which frame takes each
// offset register, with its acknowledge. Pure: no sockets, no threads, no clock reads, so the
// codec and the validation run in unit tests and fuzz targets.
//
// Lifecycle: a CanMapping is built (by parse_can_config() or by code) and validated once with
// validate_mapping() (allocates, reports every problem as a Diagnostic naming file:line:column and
// key path). FrameDecoder and encode_offset() then run on the I/O thread: real-time safe, no
// allocation, no locks, no I/O.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/common/types.hpp"
#include "formats/toml/diagnostics.hpp"
#include "formats/toml/key_positions.hpp"

namespace nccomp::drivers::can {

/// Largest payload of a CAN FD frame [bytes].
inline constexpr std::size_t kMaxPayloadBytes = 64;
inline constexpr std::uint32_t kMaxStandardId = 0x7FF;
inline constexpr std::uint32_t kMaxExtendedId = 0x1FFFFFFF;

enum class ByteOrder : std::uint8_t {
  kLittleEndian = 0,  // Intel: start_bit is the least significant bit
  kBigEndian = 1,     // Motorola (DBC): start_bit is the most significant bit, sawtooth numbering
};

enum class ValueType : std::uint8_t { kUnsigned = 0, kSigned = 1, kFloat = 2 };

/// One signal's place in a frame and its scaling: physical = raw * scale + offset.
struct SignalLayout {
  std::uint16_t start_bit{0};
  std::uint8_t length_bits{8};
  ByteOrder byte_order{ByteOrder::kLittleEndian};
  ValueType type{ValueType::kUnsigned};
  double scale{1.0};
  double offset{0.0};
};

/// The frame bit positions (bit b = byte b/8, bit b%8) of a layout's value bits, least
/// significant first. Returns the number of bits, or 0 if a position falls outside
/// [0, frame_bits) (the signal overflows the frame) or the length is 0 or above 64.
std::size_t signal_bit_positions(const SignalLayout& layout, std::size_t frame_bits,
                                 std::array<std::uint16_t, 64>& positions) noexcept;

/// The raw bits of a signal (zero-extended). Real-time safe. data must hold the whole layout.
std::uint64_t extract_raw(const SignalLayout& layout, std::span<const std::uint8_t> data) noexcept;
/// Writes the low length_bits of raw into the signal's place. Real-time safe.
void insert_raw(const SignalLayout& layout, std::uint64_t raw,
                std::span<std::uint8_t> data) noexcept;
/// raw → physical value (sign extension, IEEE float for kFloat). Real-time safe.
double raw_to_physical(const SignalLayout& layout, std::uint64_t raw) noexcept;
/// physical → raw bits; nullopt if not finite or it does not fit the signal. Real-time safe.
std::optional<std::uint64_t> physical_to_raw(const SignalLayout& layout, double value) noexcept;

/// Which core event a received frame feeds.
enum class EventKind : std::uint8_t {
  kAxisSample = 0,
  kToolMeasurement = 1,
  kProbeMeasurement = 2,
  kCalibrationTouch = 3,
  kToolChange = 4,
  kProgramEvent = 5,
  kTemperature = 6,
};
inline constexpr std::size_t kEventKinds = 7;

/// The event fields a signal may carry. Names (config) are listed in can_mapping.cpp.
enum class Field : std::uint8_t {
  kXmm,
  kYmm,
  kZmm,
  kAdeg,
  kBdeg,
  kCdeg,
  kProgramPathMm,
  kTool,
  kNormalX,
  kNormalY,
  kNormalZ,
  kCutting,
  kBroken,
  kWearUm,
  kPart,
  kCheckpoint,
  kRawDeviationUm,
  kWallAngleDeg,
  kBallRadiusMm,
  kProbe,
  kAxis,
  kDirection,
  kVariant,
  kTriggerPositionMm,
  kSister,
  kProgramKind,
  kSensor,
  kTemperatureC,
};

std::optional<EventKind> event_kind_from_name(std::string_view name) noexcept;
std::string_view event_kind_name(EventKind kind) noexcept;
/// The field a signal name denotes for an event kind, or nullopt if that event has no such field.
std::optional<Field> field_from_name(EventKind kind, std::string_view name) noexcept;
/// Comma-separated list of valid signal names of an event kind (for error messages).
std::string field_names(EventKind kind);

/// Where a mapping element came from: its table's file:line:column and key path (e.g.
/// "can.rx[2].signal[0]"), for error messages.
using Origin = formats::Where;

struct RxSignal {
  std::string name;
  Field field{Field::kXmm};
  SignalLayout layout{};
  /// Accepted physical range; outside → the frame is rejected (malformed, out of range).
  double min{-1e300};
  double max{1e300};
  Origin origin{};
};

/// A received frame: its ID and payload length, the event it feeds, its signals.
struct RxFrame {
  std::uint32_t id{0};
  bool extended{false};
  /// Expected payload length [bytes]; a frame with another length is rejected (wrong DLC).
  std::uint8_t length_bytes{8};
  EventKind event{EventKind::kAxisSample};
  /// true: this frame completes the event, which is pushed. false: it only updates the latest
  /// values (e.g. X and Y in one frame, Z and the tool in the next, which emits).
  bool emit{true};
  std::vector<RxSignal> signals;
  Origin origin{};
};

/// The NC's acknowledge of an offset write: a frame on ack_id echoing the written payload.
struct TxAck {
  std::uint32_t id{0};
  bool extended{false};
};

/// The frame that writes one offset register: value_um encoded by `value`.
struct TxRegister {
  std::uint16_t register_index{0};
  std::uint32_t id{0};
  bool extended{false};
  std::uint8_t length_bytes{8};
  SignalLayout value{};
  std::optional<TxAck> ack;
  Origin origin{};
};

struct CanMapping {
  /// CAN FD frames allowed (payloads up to 64 bytes); the interface MTU is checked at start.
  bool fd{false};
  std::vector<RxFrame> rx;
  std::vector<TxRegister> offsets;
  /// Set by validate_mapping(): axis slots in AxisSample (highest mapped axis + 1, at least 1).
  std::uint8_t axis_count{3};
  std::string file;  // config file name, for error messages
};

/// Checks the whole mapping and reports every problem to diag: unknown signal names, overlapping
/// signals, signals overflowing the frame, bad IDs, duplicate IDs / registers, lengths not
/// allowed for the frame type. Each names the key's file:line:column from `positions` (the
/// parsed [can] table's, see formats::record_positions) where it is there, else the element's
/// origin, with the key path. Sets axis_count. Returns false if it reported anything.
bool validate_mapping(CanMapping& mapping, formats::Diagnostics& diag,
                      const formats::KeyPositions* positions = nullptr);

/// Valid CAN (FD) payload lengths: 0–8, 12, 16, 20, 24, 32, 48, 64.
bool valid_payload_length(std::size_t length_bytes, bool fd) noexcept;

/// Why a frame on a mapped ID was rejected.
enum class RejectReason : std::uint8_t {
  kNone = 0,
  kUnknownId = 1,    // not mapped (the kernel filter should have dropped it)
  kWrongLength = 2,  // DLC / payload length differs from the mapping
  kOutOfRange = 3,   // a value outside its configured or type range
  kNotFinite = 4,    // NaN or infinity in a float signal
};
inline constexpr std::size_t kRejectReasons = 5;

/// Turns frames into core events. configure() allocates; decode() is real-time safe.
class FrameDecoder {
 public:
  /// mapping must have passed validate_mapping(). Allocates (not real-time).
  explicit FrameDecoder(const CanMapping& mapping);

  struct Result {
    RejectReason reject{RejectReason::kNone};
    /// true if out holds a complete event to push (also a faulted measurement, with a reject).
    bool emitted{false};
  };

  /// Decodes one frame received at now_ns. A rejected frame applies none of its signals (all
  /// are checked before any is applied). A rejected frame of a measurement (tool measurement,
  /// probe measurement, calibration touch) makes that measurement faulted (core::InputFault, its
  /// values 0): emitted at once if the frame completes the event, else by the frame that does.
  /// Real-time safe: no allocation, no locks, no I/O.
  Result decode(std::uint32_t id, bool extended, std::span<const std::uint8_t> payload,
                core::TimeNs now_ns, core::Event& out) noexcept;

  /// Index into the mapping's rx frames for an ID, or -1. Real-time safe (binary search).
  [[nodiscard]] int find(std::uint32_t id, bool extended) const noexcept;

 private:
  Result reject(const RxFrame& f, RejectReason why, core::TimeNs now_ns, core::Event& out) noexcept;

  const CanMapping& mapping_;
  std::vector<std::pair<std::uint32_t, int>> index_;  // (key, rx index), sorted by key
  std::array<core::Event, kEventKinds> latest_;
  std::array<core::InputFault, kEventKinds> faults_{};  // a frame of the event was rejected
};

/// Encodes an offset write into a payload of reg.length_bytes bytes (unused bits zero).
/// Returns false if value_um does not fit the register's signal. Real-time safe.
bool encode_offset(const TxRegister& reg, double value_um,
                   std::span<std::uint8_t, kMaxPayloadBytes> payload) noexcept;

/// Key for lookups: the ID with bit 31 set for extended IDs.
constexpr std::uint32_t id_key(std::uint32_t id, bool extended) {
  return extended ? (id | 0x80000000U) : id;
}

/// The value (physical units) of a field in an event, for encoders (sim/can_nc) and tests.
/// nullopt if the event does not have that field.
std::optional<double> field_value(const core::Event& event, Field field) noexcept;

}  // namespace nccomp::drivers::can
