// The [modbus] section of an nccomp config: the connection (TCP or RTU), timing and fault
// handling, and the register map as data (which table / address / encoding carries each signal,
// which holding registers take which offset).
//
// Parsing and validation are not real-time (they allocate); the driver uses the validated
// result, whose read blocks and field positions are precomputed so that a poll only indexes.
//
// Rules enforced here (each refusal names file, line, column and key path; every error of a map
// is reported, not only the first):
// - unknown keys and unknown signals are errors;
// - addresses + width must fit 0..65535; no two mapped items may share a register or bit;
// - an event group (sequence counter + its value registers) must lie in one table and within
//   one read request (125 registers), so it is read atomically: the server answers one request
//   from one state, and the counter and the values cannot tear;
// - on RTU, the map's bus time per poll must fit the poll period at the configured baud rate;
// - the I/O thread's SCHED_FIFO priority must be below the loop thread's, where that is known.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <toml++/toml.h>

#include "core/common/types.hpp"
#include "drivers/modbus/encoding.hpp"
#include "formats/toml/diagnostics.hpp"

namespace nccomp::drivers::modbus {

enum class Transport : std::uint8_t { kTcp, kRtu };

/// Signal groups. kAxis is state (one AxisSample per poll); the others are events carried by a
/// sequence counter; temperatures are listed separately.
enum class Group : std::uint8_t {
  kAxis = 0,
  kToolMeasurement,
  kProbeMeasurement,
  kCalibrationTouch,
  kToolChange,
  kProgramEvent,
};
inline constexpr std::size_t kGroupCount = 6;

// Field indices per group (the order of the names in config.cpp's tables).
namespace axis_field {
inline constexpr std::size_t kX = 0, kY = 1, kZ = 2, kA = 3, kB = 4, kC = 5, kPath = 6, kTool = 7,
                             kNormalX = 8, kNormalY = 9, kNormalZ = 10, kCutting = 11, kCount = 12;
}
namespace tool_meas_field {
inline constexpr std::size_t kSeq = 0, kTool = 1, kWear = 2, kBroken = 3, kCount = 4;
}
namespace probe_field {
inline constexpr std::size_t kSeq = 0, kPart = 1, kCheckpoint = 2, kDeviation = 3, kAngle = 4,
                             kBallRadius = 5, kX = 6, kY = 7, kZ = 8, kCount = 9;
}
namespace touch_field {
inline constexpr std::size_t kSeq = 0, kProbe = 1, kAxis = 2, kDirection = 3, kVariant = 4,
                             kPosition = 5, kCount = 6;
}
namespace tool_change_field {
inline constexpr std::size_t kSeq = 0, kTool = 1, kSister = 2, kCount = 3;
}
namespace program_field {
inline constexpr std::size_t kSeq = 0, kKind = 1, kPart = 2, kCount = 3;
}
inline constexpr std::size_t kMaxFields = 12;

/// The config key names of a group and of its fields (for messages and docs).
std::string_view group_key(Group g) noexcept;
std::size_t field_count(Group g) noexcept;
std::string_view field_key(Group g, std::size_t field) noexcept;

/// One contiguous read request.
struct ReadBlock {
  Table table{Table::kHolding};
  std::uint16_t start{0};
  std::uint16_t count{0};
};

struct SignalMap {
  bool mapped{false};
  Table table{Table::kHolding};
  std::uint16_t address{0};
  Encoding encoding{};
  /// Consecutive values of this encoding (only tool_measurement.wear_um: a wear profile over
  /// the edge's support points); 1 for every other signal.
  std::uint8_t count{1};
  /// Accepted physical range (after scale and offset), from the map's `min` / `max`: a finite
  /// value outside it drops the sample or event (counted as out of range). Unbounded by default.
  double min{-std::numeric_limits<double>::infinity()};
  double max{std::numeric_limits<double>::infinity()};
  /// Position in the poll: read block index and the value's first register within it.
  std::size_t block{0};
  std::uint16_t block_offset{0};
};

/// Registers (or bits) a mapped signal occupies.
constexpr std::uint32_t span(const SignalMap& s) noexcept {
  return std::uint32_t{width(s.encoding.type)} * s.count;
}

struct GroupMap {
  bool present{false};
  std::array<SignalMap, kMaxFields> fields{};
};

struct TemperatureMap {
  std::uint8_t sensor{0};
  SignalMap value{};
};

struct OffsetMap {
  std::uint16_t register_index{0};
  /// Holding register(s), written with function 16.
  std::uint16_t address{0};
  Encoding encoding{};
};

enum class Parity : std::uint8_t { kNone, kEven, kOdd };

struct ModbusConfig {
  Transport transport{Transport::kTcp};
  // TCP
  std::string host{"127.0.0.1"};
  std::uint16_t port{502};
  // RTU
  std::string device{};
  std::uint32_t baud{19200};
  Parity parity{Parity::kEven};
  std::uint8_t data_bits{8};
  std::uint8_t stop_bits{1};
  bool rs485{false};

  std::uint8_t unit_id{1};
  double response_timeout_s{0.5};
  double byte_timeout_s{0.5};
  double poll_rate_hz{100.0};
  /// True when poll_rate_hz was not in the file (ParseOptions::default_poll_rate_hz applied).
  bool poll_rate_defaulted{false};
  /// Offsets are written at most this often (latest value wins in between). 0 in the file means
  /// "derive": the poll rate on TCP, the bus budget left by the polls on RTU.
  double offset_write_rate_hz{0.0};
  /// Reconnect back-off [s]: however the connection was lost, the next connect waits the
  /// back-off, which starts at reconnect_min_s and doubles up to reconnect_max_s ...
  double reconnect_min_s{0.1};
  double reconnect_max_s{5.0};
  /// ... and returns to reconnect_min_s only after a connection stayed healthy (every read and
  /// write answered, no timeout or garbage) this long [s]; at least reconnect_max_s.
  double reconnect_reset_after_s{10.0};
  /// Consecutive failed transactions (timeouts, garbage) after which the link is declared dead
  /// and reconnected: detects a silently dead TCP connection (cable pull).
  std::uint32_t dead_after_failures{3};
  /// Read every written offset back and re-write on mismatch.
  bool verify_writes{false};
  /// An offset still undelivered, or the link down, for this long raises the status alarm.
  double alarm_after_s{1.0};
  /// No intact poll (every block read without a fault and, if the axis group is mapped, a valid
  /// axis sample) for this long: the input is stale (BusStatus::input_stale, the daemon's alarm).
  double degraded_alarm_after_s{5.0};
  std::size_t rx_capacity{1024};
  std::size_t tx_capacity{256};
  /// Read blocks of one table whose gap is at most this many registers (8x as many bits) are
  /// merged into one request, if the result still fits one request. 0 merges only adjacent
  /// blocks. A gap is read too, so raise it only for NCs that answer every address in the gap
  /// (many answer unmapped addresses with exception 2, which would fail the merged request).
  std::uint32_t merge_gap_registers{0};
  /// SCHED_FIFO priority the I/O thread gives itself at start, 1..99; 0 = leave it as created
  /// (normal scheduling). Polls at a fixed rate overrun under load at normal priority
  /// (docs/modbus.md, "Real-time priority of the I/O thread"). In nccompd it must be below the
  /// loop thread's priority, so that the loop always preempts the driver.
  int io_sched_fifo_priority{0};
  /// CPUs the I/O thread pins itself to at start; empty = any CPU.
  std::vector<int> io_cpu_affinity{};

  std::array<GroupMap, kGroupCount> groups{};
  std::vector<TemperatureMap> temperatures{};
  std::vector<OffsetMap> offsets{};
  /// Precomputed read requests of one poll, in order.
  std::vector<ReadBlock> blocks{};
  /// Estimated bus time of one poll and of writing every offset once [s] (RTU; 0 on TCP).
  double poll_bus_time_s{0.0};
  double write_bus_time_s{0.0};
};

/// How poll_rate_hz relates to the loop that consumes the samples.
struct ParseOptions {
  /// poll_rate_hz when the key is absent (stand-alone tools: 100 Hz; nccompd: its loop rate).
  double default_poll_rate_hz{100.0};
  /// > 0: a larger poll_rate_hz is refused (nccompd: its loop rate; polls the loop never takes
  /// only load the NC and the bus).
  double max_poll_rate_hz{0.0};
  /// Where the two rates come from, for messages (e.g. "daemon.rate_hz"); empty = built in.
  std::string_view rate_source{};
  /// The loop thread's SCHED_FIFO priority (0 = the loop runs at normal scheduling); -1 =
  /// unknown (stand-alone tools). When known, an io_sched_fifo_priority > 0 that is not below it
  /// is refused: the I/O thread must never preempt the loop.
  int loop_sched_fifo_priority{-1};
  /// Where the loop's priority comes from, for messages (e.g.
  /// "daemon.realtime.sched_fifo_priority").
  std::string_view loop_priority_source{};
};

/// Parses the [modbus] table of a TOML document. `file` names the source in messages.
/// Throws formats::DiagnosticsError (every error of the map). Not real-time.
ModbusConfig parse_modbus_config(std::string_view toml_text, const std::string& file,
                                 const ParseOptions& options = {});
/// Parses an already parsed [modbus] table (the daemon's config loader hands it over). Errors
/// name the file the table's nodes were parsed from (their source path), else `file`, with line,
/// column and key path. Throws formats::DiagnosticsError. Not real-time.
ModbusConfig parse_modbus_table(const toml::table& modbus, const std::string& file,
                                const ParseOptions& options = {});
/// The same, reporting every error of the map to `diag` (file:line:column, key path) instead of
/// throwing; nullopt if there was one. The daemon's [modbus] section uses it. Not real-time.
std::optional<ModbusConfig> read_modbus_table(const toml::table& modbus, std::string_view file,
                                              const ParseOptions& options,
                                              formats::Diagnostics& diag);
/// Reads and parses a file. Throws formats::DiagnosticsError.
ModbusConfig load_modbus_config(const std::string& path);

/// RTU character time [s]: start + data + parity + stop bits at the baud rate.
double rtu_char_time_s(const ModbusConfig& c) noexcept;
/// RTU inter-frame silence [s]: 3.5 character times, fixed 1.75 ms above 19200 baud (spec).
double rtu_frame_gap_s(const ModbusConfig& c) noexcept;

}  // namespace nccomp::drivers::modbus
