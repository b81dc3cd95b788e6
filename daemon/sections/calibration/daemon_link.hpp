// The calibration module inside nccompd (docs/calibration.md, "In the daemon"):
// - the clock origin: wall clock minus the loop's clock, set on every CalibrationModule the
//   section builds and re-based at start-up (lock-step runs on the peer's clock), so that drift
//   models and creeps survive a daemon restart and a reboot;
// - at start-up: adopt a newer offline calibration ([calibration] state_file), then tell the
//   calibrator what the NC's axis registers hold (read back where the bus can);
// - the operator's commands ("calibrate ..." on the status socket): parsed and validated here on
//   the status server's command thread, queued to the loop as OperatorCommand events, answered
//   from the module's published snapshot. Every command but the status ("calibrate" or
//   "calibrate status") feeds the machine: only root and the admin group may (calibrate_access).
//   Not real-time (SnapshotSink::publish() is, on the loop thread).
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "core/calib/calib_module.hpp"
#include "core/engine/engine.hpp"
#include "daemon/command.hpp"
#include "daemon/daemon.hpp"

namespace nccomp::daemon::sections {

/// Wall clock minus the monotonic clock [s] the section gives new modules (the start-up hook's
/// value once it ran, so that a reloaded configuration keeps it).
double calibration_clock_offset_s();
/// The sink every CalibrationModule of this process publishes to.
core::calib::SnapshotSink& calibration_snapshot_sink();
/// The latest snapshot (publishes == 0: no calibration module has run yet).
core::calib::CalibSnapshot latest_calibration_snapshot();

/// The start-up work (run_daemon's hook "calibration"); returns lines for the log. wall_now_s is
/// the wall clock at now_ns (a parameter so that tests can put the process anywhere in time).
std::vector<std::string> calibration_startup(core::engine::Engine& engine,
                                             const RegisterReader& read, core::TimeNs now_ns,
                                             double wall_now_s);

/// The "calibrate" verb's handler.
std::string handle_calibrate_command(std::string_view args, CommandContext& ctx);

/// The "calibrate" verb's access rule: read-only for the status ("" or "status", what `nccomp
/// calibrate --daemon` polls), else it changes the machine (begin, touches, facets, discard,
/// recalibrate, and anything the calibrator takes in future).
CommandAccess calibrate_access(std::string_view args) noexcept;

}  // namespace nccomp::daemon::sections
