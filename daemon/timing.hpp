// Timing pieces of the loop, pure and unit-tested: the deadline policy after an overrun and the
// wake-up latency histogram.
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <span>

#include "core/common/types.hpp"
#include "daemon/config/builtin_sections.hpp"

namespace nccomp::daemon {

using core::TimeNs;

struct Deadline {
  /// The next absolute wake-up time [ns].
  TimeNs next_ns{0};
  /// Deadlines that were skipped because the loop was late (0 = on time).
  std::uint64_t missed{0};
};

/// After a cycle that started at deadline `current_ns` and finished at `now_ns`: the next deadline.
/// On time (now < current + period): current + period. Late (an overrun): with kSkipMissed the
/// first deadline on the original grid that is still in the future; with kRestart now + period.
/// Neither policy lets the loop run a burst of back-to-back cycles to catch up (ros2_control's
/// sleeping policy; a burst would hand the NC stale, bunched-up writes).
/// Real-time safe.
[[nodiscard]] Deadline advance_deadline(TimeNs current_ns, TimeNs now_ns, TimeNs period_ns,
                                        config::OverrunPolicy policy) noexcept;

/// The systemd watchdog's rule: feed it only if the loop's heartbeat advanced since the last
/// check, so a stalled loop (the process alive, the loop not) is restarted by systemd.
class HeartbeatWatch {
 public:
  explicit HeartbeatWatch(std::uint64_t initial) noexcept : last_(initial) {}
  /// True if `beat` differs from the beat seen at the previous call (or construction).
  bool advanced(std::uint64_t beat) noexcept {
    const bool moved = beat != last_;
    last_ = beat;
    return moved;
  }

 private:
  std::uint64_t last_;
};

/// Wake-up latency histogram with fixed buckets: 1 µs wide up to 1024 µs, then 64 buckets per
/// power of two up to ~2^41 µs. One writer (the loop thread: record() is wait-free, no
/// allocation), any number of readers (relaxed atomics: a reader may see a histogram a few
/// samples out of date, never a torn count).
class LatencyHistogram {
 public:
  static constexpr std::size_t kLinear = 1024;
  static constexpr std::size_t kSub = 64;
  static constexpr std::size_t kGroups = 32;
  static constexpr std::size_t kBuckets = kLinear + kGroups * kSub;

  /// Writer only. Real-time safe.
  void record(TimeNs latency_ns) noexcept;
  /// Any thread: the latency [µs] below which fraction q (0..1) of the samples lie (the upper
  /// edge of the bucket holding the q-quantile); 0 if empty.
  [[nodiscard]] double quantile_us(double q) const noexcept;
  [[nodiscard]] std::uint64_t count() const noexcept;
  /// Any thread: the sum of the recorded latencies [s] (a Prometheus histogram's _sum).
  [[nodiscard]] double sum_s() const noexcept;
  /// Any thread, one pass: out[i] = the samples below edges_us[i] (ascending bucket edges, see
  /// is_edge_us: then the count is exact), `total` = all samples, so out[i] <= total.
  void count_below_us(std::span<const std::uint64_t> edges_us, std::span<std::uint64_t> out,
                      std::uint64_t& total) const noexcept;
  /// True if `us` is the lower edge of a bucket: a sample is counted below it exactly.
  [[nodiscard]] static bool is_edge_us(std::uint64_t us) noexcept;
  [[nodiscard]] std::int64_t max_ns() const noexcept {
    return max_ns_.load(std::memory_order_relaxed);
  }
  /// Writer only (or when no writer runs).
  void reset() noexcept;

  /// Bucket of a latency [µs] and a bucket's upper edge [µs]; exposed for tests.
  [[nodiscard]] static std::size_t bucket_of(std::uint64_t us) noexcept;
  [[nodiscard]] static std::uint64_t upper_edge_us(std::size_t bucket) noexcept;

 private:
  std::array<std::atomic<std::uint64_t>, kBuckets> counts_{};
  std::atomic<std::uint64_t> total_{0};
  std::atomic<std::int64_t> max_ns_{0};
  std::atomic<std::uint64_t> sum_ns_{0};
};

}  // namespace nccomp::daemon
