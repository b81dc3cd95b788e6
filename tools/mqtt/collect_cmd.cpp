// `nccomp collect --broker URI --out DIR [--site SITE] …`: writes one v2 measurement log per
// machine from what the publishers send (docs/mqtt.md). Runs until SIGTERM or SIGINT.
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <memory>
#include <string>

#include "formats/measurement_log/measurement_log.hpp"
#include "tools/mqtt/collector.hpp"
#include "tools/mqtt/mqtt_config.hpp"
#include "tools/mqtt/mqtt_link.hpp"
#include "tools/nccomp/command.hpp"

namespace {

std::atomic<bool> g_stop{false};

extern "C" void on_collect_signal(int) { g_stop.store(true); }

struct Options {
  nccomp::tools::mqtt::BrokerOptions broker;
  std::string out;
  std::string site;
};

std::int64_t mono_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

void run(const Options& o, const std::string& password) {
  namespace mq = nccomp::tools::mqtt;
  mq::CollectorStore store(o.out);
  // A persistent session: the broker keeps the rows for this client id while it is away.
  mq::MqttLink link(o.broker, password);
  const std::string filter =
      "nccomp/" + (o.site.empty() ? std::string("+") : o.site) + "/+/measurements";
  std::atomic<std::int64_t> last_refusal_log{0};
  link.subscribe_on_connect(filter, [&](const std::string& topic, const std::string& payload) {
    std::string error;
    try {
      if (store.add(topic, payload, error) == mq::CollectorStore::Result::kRefused) {
        const std::int64_t now = mono_ns();
        if (now - last_refusal_log.load() > 10'000'000'000) {
          last_refusal_log.store(now);
          spdlog::warn("refused a message: {} (counted; further refusals within 10 s only counted)",
                       error);
        }
      }
    } catch (const std::exception& e) {
      // Not written (disk full, …): not acknowledged, the broker delivers it again.
      spdlog::error("{}", e.what());
      return false;
    }
    return true;
  });
  spdlog::info("nccomp collect: {} from {} as {} into {}", filter, o.broker.uri, o.broker.client_id,
               o.out);
  double backoff_s = 1.0;
  std::int64_t next_connect = mono_ns();
  std::int64_t next_sync = mono_ns();
  std::int64_t next_report = mono_ns() + 60'000'000'000;
  mq::CollectorStore::Stats reported{};
  while (!g_stop.load()) {
    for (const auto& e : link.wait(50)) {
      using T = mq::LinkEvent::Type;
      if (e.type == T::kConnected) {
        spdlog::info("connected to {}", o.broker.uri);
        backoff_s = 1.0;
      } else if (e.type == T::kSubscribed) {
        spdlog::info("subscribed to {}", e.text);
      } else if (e.type == T::kRefused) {
        spdlog::error("{}", e.text);
      } else if (e.type == T::kConnectFailed) {
        spdlog::warn("cannot connect to {}: {}; next try in {} s", o.broker.uri, e.text,
                     static_cast<int>(backoff_s));
        next_connect = mono_ns() + static_cast<std::int64_t>(backoff_s * 1e9);
        backoff_s = std::min(backoff_s * 2.0, o.broker.reconnect_max_s);
      } else if (e.type == T::kConnectionLost) {
        spdlog::warn("connection to {} lost ({})", o.broker.uri, e.text);
        next_connect = mono_ns() + 1'000'000'000;
      }
    }
    const std::int64_t now = mono_ns();
    if (!link.connected() && now >= next_connect) {
      next_connect = now + 15'000'000'000;
      link.connect();
    }
    if (now >= next_sync) {
      next_sync = now + 1'000'000'000;
      store.sync();
    }
    if (now >= next_report) {
      next_report = now + 60'000'000'000;
      const auto s = store.stats();
      if (s.written != reported.written || s.refused != reported.refused) {
        spdlog::info(
            "{} row(s) written, {} duplicate(s) dropped, {} refused, {} sequence "
            "number(s) missing",
            s.written, s.duplicates, s.refused, s.missing);
      }
      reported = s;
    }
  }
  link.disconnect();
  store.sync();
  const auto s = store.stats();
  spdlog::info(
      "stopping: {} row(s) written, {} duplicate(s) dropped, {} refused, {} sequence "
      "number(s) missing",
      s.written, s.duplicates, s.refused, s.missing);
}

void setup(CLI::App& app) {
  auto* sub = app.add_subcommand(
      "collect", "Write one measurement log per machine from the MQTT publishers' rows");
  auto o = std::make_shared<Options>();
  sub->add_option("--broker", o->broker.uri, "Broker, tcp://host:port or ssl://host:port")
      ->required();
  sub->add_option("--out", o->out, "Directory of the logs: OUT/<site>/<machine>.csv")->required();
  sub->add_option("--site", o->site, "Only this site (default: every site)");
  sub->add_option("--client-id", o->broker.client_id,
                  "MQTT client id, fixed for the persistent session (default nccomp-collect-HOST)");
  sub->add_option("--username", o->broker.username, "User name at the broker");
  sub->add_option("--password-file", o->broker.password_file,
                  "File with the password (mode 0600 or 0640)");
  sub->add_option("--ca-file", o->broker.ca_file, "TLS: CA certificate(s) of the broker");
  sub->add_option("--cert-file", o->broker.cert_file, "TLS: client certificate");
  sub->add_option("--key-file", o->broker.key_file, "TLS: client key");
  sub->add_option("--session-expiry-s", o->broker.session_expiry_s,
                  "How long the broker keeps rows for this collector while it is away [s]")
      ->check(CLI::Range(std::int64_t{60}, std::int64_t{0xFFFFFFFE}));
  sub->callback([o] {
    namespace mq = nccomp::tools::mqtt;
    if (o->broker.client_id.empty()) {
      o->broker.client_id = "nccomp-collect-" + nccomp::formats::measurement_log::host_machine_id();
    }
    if (!o->site.empty() && !nccomp::formats::measurement_log::valid_machine_id(o->site)) {
      throw nccomp::tools::CommandError(nccomp::tools::kExitUsage,
                                        "--site '" + o->site + "' is not a topic level");
    }
    if (const std::string e = mq::check_broker(o->broker); !e.empty()) {
      throw nccomp::tools::CommandError(nccomp::tools::kExitUsage, e);
    }
    std::string password;
    try {
      if (!o->broker.password_file.empty()) {
        password = mq::read_password_file(o->broker.password_file);
      }
    } catch (const std::exception& e) {
      throw nccomp::tools::CommandError(nccomp::tools::kExitInvalidInput, e.what());
    }
    std::signal(SIGTERM, on_collect_signal);
    std::signal(SIGINT, on_collect_signal);
    try {
      run(*o, password);
    } catch (const std::exception& e) {
      throw nccomp::tools::CommandError(nccomp::tools::kExitFailure, e.what());
    }
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(collect, setup);
