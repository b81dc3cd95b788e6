// `nccomp warm-start [--at-next-motion] [--socket PATH | --config FILE]`: tells a running nccompd
// that the machine's warm start is now (the origin of the measurement log's time_s and of the
// [model]'s warm-up terms), or that the machine is cold and its next axis motion is the warm start
// (docs/daemon.md, "Warm start"). One "warm-start ..." request on the status socket; the daemon
// answers once its loop has taken the command. Changes the machine: the daemon takes it from root
// and members of [status] admin_group only; a refusal exits 3.
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
  bool at_next_motion{false};
};

void setup(CLI::App& app) {
  auto* sub = app.add_subcommand(
      "warm-start", "Declare the machine's warm start to the running nccompd (time_s restarts)");
  auto o = std::make_shared<Options>();
  sub->add_option("-s,--socket", o->socket, "Status socket (default /run/nccompd/status.sock)");
  sub->add_option("-c,--config", o->config, "Take the socket path from this configuration");
  sub->add_flag("--at-next-motion", o->at_next_motion,
                "The machine is cold now: its next axis motion is the warm start");
  sub->callback([o] {
    const std::string path = nccomp::tools::status_socket_path(o->socket, o->config);
    std::cout << nccomp::tools::operator_command(
        path, nccomp::client::warm_start_request(o->at_next_motion));
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(warm_start, setup);
