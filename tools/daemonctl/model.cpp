// `nccomp model load FILE | candidate FILE | promote | rollback | status [--socket PATH |
// --config FILE]`: the model of a running nccompd (docs/closing-the-loop.md, "Loading a model
// into a running daemon" and "A candidate in shadow"). candidate scores FILE in shadow beside the
// live model; promote makes it live once the rule found it better (promote = "operator"). load
// puts FILE in place of the [model] section's file and reloads with the same bumpless handover
// as SIGHUP; rollback returns to the model before it (or to none); status shows the live model,
// the one kept for rollback, the handover counters and the shadow. load, rollback, candidate and
// promote change the machine: the daemon takes them from root and members of [status]
// admin_group only; a refusal (also a file that does not parse or does not fit the configuration)
// exits 3 and changes nothing.
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>

#include "client/protocol.hpp"
#include "tools/daemonctl/status_socket.hpp"
#include "tools/nccomp/command.hpp"

namespace {

struct Options {
  std::string file;
  std::string socket;
  std::string config;
};

void add_socket_options(CLI::App* app, const std::shared_ptr<Options>& o) {
  app->add_option("-s,--socket", o->socket, "Status socket (default /run/nccompd/status.sock)");
  app->add_option("-c,--config", o->config, "Take the socket path from this configuration");
}

void setup(CLI::App& app) {
  auto* sub = app.add_subcommand("model", "The model of the running nccompd ([model])");
  sub->require_subcommand(1);
  auto o = std::make_shared<Options>();
  auto* load = sub->add_subcommand(
      "load", "Load a model.toml into the running daemon (bumpless handover, as a reload)");
  load->add_option("file", o->file, "The model file (nccomp analyze's model.toml)")->required();
  add_socket_options(load, o);
  load->callback([o] {
    const std::string path = nccomp::tools::status_socket_path(o->socket, o->config);
    // The daemon runs elsewhere: it gets the absolute path.
    const std::string file = std::filesystem::absolute(o->file).lexically_normal().string();
    std::cout << nccomp::tools::operator_command(path, nccomp::client::model_load_request(file));
  });
  auto* rollback =
      sub->add_subcommand("rollback", "Return to the model before the live one (or to none)");
  add_socket_options(rollback, o);
  rollback->callback([o] {
    const std::string path = nccomp::tools::status_socket_path(o->socket, o->config);
    std::cout << nccomp::tools::operator_command(path, nccomp::client::model_rollback_request());
  });
  auto* candidate = sub->add_subcommand(
      "candidate", "Score a model.toml in shadow beside the live one ([model.shadow] decides)");
  candidate->add_option("file", o->file, "The model file (nccomp analyze's model.toml)")
      ->required();
  add_socket_options(candidate, o);
  candidate->callback([o] {
    const std::string path = nccomp::tools::status_socket_path(o->socket, o->config);
    const std::string file = std::filesystem::absolute(o->file).lexically_normal().string();
    std::cout << nccomp::tools::operator_command(path,
                                                 nccomp::client::model_candidate_request(file));
  });
  auto* promote = sub->add_subcommand(
      "promote", "Make the candidate live once the rule announced it better (promote = operator)");
  add_socket_options(promote, o);
  promote->callback([o] {
    const std::string path = nccomp::tools::status_socket_path(o->socket, o->config);
    std::cout << nccomp::tools::operator_command(path, nccomp::client::model_promote_request());
  });
  auto* status = sub->add_subcommand(
      "status", "The live model, the one kept for rollback, and the handover counters");
  add_socket_options(status, o);
  status->callback([o] {
    const std::string path = nccomp::tools::status_socket_path(o->socket, o->config);
    std::cout << nccomp::tools::operator_command(path, nccomp::client::model_status_request());
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(model, setup);
