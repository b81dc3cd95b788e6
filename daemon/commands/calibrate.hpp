// The "calibrate" verb of nccompd's status socket (docs/calibration.md, "In the daemon"): the
// operator's calibration commands (`nccomp calibrate --daemon SOCKET`), parsed and validated here
// on the status server's command thread with the calibration command language, queued to the loop
// as OperatorCommand events and answered from the calibration module's published snapshot
// (daemon/sections/calibration/daemon_link.hpp). Every command but the status ("calibrate" or
// "calibrate status") feeds the machine: only root and the admin group may (calibrate_access).
// Not real-time.
#pragma once

#include <string>
#include <string_view>

#include "daemon/commands/command.hpp"

namespace nccomp::daemon::commands {

/// The "calibrate" verb's handler: "ok <phase> <request>" and the calibrator's answer, or
/// "error: ..." (not a daemon command, no calibration module, queue full, refused by the
/// calibrator, no answer within 5 s).
std::string handle_calibrate_command(std::string_view args, CommandContext& ctx);

/// The "calibrate" verb's access rule: read-only for the status ("" or "status", what `nccomp
/// calibrate --daemon` polls), else it changes the machine (begin, touches, facets, discard,
/// recalibrate, and anything the calibrator takes in future).
CommandAccess calibrate_access(std::string_view args) noexcept;

}  // namespace nccomp::daemon::commands
