// `nccomp status [--json|--metrics] [--socket PATH | --config FILE]`: asks a running nccompd for
// its status over the Unix socket (loop statistics, registers, buses, state, last alarms). Exit
// status 1 when the daemon cannot be reached or answers an error (busy).
#include <cstdlib>
#include <iostream>
#include <memory>
#include <string>

#include "daemon/status.hpp"
#include "tools/daemonctl/status_socket.hpp"
#include "tools/nccomp/command.hpp"

namespace {

struct Options {
  std::string socket;
  std::string config;
  bool json{false};
  bool metrics{false};
};

void setup(CLI::App& app) {
  auto* sub = app.add_subcommand("status", "Show the status of the running nccompd");
  auto o = std::make_shared<Options>();
  sub->add_option("-s,--socket", o->socket, "Status socket (default /run/nccompd/status.sock)");
  sub->add_option("-c,--config", o->config, "Take the socket path from this configuration");
  sub->add_flag("--json", o->json, "Machine-readable JSON");
  sub->add_flag("--metrics", o->metrics, "Prometheus text format");
  sub->callback([o] {
    std::string answer;
    const std::string path = nccomp::tools::status_socket_path(o->socket, o->config);
    try {
      answer = nccomp::daemon::query_status(path, o->json      ? "json"
                                                  : o->metrics ? "metrics"
                                                               : "text");
    } catch (const std::exception& e) {
      throw nccomp::tools::CommandError(nccomp::tools::kExitFailure, e.what());
    }
    if (answer.empty()) {
      throw nccomp::tools::CommandError(nccomp::tools::kExitFailure, "no answer from " + path);
    }
    if (answer.rfind("error: ", 0) == 0) {  // e.g. busy: max_clients are being served
      while (!answer.empty() && answer.back() == '\n') answer.pop_back();
      throw nccomp::tools::CommandError(nccomp::tools::kExitFailure, answer.substr(7));
    }
    std::cout << answer;
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(status, setup);
