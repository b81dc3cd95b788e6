// Subcommand registry of the operator command `nccomp`.
//
// A subcommand lives in its own folder under tools/ and registers itself at static
// initialisation:
//
//   namespace { void setup(CLI::App& app) { auto* sub = app.add_subcommand("plan", "..."); ... } }
//   NCCOMP_REGISTER_COMMAND(plan, setup);
//
// A subcommand reports failure by throwing nccomp::tools::CommandError (exit code + message for
// the operator) or any std::exception (exit code 1).
#pragma once

#include <CLI/CLI.hpp>

#include <stdexcept>
#include <string>
#include <vector>

namespace nccomp::tools {

using SetupFn = void (*)(CLI::App&);

struct CommandEntry {
  const char* name;
  SetupFn setup;
};

/// Adds a subcommand's setup function; returns a dummy for static registration.
int register_command(const char* name, SetupFn setup);
/// All registered subcommands, sorted by name.
std::vector<CommandEntry> registered_commands();

/// An error meant for the operator: printed as "nccomp: error: <what>", exit status `code`.
class CommandError : public std::runtime_error {
 public:
  CommandError(int code, const std::string& what) : std::runtime_error(what), code_(code) {}
  [[nodiscard]] int code() const noexcept { return code_; }

 private:
  int code_;
};

/// Exit codes shared by the subcommands.
inline constexpr int kExitOk = 0;
inline constexpr int kExitFailure = 1;
inline constexpr int kExitUsage = 2;
inline constexpr int kExitInvalidInput = 3;

}  // namespace nccomp::tools

#define NCCOMP_REGISTER_COMMAND(ident, fn)                                                  \
  namespace {                                                                               \
  [[maybe_unused]] const int nccomp_command_registered_##ident =                            \
      ::nccomp::tools::register_command(#ident, fn);                                        \
  }
