// Turns the registers of one poll into core events: one AxisSample per poll, an event per
// advanced sequence counter, a TemperatureSample when a temperature changed.
//
// Events over a polled bus: the NC writes an event's value registers first and then increments
// its sequence counter, which is kSequenceStart (0) when the NC has just started; the counter and
// the values are read in one request (config.hpp makes sure of that), so they always belong
// together. Per poll, k being the number of events the counter says happened since the last read:
//   - first poll after start without a cursor (resume()): the counter is a baseline, nothing is
//     emitted (its event is old);
//   - first poll after start with a cursor, the counter of the last event the engine took
//     before nccompd stopped (saved with its state): the rules below against the cursor, the
//     events counted in events_recovered_after_start / events_lost_while_down instead (they
//     happened while nccompd was down) and reported in resume_reports();
//   - counter unchanged: nothing;
//   - advanced by k (also through the top of its range, 65535 -> 0 for uint16, as long as that
//     means k <= kMaxWrapEvents): the latest event is emitted once and k − 1 are counted as lost
//     (the NC produced events faster than the poll rate);
//   - moved back otherwise, to n: the NC restarted and counted again from kSequenceStart, so
//     k = n − kSequenceStart events happened since its restart: counted as a sequence reset, the
//     latest (k >= 1) emitted once, k − 1 counted as lost. Events the NC produced between the
//     last read and its restart are unknown: neither emitted nor counted.
// Counters and baselines survive a reconnect, so events produced while the link was down show
// up as one emitted event plus lost ones, never twice. The one case the counter cannot show: an
// NC that restarted and produced exactly as many events as it had before. After a reconnect
// (note_reconnect()) a counter that reads the same value as before, other than kSequenceStart,
// is counted in sequence_unchanged_after_reconnect, so that an operator can see the doubt.
//
// Plausibility: a finite value outside its signal's `min` / `max` (config) counts
// values_out_of_range; NaN / inf / non-integral / invalid codes count values_invalid. An axis
// sample, tool change or program event with such a value is dropped. A measurement (tool
// measurement, probe measurement, calibration touch) is emitted once, marked faulted
// (core::InputFault) with its values cleared, so that its method raises its alarm instead of
// losing it in silence. Either way an event's counter is consumed, so it is not re-read.
//
// Every emitted event carries its counter (core::EventOrigin, `numbered`), which the engine keeps
// as its cursor; a counter consumed without an event (a baseline, an NC restart with none since)
// is emitted as a counter_only event, so that the cursor follows it.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/common/types.hpp"
#include "drivers/modbus/config.hpp"

namespace nccomp::drivers::modbus {

/// An NC's event counter right after the NC started (no event yet): what the reference profile
/// (ncsim, sim/modbus_nc) and PLCs with non-retentive counters do.
inline constexpr std::uint32_t kSequenceStart = 0;
/// A counter that moved back is taken for a wrap through the top of its range only if that means
/// at most this many events since the last read, else for an NC restart. A few events happen
/// between two polls, a few hundred at most across a long outage; the price is that a restart
/// from one of the top 256 counter values (uint16: 65280..65535) to a small one can be taken for a
/// wrap (docs/modbus.md, "NC restarts").
inline constexpr std::uint32_t kMaxWrapEvents = 256;

struct DecodeCounters {
  std::uint64_t events_lost{0};  // events the counter says happened but were not emitted
  // First read after a start with a cursor: the newest of the events the NC produced while
  // nccompd was down, emitted; and the others, not emitted.
  std::uint64_t events_recovered_after_start{0};
  std::uint64_t events_lost_while_down{0};
  std::uint64_t sequence_resets{0};  // counter moved backwards (NC restart)
  // First read after a reconnect saw the same counter (not kSequenceStart): an NC restart that
  // produced exactly as many events as before cannot be ruled out (its newest would be missed).
  std::uint64_t sequence_unchanged_after_reconnect{0};
  std::uint64_t values_invalid{0};       // NaN / inf / non-integral / not a valid code: dropped
  std::uint64_t values_out_of_range{0};  // finite but outside the map's min / max: dropped
};

/// What the first read of one event group's counter after a start with a cursor found.
struct ResumeReport {
  bool done{false};          // the first read happened (the fields below are set)
  std::uint32_t cursor{0};   // the engine's last event before nccompd stopped
  std::uint32_t counter{0};  // the NC's counter at the first read
  bool nc_restarted{false};  // it moved back: the NC counted again from kSequenceStart
  std::uint32_t events{0};   // events since the cursor (since the NC's restart), as it tells
  bool delivered{false};     // the newest was emitted (false: none, or its values were refused)
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

  /// The driver re-established its connection (the NC may have restarted meanwhile): the next
  /// read of each event counter is checked for an unchanged counter. Real-time safe.
  void note_reconnect() noexcept;

  /// Before the first decode(): the engine's cursors (core::numbered_kind() order). A group with
  /// a known cursor compares its first read with it instead of taking it as a baseline.
  void resume(const core::EventCursorSet& cursors) noexcept;
  /// Per group (Group order): what its first read after resume() found.
  [[nodiscard]] const std::array<ResumeReport, kGroupCount>& resume_reports() const noexcept {
    return resume_;
  }

  [[nodiscard]] const DecodeCounters& counters() const noexcept { return counters_; }

 private:
  [[nodiscard]] double value(const SignalMap& s) const noexcept;
  /// False if a mapped field of g (the first n) holds a finite value outside its min / max.
  [[nodiscard]] bool in_range(const GroupMap& g, std::size_t n) const noexcept;
  void decode_axis(core::TimeNs t_ns);
  void decode_event(Group g, core::TimeNs t_ns);
  void decode_temperatures(core::TimeNs t_ns, std::span<const std::uint8_t> block_ok);
  void emit(const core::Event& e) noexcept;
  /// Emits a measurement; one whose values are out of range (range_ok false) or invalid (ok
  /// false) is counted and emitted faulted (core::InputFault), its values cleared.
  void emit_measurement(core::Event e, bool range_ok, bool ok) noexcept;
  /// A counter consumed without an event to deliver (core::EventOrigin::counter_only).
  void emit_counter(Group g, core::TimeNs t_ns, std::uint32_t seq) noexcept;

  const ModbusConfig& config_;
  std::vector<std::vector<std::uint16_t>> blocks_;
  std::vector<core::Event> out_;
  struct SeqState {
    bool baseline{false};
    bool reconnected{false};  // no read of this counter since the last reconnect
    bool resumed{false};      // `last` is the engine's cursor, not read from the NC yet
    std::uint32_t last{0};
  };
  std::array<SeqState, kGroupCount> seq_{};
  std::array<ResumeReport, kGroupCount> resume_{};
  std::vector<double> last_temperature_;
  DecodeCounters counters_{};
};

}  // namespace nccomp::drivers::modbus
