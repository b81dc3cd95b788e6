// What one step of a core module produces, in fixed-capacity storage sized at compile time, so
// step() never allocates. The caller clears it before each cycle and forwards its contents
// (offset writes → bus TX ring, alarms → alarm ring / NC alarm register, records → measurement
// log ring).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

#include "core/common/types.hpp"

namespace nccomp::core {

/// A vector with fixed capacity N and no allocation. push() refuses when full and counts it.
template <typename T, std::size_t N>
class FixedVector {
 public:
  /// Real-time safe. Returns false (and counts an overflow) when full.
  bool push(const T& v) noexcept {
    if (size_ == N) {
      ++overflows_;
      return false;
    }
    items_[size_++] = v;
    return true;
  }
  void clear() noexcept { size_ = 0; }
  [[nodiscard]] std::size_t size() const noexcept { return size_; }
  [[nodiscard]] bool empty() const noexcept { return size_ == 0; }
  [[nodiscard]] static constexpr std::size_t capacity() noexcept { return N; }
  [[nodiscard]] std::uint64_t overflows() const noexcept { return overflows_; }
  [[nodiscard]] const T& operator[](std::size_t i) const noexcept { return items_[i]; }
  [[nodiscard]] T& operator[](std::size_t i) noexcept { return items_[i]; }
  [[nodiscard]] std::span<const T> view() const noexcept { return {items_.data(), size_}; }
  [[nodiscard]] const T* begin() const noexcept { return items_.data(); }
  [[nodiscard]] const T* end() const noexcept { return items_.data() + size_; }

 private:
  std::array<T, N> items_{};
  std::size_t size_{0};
  std::uint64_t overflows_{0};
};

/// Output of one core step. Capacities cover the worst case of one cycle with margin; an overflow
/// is counted (and must show up in status), never silently ignored.
struct StepOutput {
  FixedVector<OffsetWrite, 128> writes;
  FixedVector<AlarmEvent, 32> alarms;
  FixedVector<MeasurementRecord, 64> records;
  /// Additive trims (core/engine/engine.hpp, "Trims"): value_um is this module's whole trim of
  /// the register, replacing the one it published before. The engine adds every module's trim to
  /// the register's target; a trim never leaves the engine by itself.
  FixedVector<OffsetWrite, 32> trims;

  void clear() noexcept {
    writes.clear();
    alarms.clear();
    records.clear();
    trims.clear();
  }
  /// Convenience for modules: raise an alarm / warning / info.
  void alarm(TimeNs t_ns, Severity severity, AlarmCode code, std::int32_t subject,
             double value) noexcept {
    alarms.push(AlarmEvent{t_ns, severity, code, subject, value});
  }
};

}  // namespace nccomp::core
