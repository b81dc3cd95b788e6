// `nccomp register release NAME|all [--socket PATH | --config FILE]`: ends the start-up hold of a
// register of the running nccompd (docs/daemon.md, "Start-up: registers beyond the limits and
// modules without state"): one whose NC value lay beyond max_abs_um (the daemon's value is
// written in one move, within the limits) or one whose module had no usable state and could not
// adopt the NC's value. One "register release ..." request on the status socket; the daemon
// answers once its loop has taken the command, with what each register was held for.
#include <iostream>
#include <memory>
#include <string>

#include "client/protocol.hpp"
#include "tools/daemonctl/status_socket.hpp"
#include "tools/nccomp/command.hpp"

namespace {

struct Options {
  std::string name;
  std::string socket;
  std::string config;
};

void setup(CLI::App& app) {
  auto* sub = app.add_subcommand("register", "Registers of the running nccompd");
  sub->require_subcommand(1);
  auto* release = sub->add_subcommand(
      "release",
      "End the start-up hold of a register (beyond max_abs_um, or without state); 'all' ends "
      "every hold");
  auto o = std::make_shared<Options>();
  release->add_option("name", o->name, "The register's name in [[registers]], or 'all'")
      ->required();
  release->add_option("-s,--socket", o->socket, "Status socket (default /run/nccompd/status.sock)");
  release->add_option("-c,--config", o->config, "Take the socket path from this configuration");
  release->callback([o] {
    const std::string path = nccomp::tools::status_socket_path(o->socket, o->config);
    std::cout << nccomp::tools::operator_command(path,
                                                 nccomp::client::register_release_request(o->name));
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(register, setup);
