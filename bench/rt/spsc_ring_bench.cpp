// SPSC ring throughput: one producer thread, one consumer thread, ns per item.
// Peer in the same run: a std::mutex-protected std::deque (what a first version would use).
#include <benchmark/benchmark.h>

#include <atomic>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>

#include "core/rt/spsc_ring.hpp"

namespace {

constexpr std::uint64_t kBatch = 1 << 16;

class MutexQueue {
 public:
  explicit MutexQueue(std::size_t capacity) : capacity_(capacity) {}
  bool try_push(std::uint64_t v) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (queue_.size() == capacity_) {
      return false;
    }
    queue_.push_back(v);
    return true;
  }
  bool try_pop(std::uint64_t& v) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (queue_.empty()) {
      return false;
    }
    v = queue_.front();
    queue_.pop_front();
    return true;
  }

 private:
  std::size_t capacity_;
  std::mutex mutex_;
  std::deque<std::uint64_t> queue_;
};

template <typename Queue>
void run(benchmark::State& state, Queue& q) {
  std::atomic<std::uint64_t> target{0};
  std::atomic<bool> stop{false};
  std::uint64_t sum = 0;
  std::thread consumer([&] {
    std::uint64_t received = 0;
    std::uint64_t v = 0;
    for (;;) {
      if (q.try_pop(v)) {
        sum += v;
        ++received;
      } else if (stop.load(std::memory_order_acquire) &&
                 received == target.load(std::memory_order_acquire)) {
        break;
      }
    }
  });
  std::uint64_t sent = 0;
  for (auto _ : state) {
    for (std::uint64_t i = 0; i < kBatch; ++i) {
      while (!q.try_push(sent)) {
      }
      ++sent;
    }
  }
  target.store(sent, std::memory_order_release);
  stop.store(true, std::memory_order_release);
  consumer.join();
  benchmark::DoNotOptimize(sum);
  state.SetItemsProcessed(static_cast<std::int64_t>(sent));
  // Reported in seconds per item with an SI prefix: "4.1n" is 4.1 ns per item.
  state.counters["ns_per_item"] = benchmark::Counter(
      static_cast<double>(sent), benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}

void BM_SpscRing(benchmark::State& state) {
  nccomp::core::rt::SpscRing<std::uint64_t> ring(static_cast<std::size_t>(state.range(0)));
  run(state, ring);
}

void BM_MutexDequePeer(benchmark::State& state) {
  MutexQueue q(static_cast<std::size_t>(state.range(0)));
  run(state, q);
}

}  // namespace

BENCHMARK(BM_SpscRing)->Arg(1024)->Arg(65536)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_MutexDequePeer)->Arg(1024)->Arg(65536)->UseRealTime()->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();
