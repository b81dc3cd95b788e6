// Turns the registers of one poll into core events: one AxisSample per poll, an event per
// advanced sequence counter, a TemperatureSample when a temperature changed.
//
// Events over a polled bus: the NC writes an event's value registers first and then increments
// its sequence counter; the counter and the values are read in one request (config.hpp makes
// sure of that), so they always belong together. Per poll:
//   - first poll after start: the counter is a baseline, nothing is emitted (its event is old);
//   - counter unchanged: nothing; advanced by 1: the event is emitted once;
//   - advanced by k > 1: the latest event is emitted and k − 1 events are counted as lost
//     (the NC produced events faster than the poll rate);
//   - moved back by more than half its range: the NC restarted its counter; re-baselined,
//     counted as a sequence reset.
// Counters and baselines survive a reconnect, so events produced while the link was down show
// up as one emitted event plus lost ones, never twice.
//
// Plausibility: a finite value outside its signal's `min` / `max` (config) drops the whole sample
// or event and counts values_out_of_range; NaN / inf / non-integral / invalid codes count
// values_invalid. Either way an event's counter is consumed, so it is not re-read.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/common/types.hpp"
#include "drivers/modbus/config.hpp"

namespace nccomp::drivers::modbus {

struct DecodeCounters {
  std::uint64_t events_lost{0};          // sequence jumps > 1
  std::uint64_t sequence_resets{0};      // counter moved backwards (NC restart)
  std::uint64_t values_invalid{0};       // NaN / inf / non-integral / not a valid code: dropped
  std::uint64_t values_out_of_range{0};  // finite but outside the map's min / max: dropped
};

class PollDecoder {
 public:
  /// Allocates the per-block buffers and the output storage (not real-time).
  explicit PollDecoder(const ModbusConfig& config);

  /// Buffer of read block i: one element per register, or per bit (0 / 1) for bit tables.
  [[nodiscard]] std::span<std::uint16_t> block(std::size_t i) noexcept { return blocks_[i]; }
  [[nodiscard]] std::size_t block_count() const noexcept { return blocks_.size(); }

  /// Decodes one poll at time t_ns; block_ok[i] says whether block i was read in this poll.
  /// Groups with a block that was not read are skipped. The span is valid until the next call.
  /// Real-time safe: no allocation, no locks, no I/O.
  std::span<const core::Event> decode(core::TimeNs t_ns, std::span<const std::uint8_t> block_ok);

  [[nodiscard]] const DecodeCounters& counters() const noexcept { return counters_; }

 private:
  [[nodiscard]] double value(const SignalMap& s) const noexcept;
  /// False if a mapped field of g (the first n) holds a finite value outside its min / max.
  [[nodiscard]] bool in_range(const GroupMap& g, std::size_t n) const noexcept;
  void decode_axis(core::TimeNs t_ns);
  void decode_event(Group g, core::TimeNs t_ns);
  void decode_temperatures(core::TimeNs t_ns, std::span<const std::uint8_t> block_ok);
  void emit(const core::Event& e) noexcept;

  const ModbusConfig& config_;
  std::vector<std::vector<std::uint16_t>> blocks_;
  std::vector<core::Event> out_;
  struct SeqState {
    bool baseline{false};
    std::uint32_t last{0};
  };
  std::array<SeqState, kGroupCount> seq_{};
  std::vector<double> last_temperature_;
  DecodeCounters counters_{};
};

}  // namespace nccomp::drivers::modbus
