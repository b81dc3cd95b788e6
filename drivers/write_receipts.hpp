// Per offset register of a bus, the receipt of the newest write its I/O thread finished with
// (Bus::write_receipt()): published by the I/O thread, read by the loop thread. One atomic word
// per register (sequence << 2 | outcome): lock-free, wait-free, no allocation after the
// constructor. The loop hands the receipts to the engine, which limits each register's next write
// from what the NC holds (core/engine/engine.hpp, "Write receipts").
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>

#include "core/common/types.hpp"

namespace nccomp::drivers {

class WriteReceipts {
 public:
  /// Not real-time: one word per register slot of the driver, all "nothing finished".
  explicit WriteReceipts(std::size_t slots)
      : words_(std::make_unique<std::atomic<std::uint64_t>[]>(slots)) {}

  /// I/O thread: the write `sequence` of `slot` finished with `outcome`. A write without a
  /// sequence (0: no receipt wanted) publishes nothing.
  void publish(std::size_t slot, std::uint64_t sequence, core::WriteOutcome outcome) noexcept {
    if (sequence != 0) {
      words_[slot].store((sequence << 2) | static_cast<std::uint64_t>(outcome),
                         std::memory_order_release);
    }
  }
  /// Any thread (the loop): the newest receipt of `slot`.
  [[nodiscard]] core::WriteReceipt load(std::size_t slot) const noexcept {
    const std::uint64_t w = words_[slot].load(std::memory_order_acquire);
    return core::WriteReceipt{w >> 2, static_cast<core::WriteOutcome>(w & 3U)};
  }

 private:
  std::unique_ptr<std::atomic<std::uint64_t>[]> words_;
};

/// The receipt a driver gives for a register it has no mapping for: every write of it refused.
inline constexpr core::WriteReceipt kUnmappedReceipt{~std::uint64_t{0} >> 2,
                                                     core::WriteOutcome::kRefused};

}  // namespace nccomp::drivers
