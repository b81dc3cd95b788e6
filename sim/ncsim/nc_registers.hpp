// The NC's offset registers with a real NC's semantics (issue 10 item 3): a write carries an
// absolute value; the NC range-checks it (out of range or not finite: refused, the register keeps
// its value); an accepted value takes effect after a configurable latency (the NC takes offsets
// at block boundaries / in its interpolator cycle, not at once). Pure: time comes in.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <vector>

namespace nccomp::sim::ncsim {

struct WriteRow {
  double t_s{0.0};
  std::uint16_t register_index{0};
  double value_um{0.0};
  double effective_t_s{0.0};
};

enum class WriteResult : std::uint8_t { kAccepted, kUnknownRegister, kOutOfRange };

class OffsetRegisters {
 public:
  /// known: the register indices the bus map carries; limit_um: the NC's own range check
  /// (|value| ≤ limit_um); latency_s: time from the write to the value being in force.
  OffsetRegisters(std::vector<std::uint16_t> known, double limit_um, double latency_s);

  /// A write received at t_s. Refused values leave the register as it was.
  WriteResult write(double t_s, std::uint16_t register_index, double value_um);
  /// Brings every pending write whose time has come into force. t_s must not decrease.
  void advance(double t_s);
  /// The value in force (after advance()); 0 for an unknown register.
  [[nodiscard]] double value(std::int32_t register_index) const;
  [[nodiscard]] bool known(std::int32_t register_index) const;
  /// The value the register holds when the run starts (not a write: not logged). False for an
  /// unknown register or a value out of range.
  bool preset(std::uint16_t register_index, double value_um);
  /// Every known register that was preset or written, with its last value (in force or
  /// pending), by index.
  [[nodiscard]] std::vector<std::pair<std::uint16_t, double>> held_values() const;
  /// Every accepted write, in order.
  [[nodiscard]] const std::vector<WriteRow>& log() const noexcept { return log_; }
  [[nodiscard]] std::size_t refused() const noexcept { return refused_; }
  /// Last written value per known register (in force or pending), for result.json.
  [[nodiscard]] std::vector<std::pair<std::uint16_t, double>> last_values() const;

 private:
  struct Pending {
    double effective_t_s;
    std::uint16_t index;
    double value_um;
  };
  static constexpr std::size_t kRegisterSpace = 65536;
  std::vector<double> value_;  // in force, by register index
  std::vector<bool> known_;
  std::vector<double> last_written_;
  std::deque<Pending> pending_;  // ordered by effective time (latency is constant)
  std::vector<WriteRow> log_;
  std::vector<std::uint16_t> preset_;
  double limit_um_;
  double latency_s_;
  std::size_t refused_{0};
};

}  // namespace nccomp::sim::ncsim
