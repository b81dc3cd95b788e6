#include "tools/daemonctl/status_socket.hpp"

#include <exception>

#include "client/protocol.hpp"
#include "client/status_client.hpp"
#include "tools/daemonctl/nccompd_process.hpp"
#include "tools/nccomp/command.hpp"

namespace nccomp::tools {

std::string status_socket_path(const std::string& socket, const std::string& config) {
  if (!socket.empty()) {
    return socket;
  }
  if (!config.empty()) {
    std::string path;
    try {
      path = run_nccompd_config_flag(config, "--print-status-socket");
    } catch (const CommandError& e) {
      if (e.code() != kExitInvalidInput) throw;
      throw CommandError(kExitInvalidInput, "cannot read " + config);
    }
    while (!path.empty() && path.back() == '\n') path.pop_back();
    if (!path.empty()) {
      return path;
    }
  }
  return std::string(client::kDefaultSocketPath);
}

std::string operator_command(const std::string& path, const std::string& request) {
  std::string answer;
  try {
    answer = client::query(path, request);
  } catch (const std::exception& e) {
    throw CommandError(kExitFailure, e.what());
  }
  if (client::is_error(answer)) {
    throw CommandError(kExitInvalidInput, client::error_reason(answer));
  }
  return answer;
}

}  // namespace nccomp::tools
