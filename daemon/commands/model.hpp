// The "model" verb of nccompd's status socket (docs/closing-the-loop.md, "Loading a model into a
// running daemon"): `nccomp model load PATH` puts PATH in place of the [model] section's file and
// reloads (the bumpless handover of a SIGHUP), `nccomp model rollback` returns to the model before
// (or to none), `nccomp model status` shows the live model, the one kept for rollback and the
// handover counters; `nccomp model candidate PATH` scores PATH in shadow beside the live model and
// `nccomp model promote` makes a candidate the rule found better live (docs/closing-the-loop.md,
// "A candidate in shadow"). load, rollback, candidate and promote change the machine (root and the
// admin group only, logged with the caller); status is read-only. The daemon runs the change on its
// main thread (CommandContext::change_model): a model that does not load or does not fit the
// configuration is refused with the configuration's errors and nothing changes. Not real-time.
#pragma once

#include <string>
#include <string_view>

#include "daemon/commands/command.hpp"

namespace nccomp::daemon::commands {

/// "model load PATH" | "model candidate PATH" | "model promote" | "model rollback" |
/// "model status". Answers "ok ..." or "error: ...".
std::string handle_model_command(std::string_view args, CommandContext& ctx);

/// status is read-only; load, rollback (and anything malformed) change the machine.
CommandAccess model_access(std::string_view args) noexcept;

}  // namespace nccomp::daemon::commands
