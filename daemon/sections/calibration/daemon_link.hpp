// The calibration module inside nccompd (docs/calibration.md, "In the daemon"):
// - the clock origin: wall clock minus the loop's clock, set on every CalibrationModule the
//   section builds and re-based at start-up (lock-step runs on the peer's clock), so that drift
//   models and creeps survive a daemon restart and a reboot;
// - at start-up: adopt a newer offline calibration ([calibration] state_file), then tell the
//   calibrator what the NC's axis registers hold (read back where the bus can);
// - the snapshot every module publishes, from which the "calibrate" verb answers
//   (daemon/commands/calibrate.hpp).
// Not real-time (SnapshotSink::publish() is, on the loop thread).
#pragma once

#include <string>
#include <vector>

#include "core/calib/calib_module.hpp"
#include "core/engine/engine.hpp"
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

}  // namespace nccomp::daemon::sections
