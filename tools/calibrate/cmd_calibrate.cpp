// `nccomp calibrate`: the operator's side of S3 (docs/calibration.md).
//
//   nccomp calibrate --config machine.toml [--script FILE|-] [--state FILE] [--epoch UNIX_S]
//
// Without --script and with a terminal on stdin it prompts for commands, showing what to do
// next; with --script it runs the file (or stdin for '-') and stops at the first bad line.
// --state loads a saved calibration (if the file exists) and saves the result atomically.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>

#include "tools/calibrate/config_toml.hpp"
#include "tools/calibrate/script.hpp"
#include "tools/calibrate/session.hpp"
#include "tools/nccomp/command.hpp"

namespace {

using nccomp::tools::CommandError;
using nccomp::tools::kExitFailure;
using nccomp::tools::kExitInvalidInput;
namespace cal = nccomp::tools::calibrate;

struct Options {
  std::string config;
  std::string script;
  std::string state;
  double epoch_s{-1.0};
};

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw CommandError(kExitInvalidInput, path + ": cannot be read");
  }
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// Write a temporary file, flush it, rename over the target: a crash leaves the old state or
// the new one, never half of one.
void write_atomically(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out << text;
    out.flush();
    if (!out) {
      throw CommandError(kExitFailure, tmp + ": cannot be written");
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    throw CommandError(kExitFailure, path + ": cannot be replaced: " + ec.message());
  }
}

void run(const Options& o) {
  nccomp::core::calib::CalibrationConfig config;
  try {
    config = cal::load_calibration_config_file(o.config);
  } catch (const std::invalid_argument& e) {
    throw CommandError(kExitInvalidInput, e.what());
  }
  const double epoch =
      o.epoch_s >= 0.0
          ? o.epoch_s
          : std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch())
                .count();
  cal::Session session(config, epoch, std::cout);
  if (!o.state.empty() && std::filesystem::exists(o.state)) {
    try {
      session.import_state_text(read_file(o.state));
    } catch (const std::invalid_argument& e) {
      throw CommandError(kExitInvalidInput, o.state + ": " + e.what());
    }
    std::cout << "loaded state " << o.state << " (phase "
              << nccomp::core::calib::to_string(session.calibrator().phase()) << ")\n";
  }
  const bool interactive = o.script.empty() && isatty(STDIN_FILENO) != 0;
  std::ifstream file;
  std::istream* in = &std::cin;
  std::string source = "stdin";
  if (!o.script.empty() && o.script != "-") {
    file.open(o.script);
    if (!file) {
      throw CommandError(kExitInvalidInput, o.script + ": cannot be read");
    }
    in = &file;
    source = o.script;
  }
  if (interactive) {
    std::cout << "nccomp calibrate - type 'help' for the commands, 'quit' to save and leave\n";
  }
  std::string line;
  std::size_t line_no = 0;
  while (true) {
    if (interactive) {
      std::cout << "-- " << session.hint() << "\ncalibrate> " << std::flush;
    }
    if (!std::getline(*in, line)) {
      break;
    }
    ++line_no;
    try {
      if (!session.run(cal::parse_line(line, line_no), line_no)) {
        break;
      }
    } catch (const cal::ScriptError& e) {
      if (interactive) {
        std::cout << "error: " << e.what() << '\n';
        continue;
      }
      // A script stops at its first bad line and saves nothing: the operator fixes the file.
      throw CommandError(kExitInvalidInput, source + ": " + e.what());
    }
  }
  std::cout << "-- " << session.hint() << '\n';
  if (!o.state.empty()) {
    write_atomically(o.state, session.export_state_text());
    std::cout << "saved state " << o.state << '\n';
  }
  if (session.alarm_count() > 0) {
    std::cout << session.alarm_count() << " alarm(s) raised\n";
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<Options>();
  auto* sub = app.add_subcommand(
      "calibrate",
      "initial calibration (reference touches, test grinds, nominals) and recalibration of the "
      "machine (S3), interactive or from a script");
  sub->add_option("--config", opts->config, "TOML config with a [calibration] table")
      ->required()
      ->check(CLI::ExistingFile);
  sub->add_option("--script", opts->script,
                  "command file ('-' = stdin); without it a terminal gets a prompt");
  sub->add_option("--state", opts->state,
                  "calibration state file: loaded if it exists, saved at the end");
  sub->add_option("--epoch", opts->epoch_s,
                  "wall-clock time [Unix s] of the session's time 0 (default: now)");
  sub->callback([opts] { run(*opts); });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(calibrate, setup)
