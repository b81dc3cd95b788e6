// `nccomp status [--json|--metrics] [--socket PATH | --config FILE]`: asks a running nccompd for
// its status over the Unix socket (loop statistics, registers, buses, state, last alarms). Exit
// status 1 when the daemon cannot be reached or answers an error (busy).
#include <cstdlib>
#include <iostream>
#include <memory>
#include <string>

#include "client/protocol.hpp"
#include "client/status_client.hpp"
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
    namespace client = nccomp::client;
    try {
      answer = client::query(path, o->json      ? client::kStatusJson
                                   : o->metrics ? client::kStatusMetrics
                                                : client::kStatusText);
    } catch (const std::exception& e) {
      throw nccomp::tools::CommandError(nccomp::tools::kExitFailure, e.what());
    }
    if (client::is_error(answer)) {  // e.g. busy: max_clients are being served
      throw nccomp::tools::CommandError(nccomp::tools::kExitFailure, client::error_reason(answer));
    }
    std::cout << answer;
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(status, setup);
