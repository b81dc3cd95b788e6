#include "drivers/loopback/loopback_bus.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

namespace nccomp::drivers::loopback {

LoopbackBus::LoopbackBus(std::size_t rx_capacity, std::size_t tx_capacity)
    : rx_(rx_capacity), tx_(tx_capacity) {}

LoopbackBus::~LoopbackBus() { stop(); }

void LoopbackBus::start() {
  if (thread_.joinable()) {
    return;
  }
  stop_.store(false);
  local_.state = drivers::LinkState::kUp;
  status_.store(local_);
  thread_ = std::thread([this] { run(); });
}

void LoopbackBus::stop() {
  stop_.store(true);
  if (thread_.joinable()) {
    thread_.join();
  }
  local_.state = drivers::LinkState::kStopped;
  status_.store(local_);
}

bool LoopbackBus::inject(const core::Event& e) {
  if (!rx_.try_push(e)) {
    return false;
  }
  injected_.fetch_add(1, std::memory_order_relaxed);
  return true;
}

std::optional<double> LoopbackBus::delivered(std::uint16_t register_index) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = delivered_.find(register_index);
  if (it == delivered_.end()) {
    return std::nullopt;
  }
  return it->second.last_um;
}

std::optional<LoopbackBus::Delivery> LoopbackBus::delivery(std::uint16_t register_index) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = delivered_.find(register_index);
  if (it == delivered_.end()) {
    return std::nullopt;
  }
  return it->second;
}

void LoopbackBus::run() {
  // A real driver would block in its bus call; here a short sleep stands for the bus cycle.
  while (!stop_.load(std::memory_order_acquire)) {
    core::OffsetWrite w;
    bool any = false;
    while (tx_.try_pop(w)) {
      any = true;
      {
        std::lock_guard<std::mutex> lock(mu_);
        auto [it, fresh] = delivered_.try_emplace(w.register_index);
        Delivery& d = it->second;
        const double previous = fresh ? 0.0 : d.last_um;
        if (fresh) {
          d.first_um = w.value_um;
        }
        d.largest_step_um = std::max(d.largest_step_um, std::fabs(w.value_um - previous));
        d.last_um = w.value_um;
        ++d.writes;
      }
      ++local_.counters.frames_tx;
      ++local_.counters.offsets_written;
    }
    local_.counters.events_decoded = injected_.load(std::memory_order_relaxed);
    if (any) {
      local_.last_rx_ns = w.time_ns;
    }
    status_.store(local_);
    std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
}

}  // namespace nccomp::drivers::loopback
