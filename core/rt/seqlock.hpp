// A seqlock snapshot: one writer (the loop thread) publishes multi-word state; any number of
// readers (status socket, metrics) copy a consistent snapshot without blocking the writer.
//
// The payload is stored as atomic words (Boehm, "Can seqlocks get along with programming
// language memory models?", 2012), so a reader that races with the writer reads words that may
// be torn *between* words, never undefined behaviour, and the sequence check rejects the copy.
//
// Real-time behaviour: store() is wait-free (no allocation, no lock, no syscall). load() is
// lock-free: it retries while a write is in progress.
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <optional>
#include <type_traits>

#include "core/rt/spsc_ring.hpp"

namespace nccomp::core::rt {

template <typename T>
class Seqlock {
  static_assert(std::is_trivially_copyable_v<T>, "Seqlock payload must be trivially copyable");
  static constexpr std::size_t kWords = (sizeof(T) + sizeof(std::uint64_t) - 1) / sizeof(std::uint64_t);

 public:
  Seqlock() { store(T{}); }
  explicit Seqlock(const T& initial) { store(initial); }

  /// Writer only (one thread). Wait-free.
  void store(const T& value) noexcept {
    std::array<std::uint64_t, kWords> buf{};
    std::memcpy(buf.data(), &value, sizeof(T));
    const std::uint64_t s = seq_.load(std::memory_order_relaxed);
    seq_.store(s + 1, std::memory_order_relaxed);
    // Release on each word orders the odd sequence number before it: a reader that sees any new
    // word also sees the write in progress. (No standalone fences: ThreadSanitizer cannot model
    // them, and on x86 release stores and acquire loads cost nothing extra.)
    for (std::size_t i = 0; i < kWords; ++i) {
      words_[i].store(buf[i], std::memory_order_release);
    }
    seq_.store(s + 2, std::memory_order_release);
  }

  /// Any thread. One attempt: nullopt if a write was in progress.
  [[nodiscard]] std::optional<T> try_load() const noexcept {
    std::array<std::uint64_t, kWords> buf{};
    const std::uint64_t s1 = seq_.load(std::memory_order_acquire);
    if ((s1 & 1U) != 0) {
      return std::nullopt;
    }
    // Acquire on each word keeps the second sequence read after the copy.
    for (std::size_t i = 0; i < kWords; ++i) {
      buf[i] = words_[i].load(std::memory_order_acquire);
    }
    const std::uint64_t s2 = seq_.load(std::memory_order_relaxed);
    if (s1 != s2) {
      return std::nullopt;
    }
    // T is trivially copyable; its default member initialisers are overwritten byte for byte.
    T out{};
    std::memcpy(static_cast<void*>(&out), buf.data(), sizeof(T));
    return out;
  }

  /// Any thread. Retries until a consistent copy is read.
  [[nodiscard]] T load() const noexcept {
    for (;;) {
      if (auto v = try_load()) {
        return *v;
      }
    }
  }

  /// Number of completed writes.
  [[nodiscard]] std::uint64_t version() const noexcept {
    return seq_.load(std::memory_order_acquire) / 2;
  }

 private:
  alignas(kCacheLine) std::atomic<std::uint64_t> seq_{0};
  std::array<std::atomic<std::uint64_t>, kWords> words_{};
};

}  // namespace nccomp::core::rt
