// `nccomp acknowledge [--socket PATH | --config FILE]`: acknowledges the latched alarms of a
// running nccompd (docs/daemon.md, "Operator commands"): the creep module's halt after a broken or
// mis-measured tool (alarm 23) or an excessive increment (alarm 22, on_excessive = "stop"), its
// alarm and warning flags, and the hold of the measurement request, so that the overdue laser
// measurement is asked for again. One "acknowledge" request on the status socket; the daemon
// answers once its loop has taken the command, with what was cleared. Changes the machine: the
// daemon takes it from root and members of [status] admin_group only; a refusal exits 3.
#include <iostream>
#include <memory>
#include <string>

#include "client/protocol.hpp"
#include "tools/daemonctl/status_socket.hpp"
#include "tools/nccomp/command.hpp"

namespace {

struct Options {
  std::string socket;
  std::string config;
};

void setup(CLI::App& app) {
  auto* sub = app.add_subcommand(
      "acknowledge",
      "Acknowledge the latched alarms of the running nccompd (the creep module's halt and flags)");
  auto o = std::make_shared<Options>();
  sub->add_option("-s,--socket", o->socket, "Status socket (default /run/nccompd/status.sock)");
  sub->add_option("-c,--config", o->config, "Take the socket path from this configuration");
  sub->callback([o] {
    const std::string path = nccomp::tools::status_socket_path(o->socket, o->config);
    std::cout << nccomp::tools::operator_command(path, nccomp::client::acknowledge_request());
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(acknowledge, setup);
