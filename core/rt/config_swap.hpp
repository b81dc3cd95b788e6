// Atomic configuration swap.
//
// Another thread builds a new immutable configuration and publish()es it; the loop thread calls
// pickup() at a cycle boundary, which swaps it in with one atomic exchange and hands the old one
// to a retire ring; reclaim(), called off the loop thread, deletes retired configurations.
// The loop thread never allocates or frees: if the retire ring is full it simply keeps running on
// its current configuration and picks the new one up on a later cycle.
//
// Threads: publish() and reclaim() from one non-real-time thread (or serialised by the caller);
// pickup() and current() from the loop thread only.
#pragma once

#include <atomic>
#include <cstddef>
#include <memory>

#include "core/rt/spsc_ring.hpp"

namespace nccomp::core::rt {

template <typename Config>
class ConfigSwap {
 public:
  /// @param initial the configuration the loop starts with (must not be null).
  /// @param retire_capacity slots for retired configurations awaiting reclaim (power of two).
  explicit ConfigSwap(std::unique_ptr<const Config> initial, std::size_t retire_capacity = 8)
      : current_(initial.release()), retired_(retire_capacity) {}

  ~ConfigSwap() {
    reclaim();
    delete pending_.exchange(nullptr, std::memory_order_acq_rel);
    delete current_;
  }

  ConfigSwap(const ConfigSwap&) = delete;
  ConfigSwap& operator=(const ConfigSwap&) = delete;

  /// Non-real-time thread: offers a new configuration. A configuration published earlier and not
  /// yet picked up is superseded and deleted here, on the caller's thread.
  void publish(std::unique_ptr<const Config> next) {
    delete pending_.exchange(next.release(), std::memory_order_acq_rel);
  }

  /// Loop thread, at a cycle boundary: takes a pending configuration if there is one and room to
  /// retire the old one. Returns true if the configuration changed. Wait-free, allocation-free.
  bool pickup() noexcept {
    if (pending_.load(std::memory_order_relaxed) == nullptr || retired_.free_slots() == 0) {
      return false;
    }
    const Config* next = pending_.exchange(nullptr, std::memory_order_acq_rel);
    if (next == nullptr) {
      return false;
    }
    // free_slots() > 0 was checked by the only producer: this push cannot fail.
    [[maybe_unused]] const bool pushed = retired_.try_push(current_);
    current_ = next;
    return true;
  }

  /// Loop thread: the configuration in force. Valid until the next pickup().
  [[nodiscard]] const Config& current() const noexcept { return *current_; }

  /// Non-real-time thread: frees retired configurations. Returns how many were freed.
  std::size_t reclaim() noexcept {
    std::size_t n = 0;
    const Config* old = nullptr;
    while (retired_.try_pop(old)) {
      delete old;
      ++n;
    }
    return n;
  }

  /// Non-real-time thread: true while a published configuration waits for pickup.
  [[nodiscard]] bool pending() const noexcept {
    return pending_.load(std::memory_order_acquire) != nullptr;
  }

 private:
  const Config* current_;  // loop thread only
  alignas(kCacheLine) std::atomic<const Config*> pending_{nullptr};
  SpscRing<const Config*> retired_;
};

}  // namespace nccomp::core::rt
