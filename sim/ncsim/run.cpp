#include "sim/ncsim/run.hpp"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <stdexcept>
#include <thread>

#include "drivers/can/can_config.hpp"
#include "drivers/modbus/config.hpp"
#include "sim/ncsim/bus_map.hpp"
#include "sim/ncsim/can_link.hpp"
#include "sim/ncsim/lockstep.hpp"
#include "sim/ncsim/modbus_link.hpp"
#include "sim/ncsim/result.hpp"
#include "sim/ncsim/simulation.hpp"

namespace nccomp::sim::ncsim {

namespace {

std::unique_ptr<NcLink> make_link(const SimConfig& config, BusKind bus,
                                  std::vector<std::uint16_t>& known, double& poll_rate_hz) {
  if (bus == BusKind::kModbus) {
    drivers::modbus::ModbusConfig map;
    try {
      const toml::table root =
          merged_bus_map(config.bus_map_text, config.bus_map_file, config.bus_map_extra_texts,
                         config.bus_map_extra_files);
      const toml::table* m = root["modbus"].as_table();
      if (m == nullptr) {
        throw std::runtime_error(config.bus_map_file + ": missing [modbus] table");
      }
      map = drivers::modbus::parse_modbus_table(*m, config.bus_map_file);
    } catch (const std::exception& e) {
      throw std::runtime_error(std::string("ncsim.bus_map: ") + e.what());
    }
    for (const auto& om : map.offsets) {
      known.push_back(om.register_index);
    }
    poll_rate_hz = map.poll_rate_hz;
    return std::make_unique<ModbusLink>(std::move(map), config.modbus_port,
                                        config.nc.offset_limit_um);
  }
  if (config.can_bus_map_text.empty()) {
    throw std::runtime_error("ncsim: --bus can needs ncsim.can_bus_map (reference-nc-can.toml)");
  }
  drivers::can::CanConfig can;
  try {
    const toml::table root =
        merged_bus_map(config.can_bus_map_text, config.can_bus_map_file,
                       config.can_bus_map_extra_texts, config.can_bus_map_extra_files);
    const toml::table* t = root["can"].as_table();
    if (t == nullptr) {
      throw std::runtime_error(config.can_bus_map_file + ": missing [can] table");
    }
    can = drivers::can::parse_can_table(*t, config.can_bus_map_file);
  } catch (const std::exception& e) {
    throw std::runtime_error(std::string("ncsim.can_bus_map: ") + e.what());
  }
  for (const auto& r : can.mapping.offsets) {
    known.push_back(r.register_index);
  }
  poll_rate_hz = 0.0;  // CAN pushes events: nothing to hold
  return std::make_unique<CanLink>(std::move(can), config.can_interface, config.nc.offset_limit_um);
}

}  // namespace

RunSummary run(const SimConfig& config, const RunOptions& options) {
  std::vector<std::uint16_t> known;
  double poll_rate_hz = 0.0;
  std::unique_ptr<NcLink> link_ptr = make_link(config, options.bus, known, poll_rate_hz);
  NcLink& link = *link_ptr;
  Simulation sim(config, options.program, known);
  link.preset_offsets(sim.registers().held_values());
  link.start();
  const auto period_ns =
      static_cast<core::TimeNs>(std::llround(core::kNsPerS / config.lockstep_rate_hz));
  RunSummary summary;
  auto take_writes = [&](double t_s) {
    for (const ReceivedOffset& w : link.take_writes()) {
      (void)sim.write_offset(t_s, w.register_index, w.value_um);
    }
  };
  if (!options.lockstep_socket.empty()) {
    LockstepServer server(options.lockstep_socket);
    if (options.on_ready) {
      options.on_ready(link.port());
    }
    server.accept(options.connect_timeout_s);
    const int request_reg = config.nc.measure_request_register;
    if (options.outage_at_request > 0 && (options.bus != BusKind::kModbus || request_reg < 0)) {
      throw std::runtime_error(
          "ncsim: a lock-step outage needs --bus modbus and nc.measure_request_register");
    }
    int request_rises = 0;
    bool request_up = false;
    std::int64_t outage_start_ns = -1;
    for (std::uint64_t k = 0;; ++k) {
      const auto t_ns = static_cast<core::TimeNs>(k) * period_ns;
      sim.advance_to(t_ns);
      link.publish(sim.axis(), sim.temperatures_c(), sim.take_events(), 0.0);
      link.before_tick(k);
      server.tick(k, t_ns);
      const auto reply = server.wait_done(k, options.done_timeout_s);
      summary.cycles = k + 1;
      if (reply == LockstepServer::Reply::kTimeout) {
        throw std::runtime_error("lockstep: no DONE for cycle " + std::to_string(k) + " within " +
                                 std::to_string(options.done_timeout_s) + " s");
      }
      if (reply != LockstepServer::Reply::kDone) {
        break;  // the daemon ended the run
      }
      // Writes the daemon pushed in this cycle reached the NC before DONE (Modbus) or before
      // its SYNC-ACK (CAN), and are taken at the tick's time (C2).
      if (!link.after_done(k, options.done_timeout_s)) {
        throw std::runtime_error("lockstep: no SYNC-ACK for cycle " + std::to_string(k));
      }
      take_writes(core::seconds(t_ns));
      if (sim.done() && !link.events_pending()) {
        summary.completed = true;
        server.bye();
        break;
      }
      if (options.outage_at_request > 0 && outage_start_ns < 0) {
        const bool up = std::fabs(sim.reg(request_reg)) > 0.0;
        request_rises += up && !request_up ? 1 : 0;
        request_up = up;
        if (request_rises == options.outage_at_request) {
          outage_start_ns = t_ns + core::from_seconds(options.outage_after_s);
        }
      }
      if (outage_start_ns >= 0 && t_ns >= outage_start_ns) {
        // The daemon goes down here (its caller kills it) and is back outage_s later: the NC
        // machines on alone meanwhile, and publishes what happens (the laser's result).
        std::printf(
            "ncsim: lock-step outage at cycle %llu (%.3f s): waiting for the daemon to go "
            "away\n",
            static_cast<unsigned long long>(k), core::seconds(t_ns));
        std::fflush(stdout);
        server.wait_closed(options.connect_timeout_s);
        const auto down =
            static_cast<std::uint64_t>(std::llround(options.outage_s * config.lockstep_rate_hz));
        for (std::uint64_t j = 0; j < down; ++j) {
          ++k;
          const auto tj = static_cast<core::TimeNs>(k) * period_ns;
          sim.advance_to(tj);
          link.publish(sim.axis(), sim.temperatures_c(), sim.take_events(), 0.0);
        }
        std::printf("ncsim: outage over at cycle %llu (%.3f s): waiting for the daemon\n",
                    static_cast<unsigned long long>(k),
                    core::seconds(static_cast<core::TimeNs>(k) * period_ns));
        std::fflush(stdout);
        server.accept(options.connect_timeout_s);
        outage_start_ns = std::numeric_limits<std::int64_t>::max();  // once
      }
    }
  } else {
    if (options.on_ready) {
      options.on_ready(link.port());
    }
    // Wait for a poller's first two polls: the daemon's first poll only takes the event
    // counters as a baseline, so events published before it would be lost.
    const auto wait_end =
        std::chrono::steady_clock::now() + std::chrono::duration<double>(options.wait_client_s);
    while (!link.client_ready() && std::chrono::steady_clock::now() < wait_end) {
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    // An event stays on the registers for a few polls before the next of its group.
    const double hold_s = poll_rate_hz > 0.0 ? 2.5 / poll_rate_hz : 0.0;
    const auto start = std::chrono::steady_clock::now();
    for (std::uint64_t k = 0;; ++k) {
      const auto t_ns = static_cast<core::TimeNs>(k) * period_ns;
      sim.advance_to(t_ns);
      take_writes(sim.time_s());
      link.publish(sim.axis(), sim.temperatures_c(), sim.take_events(), hold_s);
      summary.cycles = k + 1;
      if (sim.done() && !link.events_pending()) {
        summary.completed = true;
        break;
      }
      const auto next =
          start +
          std::chrono::duration_cast<std::chrono::steady_clock::duration>(
              std::chrono::duration<double>(core::seconds(t_ns + period_ns) / options.speed));
      std::this_thread::sleep_until(next);
    }
    // Writes still on their way when the program ended.
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    take_writes(sim.time_s());
  }
  link.stop();
  summary.sim_time_s = sim.time_s();
  summary.writes = sim.registers().log().size();
  summary.refused = sim.registers().refused() + link.writes_refused();
  RunInfo info{options.program, options.bus, link.writes_refused()};
  write_result(options.out_dir, sim, info);
  return summary;
}

}  // namespace nccomp::sim::ncsim
