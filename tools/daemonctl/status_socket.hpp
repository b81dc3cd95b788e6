// The status socket of a running nccompd, as `nccomp status`, `warm-start` and `acknowledge` find
// it: --socket PATH, else the [status] socket_path of --config FILE, else /run/nccompd/status.sock;
// and the request / answer of an operator command on it.
#pragma once

#include <exception>
#include <string>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"
#include "daemon/status.hpp"
#include "tools/nccomp/command.hpp"

namespace nccomp::tools {

/// Throws CommandError(kExitInvalidInput) when the config cannot be read.
inline std::string status_socket_path(const std::string& socket, const std::string& config) {
  if (!socket.empty()) {
    return socket;
  }
  if (!config.empty()) {
    namespace cfg = nccomp::daemon::config;
    auto r = cfg::load_file(config);
    if (!r.config) {
      throw CommandError(kExitInvalidInput, r.diagnostics.to_string() + "cannot read " + config);
    }
    const auto& s = cfg::status_section(*r.config);
    if (!s.socket_path.empty()) {
      return r.config->resolve(s.socket_path);
    }
  }
  return "/run/nccompd/status.sock";
}

/// Sends an operator command's request line to the daemon at path and returns its "ok ..."
/// answer. Throws CommandError(kExitFailure) when the daemon cannot be reached or does not
/// answer, CommandError(kExitInvalidInput) when it refuses ("error: <why>", a malformed or not
/// permitted command: the message is <why>).
inline std::string operator_command(const std::string& path, const std::string& request) {
  std::string answer;
  try {
    answer = nccomp::daemon::query_status(path, request);
  } catch (const std::exception& e) {
    throw CommandError(kExitFailure, e.what());
  }
  if (answer.empty()) {
    throw CommandError(kExitFailure, "no answer from " + path);
  }
  if (answer.rfind("error: ", 0) == 0) {
    std::string what = answer.substr(7);
    while (!what.empty() && what.back() == '\n') what.pop_back();
    throw CommandError(kExitInvalidInput, what);
  }
  return answer;
}

}  // namespace nccomp::tools
