// `nccomp calibrate`: the operator's side of S3 (docs/calibration.md).
//
//   nccomp calibrate --config machine.toml [--script FILE|-] [--state FILE] [--epoch UNIX_S]
//   nccomp calibrate --daemon SOCKET [--script FILE|-] [--interactive]
//
// Without --script and with a terminal on stdin (or --interactive) it prompts for commands,
// showing what to do next; with --script it runs the file (or stdin for '-') and stops at the
// first bad line. --state loads a saved calibration (if the file exists) and saves the result
// atomically. --daemon runs the same commands against a running nccompd's calibrator (status
// socket): the daemon validates and answers each; wait / await / facets-file run here.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>

#include <thread>

#include "client/protocol.hpp"
#include "client/status_client.hpp"
#include "formats/calib/config_toml.hpp"
#include "formats/calib/facet_import.hpp"
#include "formats/calib/script.hpp"
#include "tools/calibrate/session.hpp"
#include "tools/nccomp/command.hpp"

namespace {

using nccomp::tools::CommandError;
using nccomp::tools::kExitFailure;
using nccomp::tools::kExitInvalidInput;
using nccomp::tools::kExitUsage;
namespace cal = nccomp::tools::calibrate;
namespace client = nccomp::client;

struct Options {
  std::string config;
  std::string script;
  std::string state;
  std::string daemon;
  double epoch_s{-1.0};
  bool interactive{false};
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

// ---------------------------------------------------------------------------------------------
// Against a running daemon.

client::CalibrateAnswer ask(const std::string& socket, const std::string& command) {
  try {
    // 15 s: the daemon answers within 5 s once the loop took the command.
    return client::parse_calibrate_answer(
        client::query(socket, client::calibrate_request(command), 15.0));
  } catch (const std::exception& e) {
    throw CommandError(kExitFailure, e.what());
  }
}

// The command text without a comment (the daemon parses it again).
std::string command_text(const std::string& line) {
  std::string t = line.substr(0, line.find('#'));
  while (!t.empty() && (t.back() == ' ' || t.back() == '\t' || t.back() == '\r')) t.pop_back();
  std::size_t b = 0;
  while (b < t.size() && (t[b] == ' ' || t[b] == '\t')) ++b;
  return t.substr(b);
}

void run_daemon(const Options& o) {
  const bool interactive = o.interactive || (o.script.empty() && isatty(STDIN_FILENO) != 0);
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
  client::CalibrateAnswer first = ask(o.daemon, "");
  if (!first.ok) {
    throw CommandError(kExitFailure, o.daemon + ": " + first.text);
  }
  std::cout << "nccomp calibrate on " << o.daemon << " (phase " << first.phase << ")\n";
  std::string hint_text = first.text;
  if (interactive) {
    std::cout << "type 'help' for the commands, 'quit' to leave\n";
  }
  std::string line;
  std::size_t line_no = 0;
  std::size_t errors = 0;
  // column: of the offending word, 0 for the whole line.
  const auto fail = [&](const std::string& what, std::size_t column = 0) {
    ++errors;
    if (interactive) {
      std::cout << "error: " << what << '\n';
      return;
    }
    throw CommandError(
        kExitInvalidInput,
        nccomp::formats::format(nccomp::formats::Diagnostic{
            {source, static_cast<int>(line_no), static_cast<int>(column), ""}, what}));
  };
  while (true) {
    if (interactive) {
      std::cout << hint_text << "calibrate> " << std::flush;
    }
    if (!std::getline(*in, line)) {
      break;
    }
    ++line_no;
    cal::Command cmd;
    try {
      cmd = cal::parse_line(line, line_no);
    } catch (const cal::ScriptError& e) {
      fail(e.diagnostic().message, static_cast<std::size_t>(e.diagnostic().where.column));
      continue;
    }
    std::string send;
    bool quit = false;
    std::visit(
        [&](const auto& c) {
          using T = std::decay_t<decltype(c)>;
          if constexpr (std::is_same_v<T, cal::CmdEmpty>) {
          } else if constexpr (std::is_same_v<T, cal::CmdHelp>) {
            std::cout << cal::script_help();
          } else if constexpr (std::is_same_v<T, cal::CmdQuit>) {
            quit = true;
          } else if constexpr (std::is_same_v<T, cal::CmdTime> ||
                               std::is_same_v<T, cal::CmdTemperature>) {
            fail("'" + command_text(line).substr(0, command_text(line).find(' ')) +
                 "' works offline only: the daemon runs on its own clock and takes temperatures "
                 "from the NC");
          } else if constexpr (std::is_same_v<T, cal::CmdWait>) {
            std::this_thread::sleep_for(std::chrono::duration<double>(c.duration_s));
            std::cout << "waited " << c.duration_s << " s\n";
          } else if constexpr (std::is_same_v<T, cal::CmdAwait>) {
            const std::string want = nccomp::core::calib::to_string(c.phase);
            const auto end =
                std::chrono::steady_clock::now() + std::chrono::duration<double>(c.timeout_s);
            client::CalibrateAnswer a = ask(o.daemon, "");
            while (a.ok && a.phase != want && std::chrono::steady_clock::now() < end) {
              std::this_thread::sleep_for(std::chrono::milliseconds(100));
              a = ask(o.daemon, "");
            }
            if (!a.ok) {
              fail(a.text);
            } else if (a.phase != want) {
              fail("the daemon did not reach " + want + " within " +
                   std::to_string(static_cast<int>(c.timeout_s)) + " s (phase " + a.phase + ")");
            } else {
              std::cout << "phase " << a.phase << '\n';
              hint_text = a.text;
            }
          } else if constexpr (std::is_same_v<T, cal::CmdFacetsFile>) {
            std::vector<cal::FacetMeasurement> rows;
            try {
              rows = cal::read_facet_export(c.path);
            } catch (const std::invalid_argument& e) {
              fail(e.what());
              return;
            }
            if (c.row > rows.size()) {
              fail(c.path + ": has " + std::to_string(rows.size()) + " rows, not " +
                   std::to_string(c.row));
              return;
            }
            const auto& m = rows[c.row == 0 ? rows.size() - 1 : c.row - 1];
            std::cout << "from " << c.path << " line " << m.line << ":\n";
            char buf[128];
            std::snprintf(buf, sizeof buf, "facets %s %.6f %.6f",
                          m.face == nccomp::core::calib::Face::kLateral ? "lateral" : "end-face",
                          m.chord_plus_mm, m.chord_minus_mm);
            send = buf;
          } else {
            send = command_text(line);
          }
        },
        cmd);
    if (quit) {
      break;
    }
    if (send.empty()) {
      continue;
    }
    const client::CalibrateAnswer a = ask(o.daemon, send);
    if (!a.ok) {
      // The daemon's "error: ..." with the prompt after it.
      const auto nl = a.text.find('\n');
      std::string what = a.text.substr(0, nl);
      if (what.rfind("error: ", 0) == 0) what.erase(0, 7);
      fail(what);
      if (nl != std::string::npos) {
        std::cout << a.text.substr(nl + 1);
        hint_text.clear();
      }
      continue;
    }
    // The daemon's answer ends with the prompt line ("-- ..."): shown before the next command.
    const auto cut = a.text.rfind("-- ");
    std::cout << a.text.substr(0, cut);
    hint_text = cut == std::string::npos ? "" : a.text.substr(cut);
  }
  std::cout << hint_text;
  if (errors > 0) {
    std::cout << errors << " command(s) refused\n";
  }
}

void run(const Options& o) {
  if (!o.daemon.empty()) {
    if (!o.state.empty() || o.epoch_s >= 0.0) {
      throw CommandError(kExitUsage,
                         "--state and --epoch are offline options: the daemon keeps its own state "
                         "(adopt an offline state with [calibration] state_file)");
    }
    run_daemon(o);
    return;
  }
  if (o.config.empty()) {
    throw CommandError(kExitUsage, "--config FILE or --daemon SOCKET is required");
  }
  nccomp::core::calib::CalibrationConfig config;
  try {
    config = nccomp::formats::calib::load_calibration_config_file(o.config);
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
  const bool interactive = o.interactive || (o.script.empty() && isatty(STDIN_FILENO) != 0);
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
      throw CommandError(kExitInvalidInput, e.in_file(source));
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
  sub->add_option("--config", opts->config, "TOML config with a [calibration] table (offline)")
      ->check(CLI::ExistingFile);
  sub->add_option("--daemon", opts->daemon,
                  "run against a running nccompd: its status socket (e.g. "
                  "/run/nccompd/status.sock)");
  sub->add_flag("--interactive", opts->interactive,
                "prompt even when stdin is not a terminal (each command answered, then the "
                "prompt)");
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
