// The status socket of a running nccompd, as `nccomp status` and `nccomp warm-start` find it:
// --socket PATH, else the [status] socket_path of --config FILE, else /run/nccompd/status.sock.
#pragma once

#include <string>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"
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

}  // namespace nccomp::tools
