// A wait-free single-producer / single-consumer ring of fixed capacity.
//
// - Capacity is a power of two, fixed at construction; the only allocation is in the
//   constructor (like rigtorp/SPSCQueue).
// - The producer's and the consumer's indices live on separate cache lines, and each side keeps
//   a cached copy of the other's index, so in the common case a push or pop touches only its own
//   cache line.
// - Acquire/release ordering only; indices grow monotonically and are masked on access (no
//   wasted slot, unsigned wrap-around is well defined).
//
// Real-time behaviour: try_push / try_pop / front / pop are wait-free, never allocate, never
// lock, never throw (T's move/copy must be noexcept). Exactly one producer thread and one
// consumer thread.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>
#include <stdexcept>
#include <type_traits>
#include <utility>

namespace nccomp::core::rt {

/// Destructive interference size; a fixed 64 keeps the layout independent of compiler flags.
inline constexpr std::size_t kCacheLine = 64;

template <typename T>
class SpscRing {
  static_assert(std::is_nothrow_move_constructible_v<T>, "T must be nothrow move constructible");
  static_assert(std::is_nothrow_destructible_v<T>, "T must be nothrow destructible");

 public:
  /// @param capacity number of slots; must be a power of two ≥ 2. Allocates (not real-time).
  explicit SpscRing(std::size_t capacity) : capacity_(capacity), mask_(capacity - 1) {
    if (capacity < 2 || (capacity & (capacity - 1)) != 0) {
      throw std::invalid_argument("SpscRing: capacity must be a power of two >= 2");
    }
    slots_ = static_cast<Slot*>(::operator new[](capacity * sizeof(Slot), std::align_val_t{alignof(Slot)}));
  }

  ~SpscRing() {
    while (front() != nullptr) {
      pop();
    }
    ::operator delete[](slots_, std::align_val_t{alignof(Slot)});
  }

  SpscRing(const SpscRing&) = delete;
  SpscRing& operator=(const SpscRing&) = delete;

  /// Producer: constructs an element in place. Returns false (and constructs nothing) if full.
  template <typename... Args>
  [[nodiscard]] bool try_emplace(Args&&... args) noexcept(
      std::is_nothrow_constructible_v<T, Args&&...>) {
    const std::size_t write = write_.load(std::memory_order_relaxed);
    if (write - read_cache_ == capacity_) {
      read_cache_ = read_.load(std::memory_order_acquire);
      if (write - read_cache_ == capacity_) {
        return false;
      }
    }
    new (&slots_[write & mask_].storage) T(std::forward<Args>(args)...);
    write_.store(write + 1, std::memory_order_release);
    return true;
  }

  /// Producer: copies or moves value in. Returns false if full.
  [[nodiscard]] bool try_push(const T& value) noexcept(std::is_nothrow_copy_constructible_v<T>) {
    return try_emplace(value);
  }
  [[nodiscard]] bool try_push(T&& value) noexcept { return try_emplace(std::move(value)); }

  /// Consumer: the oldest element, or nullptr if empty.
  [[nodiscard]] T* front() noexcept {
    const std::size_t read = read_.load(std::memory_order_relaxed);
    if (read == write_cache_) {
      write_cache_ = write_.load(std::memory_order_acquire);
      if (read == write_cache_) {
        return nullptr;
      }
    }
    return std::launder(reinterpret_cast<T*>(&slots_[read & mask_].storage));
  }

  /// Consumer: removes the oldest element; front() must have returned non-null.
  void pop() noexcept {
    const std::size_t read = read_.load(std::memory_order_relaxed);
    std::launder(reinterpret_cast<T*>(&slots_[read & mask_].storage))->~T();
    read_.store(read + 1, std::memory_order_release);
  }

  /// Consumer: moves the oldest element into out. Returns false if empty.
  [[nodiscard]] bool try_pop(T& out) noexcept(std::is_nothrow_move_assignable_v<T>) {
    T* p = front();
    if (p == nullptr) {
      return false;
    }
    out = std::move(*p);
    pop();
    return true;
  }

  /// Either side: an instantaneous estimate; exact when called by a side whose peer is idle.
  [[nodiscard]] std::size_t size_approx() const noexcept {
    const std::size_t w = write_.load(std::memory_order_acquire);
    const std::size_t r = read_.load(std::memory_order_acquire);
    return w - r;
  }
  [[nodiscard]] bool empty_approx() const noexcept { return size_approx() == 0; }
  /// Producer: exact lower bound on free slots (space only grows concurrently).
  [[nodiscard]] std::size_t free_slots() const noexcept {
    return capacity_ - (write_.load(std::memory_order_relaxed) - read_.load(std::memory_order_acquire));
  }
  [[nodiscard]] std::size_t capacity() const noexcept { return capacity_; }

 private:
  struct Slot {
    alignas(T) unsigned char storage[sizeof(T)];
  };

  // Read-mostly, shared by both sides.
  const std::size_t capacity_;
  const std::size_t mask_;
  Slot* slots_{nullptr};

  // Producer's line: its index and its cache of the consumer's.
  alignas(kCacheLine) std::atomic<std::size_t> write_{0};
  std::size_t read_cache_{0};
  // Consumer's line: its index and its cache of the producer's.
  alignas(kCacheLine) std::atomic<std::size_t> read_{0};
  std::size_t write_cache_{0};
  // Keep whatever follows this object off the consumer's line.
  char padding_[kCacheLine - sizeof(std::atomic<std::size_t>) - sizeof(std::size_t)]{};
};

}  // namespace nccomp::core::rt
