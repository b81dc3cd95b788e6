// The "warm-start" verb of nccompd's status socket (docs/daemon.md, "Warm start"): `nccomp
// warm-start` declares the machine's warm start now ("warm-start" or "warm-start now"), or makes
// the machine cold so that its next axis motion is the warm start ("warm-start at-next-motion").
// Changes the machine: only root and the admin group may (the registry's default,
// daemon/commands/command.hpp). Validated here on the status server's command thread (anything else
// is refused and counted), queued to the loop as an OperatorCommand kWarmStart, taken by the
// engine's machine context (core/engine/context.hpp); the answer waits until the loop has taken
// it (EngineCounters). Not real-time.
#pragma once

#include <string>
#include <string_view>

#include "daemon/commands/command.hpp"

namespace nccomp::daemon::commands {

/// The "warm-start" verb's handler. Answers "ok ..." with the warm starts counted so far, or
/// "error: ..." (unknown argument, no loop, queue full, no answer within 3 s).
std::string handle_warm_start_command(std::string_view args, CommandContext& ctx);

}  // namespace nccomp::daemon::commands
