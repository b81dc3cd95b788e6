// One ncsim run: the simulation, the bus side and the clock (speed factor or lock-step), then the
// result directory. Used by the `ncsim` executable and the tests. Not real-time.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "sim/ncsim/sim_config.hpp"

namespace nccomp::sim::ncsim {

struct RunOptions {
  ProgramKind program{ProgramKind::kMouldFace};
  BusKind bus{BusKind::kModbus};
  std::string out_dir;
  /// Sim time per wall time (ignored in lock-step).
  double speed{1.0};
  /// Lock-step socket path; empty = run on the speed factor.
  std::string lockstep_socket;
  /// Speed mode: wait this long for the daemon's first polls before the clock starts [s].
  double wait_client_s{10.0};
  /// Lock-step: how long to wait for the daemon to connect, and for each DONE [s].
  double connect_timeout_s{30.0};
  double done_timeout_s{10.0};
  /// Lock-step, Modbus: an outage of the daemon (a restart; docs/ncsim.md). outage_s of simulated
  /// time after the outage_at_request-th rise of the NC's measure request register, ncsim stops
  /// ticking, prints "ncsim: lock-step outage ...", waits for the daemon to go away (killed by
  /// the caller), machines outage_s of simulated time without it and then waits for a daemon to
  /// connect and goes on. 0 = no outage.
  int outage_at_request{0};
  double outage_after_s{0.0};
  double outage_s{0.0};
  /// Called once the bus is up, with the Modbus port (0 for CAN): tests start their peer here.
  std::function<void(std::uint16_t)> on_ready;
};

struct RunSummary {
  double sim_time_s{0.0};
  std::uint64_t cycles{0};
  std::size_t writes{0};
  std::uint64_t refused{0};
  bool completed{false};  // the program ran to its end (false: the daemon said BYE / left)
};

/// Runs the program to its end and writes the result. Throws std::runtime_error with the reason.
RunSummary run(const SimConfig& config, const RunOptions& options);

}  // namespace nccomp::sim::ncsim
