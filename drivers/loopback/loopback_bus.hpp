// An in-process bus with no hardware behind it: offset writes are "delivered" by its I/O thread
// (counted and remembered per register), events are whatever inject() puts in. It lets an
// operator commission the daemon without a bus ([loopback] section) and lets tests run the whole
// process without vcan or a Modbus server.
#pragma once

#include <atomic>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <thread>

#include "drivers/bus.hpp"

namespace nccomp::drivers::loopback {

class LoopbackBus final : public drivers::Bus {
 public:
  LoopbackBus(std::size_t rx_capacity, std::size_t tx_capacity);
  ~LoopbackBus() override;

  void start() override;
  void stop() override;
  core::rt::SpscRing<core::Event>& rx() override { return rx_; }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return tx_; }
  [[nodiscard]] drivers::BusStatus status() const override { return status_.load(); }

  /// One producer thread (tests): queues an event for the loop. False if the ring is full.
  bool inject(const core::Event& e);
  /// Last value delivered for a register, if any (any thread).
  [[nodiscard]] std::optional<double> delivered(std::uint16_t register_index) const;

  /// What one register received, as an NC would see it.
  struct Delivery {
    double first_um{0.0};
    double last_um{0.0};
    /// Largest change between two consecutive delivered values; the first write is measured
    /// against 0, the value of a register nobody wrote yet [µm].
    double largest_step_um{0.0};
    std::uint64_t writes{0};
  };
  /// The register's delivery record, if anything was delivered (any thread).
  [[nodiscard]] std::optional<Delivery> delivery(std::uint16_t register_index) const;

 private:
  void run();

  core::rt::SpscRing<core::Event> rx_;
  core::rt::SpscRing<core::OffsetWrite> tx_;
  core::rt::Seqlock<drivers::BusStatus> status_;
  drivers::BusStatus local_{};  // I/O thread's copy; published through status_
  mutable std::mutex mu_;
  std::map<std::uint16_t, Delivery> delivered_;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> injected_{0};
  std::thread thread_;
};

}  // namespace nccomp::drivers::loopback
