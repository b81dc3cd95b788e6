// The "acknowledge" verb of nccompd's status socket (docs/daemon.md, "Operator commands"):
// `nccomp acknowledge` clears the latched alarms of the running daemon ("acknowledge" or
// "acknowledge all"): the creep module's halt after a broken / mis-measured tool (alarm 23) or an
// excessive increment (alarm 22, on_excessive = "stop"), its alarm and warning flags and the hold
// of the measurement request. Changes the machine: only root and the admin group may (the
// registry's default, daemon/commands/command.hpp). Validated here on the status server's command
// thread (anything else is refused and counted), queued to the loop as an OperatorCommand
// kAcknowledge, taken by the modules in one cycle (core/creep/creep_module.hpp); the answer waits
// until the loop has taken it and a status of the modules published after it shows what was
// cleared. Not real-time.
#pragma once

#include <string>
#include <string_view>

#include "daemon/commands/command.hpp"

namespace nccomp::daemon::commands {

/// The "acknowledge" verb's handler. Answers "ok acknowledged: ..." with what each module that
/// takes acknowledgements cleared, or "error: ..." (unknown argument, no loop, queue full, no
/// answer within 3 s).
std::string handle_acknowledge_command(std::string_view args, CommandContext& ctx);

}  // namespace nccomp::daemon::commands
