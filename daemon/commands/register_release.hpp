// The "register" verb of nccompd's status socket: `nccomp register release NAME` (or `all`) ends
// the start-up hold of a register (core/engine/engine.hpp, RegisterHold): one whose NC value lay
// beyond max_abs_um (the daemon's value is then written in one move, within the limits), or one
// whose module had no usable state and could not adopt the NC's value (the register then moves
// from the NC's value to the module's through the limiter). Validated here on the status thread
// (an unknown name or argument is refused and counted), queued to the loop as an
// OperatorCommand kRegisterRelease; the answer waits until the loop took it. Logged. Not
// real-time.
#pragma once

#include <string>
#include <string_view>

#include "daemon/commands/command.hpp"

namespace nccomp::daemon::commands {

/// The "register" verb's handler: "ok released ..." with what each released register was held
/// for, "ok ... not held: nothing to release", or "error: ...".
std::string handle_register_command(std::string_view args, CommandContext& ctx);

}  // namespace nccomp::daemon::commands
