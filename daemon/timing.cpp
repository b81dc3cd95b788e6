#include "daemon/timing.hpp"

#include <bit>

namespace nccomp::daemon {

Deadline advance_deadline(TimeNs current_ns, TimeNs now_ns, TimeNs period_ns,
                          config::OverrunPolicy policy) noexcept {
  const TimeNs next = current_ns + period_ns;
  if (now_ns < next) {
    return {next, 0};
  }
  if (policy == config::OverrunPolicy::kRestart) {
    const auto missed = static_cast<std::uint64_t>((now_ns - current_ns) / period_ns);
    return {now_ns + period_ns, missed};
  }
  // Deadlines current+k·period for k = 1..n are past (or now); the next one is k = n + 1.
  const auto n = (now_ns - current_ns) / period_ns;
  return {current_ns + (n + 1) * period_ns, static_cast<std::uint64_t>(n)};
}

std::size_t LatencyHistogram::bucket_of(std::uint64_t us) noexcept {
  if (us < kLinear) {
    return static_cast<std::size_t>(us);
  }
  const auto e = static_cast<std::size_t>(std::bit_width(us) - 1);  // ≥ 10
  const std::size_t group = e - 10;
  if (group >= kGroups) {
    return kBuckets - 1;
  }
  const auto sub = static_cast<std::size_t>((us >> (e - 6)) & (kSub - 1));
  return kLinear + group * kSub + sub;
}

std::uint64_t LatencyHistogram::upper_edge_us(std::size_t bucket) noexcept {
  if (bucket < kLinear) {
    return bucket + 1;
  }
  const std::size_t group = (bucket - kLinear) / kSub;
  const std::size_t sub = (bucket - kLinear) % kSub;
  const std::size_t e = group + 10;
  return (std::uint64_t{1} << e) +
         (static_cast<std::uint64_t>(sub) + 1) * (std::uint64_t{1} << (e - 6));
}

void LatencyHistogram::record(TimeNs latency_ns) noexcept {
  const TimeNs l = latency_ns < 0 ? 0 : latency_ns;
  const std::size_t b = bucket_of(static_cast<std::uint64_t>(l) / 1000U);
  // Single writer: load + store is enough and cheaper than a locked read-modify-write.
  counts_[b].store(counts_[b].load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
  total_.store(total_.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
  sum_ns_.store(sum_ns_.load(std::memory_order_relaxed) + static_cast<std::uint64_t>(l),
                std::memory_order_relaxed);
  if (l > max_ns_.load(std::memory_order_relaxed)) {
    max_ns_.store(l, std::memory_order_relaxed);
  }
}

std::uint64_t LatencyHistogram::count() const noexcept {
  return total_.load(std::memory_order_relaxed);
}

double LatencyHistogram::sum_s() const noexcept {
  return static_cast<double>(sum_ns_.load(std::memory_order_relaxed)) / 1e9;
}

bool LatencyHistogram::is_edge_us(std::uint64_t us) noexcept {
  const std::size_t b = bucket_of(us);
  return b == 0 ? us == 0 : upper_edge_us(b - 1) == us;
}

void LatencyHistogram::count_below_us(std::span<const std::uint64_t> edges_us,
                                      std::span<std::uint64_t> out,
                                      std::uint64_t& total) const noexcept {
  std::size_t e = 0;
  std::uint64_t seen = 0;
  for (std::size_t b = 0; b < kBuckets; ++b) {
    // Bucket b holds the samples from its lower edge up to, not including, upper_edge_us(b).
    const std::uint64_t lower_us = b == 0 ? 0 : upper_edge_us(b - 1);
    while (e < edges_us.size() && e < out.size() && edges_us[e] <= lower_us) {
      out[e++] = seen;
    }
    seen += counts_[b].load(std::memory_order_relaxed);
  }
  for (; e < edges_us.size() && e < out.size(); ++e) {
    out[e] = seen;
  }
  total = seen;
}

double LatencyHistogram::quantile_us(double q) const noexcept {
  std::uint64_t total = 0;
  for (const auto& c : counts_) {
    total += c.load(std::memory_order_relaxed);
  }
  if (total == 0) {
    return 0.0;
  }
  const double rank = q * static_cast<double>(total);
  std::uint64_t seen = 0;
  for (std::size_t b = 0; b < kBuckets; ++b) {
    seen += counts_[b].load(std::memory_order_relaxed);
    if (static_cast<double>(seen) >= rank && seen > 0) {
      return static_cast<double>(upper_edge_us(b));
    }
  }
  return static_cast<double>(upper_edge_us(kBuckets - 1));
}

void LatencyHistogram::reset() noexcept {
  for (auto& c : counts_) {
    c.store(0, std::memory_order_relaxed);
  }
  total_.store(0, std::memory_order_relaxed);
  max_ns_.store(0, std::memory_order_relaxed);
  sum_ns_.store(0, std::memory_order_relaxed);
}

}  // namespace nccomp::daemon
