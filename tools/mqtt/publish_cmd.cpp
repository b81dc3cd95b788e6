// `nccomp publish --config FILE [--check]`: the MQTT publisher (docs/mqtt.md). Runs until SIGTERM
// or SIGINT; systemd/nccomp-publish.service starts it.
#include <spdlog/spdlog.h>

#include <atomic>
#include <csignal>
#include <iostream>
#include <memory>
#include <string>

#include "tools/mqtt/mqtt_config.hpp"
#include "tools/mqtt/publisher.hpp"
#include "tools/nccomp/command.hpp"

namespace {

std::atomic<bool> g_stop{false};

extern "C" void on_signal(int) { g_stop.store(true); }

void setup(CLI::App& app) {
  auto* sub = app.add_subcommand(
      "publish", "Publish measurement rows, alarms, model changes and a heartbeat over MQTT");
  auto config = std::make_shared<std::string>();
  auto check = std::make_shared<bool>(false);
  sub->add_option("-c,--config", *config, "Configuration (nccomp-publish.toml)")->required();
  sub->add_flag("--check", *check, "Validate the configuration and the password file, then exit");
  sub->callback([config, check] {
    namespace mq = nccomp::tools::mqtt;
    nccomp::formats::Diagnostics diag;
    auto c = mq::load_publish_config(*config, diag);
    if (!c) {
      std::cerr << diag.to_string();
      throw nccomp::tools::CommandError(
          nccomp::tools::kExitInvalidInput,
          std::to_string(diag.items().size()) + " error(s) in " + *config);
    }
    std::string password;
    try {
      if (!c->broker.password_file.empty())
        password = mq::read_password_file(c->broker.password_file);
    } catch (const std::exception& e) {
      throw nccomp::tools::CommandError(nccomp::tools::kExitInvalidInput, e.what());
    }
    if (*check) {
      std::cout << *config << ": OK\n  topics: "
                << mq::topic(c->site, c->machine, "{measurements,alarms,model,status}")
                << "\n  broker: " << c->broker.uri << " as "
                << (c->broker.username.empty() ? "(no user)" : c->broker.username) << ", client id "
                << c->broker.client_id << "\n  log: " << c->log_directory
                << "\n  queue: " << c->queue_directory << " (at most " << c->max_messages
                << " messages)\n";
      return;
    }
    std::signal(SIGTERM, on_signal);
    std::signal(SIGINT, on_signal);
    int status = 0;
    try {
      mq::Publisher p(*c, password);
      status = p.run(g_stop);
    } catch (const std::exception& e) {
      throw nccomp::tools::CommandError(nccomp::tools::kExitFailure, e.what());
    }
    if (status != 0) throw nccomp::tools::CommandError(status, "publisher stopped on an error");
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(publish, setup);
