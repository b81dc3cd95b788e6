// nccompd as a program that nccomp runs: `nccomp check-config` and `--config FILE` (the status
// socket of a configuration) ask the daemon's own loader (`nccompd --check-config`,
// `nccompd --print-status-socket`), so that nccomp needs no part of the daemon. Not real-time.
#pragma once

#include <string>
#include <vector>

namespace nccomp::tools {

/// The nccompd to run: $NCCOMPD, else beside this nccomp (the same directory, ../sbin/nccompd as
/// installed, ../daemon/nccompd in the build tree), else the first in PATH, else
/// /usr/sbin/nccompd. Throws CommandError(kExitFailure) when none is an executable file.
[[nodiscard]] std::string find_nccompd();

struct ProgramRun {
  int exit_code{-1};  // 128 + signal if it was killed
  std::string out;    // its standard output
  std::string err;    // its standard error
};

/// Runs program with args (argv[1] on) and its standard output and error captured; waits for it.
/// Throws CommandError(kExitFailure) when it cannot be started.
[[nodiscard]] ProgramRun run_program(const std::string& program,
                                     const std::vector<std::string>& args);

/// Runs `nccompd --config FILE <flag>` for a daemon flag that loads the configuration and exits
/// 0, or 3 with the loader's errors on standard error and "nccompd: <summary>" as their last line.
/// Returns its standard output when it exited 0; otherwise writes the errors to this process's
/// standard error and throws CommandError with the summary (exit code 3), or with what went wrong
/// (exit code 1).
[[nodiscard]] std::string run_nccompd_config_flag(const std::string& file, const std::string& flag);

}  // namespace nccomp::tools
