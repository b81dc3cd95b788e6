// GIVEN the loop running an engine with an [[input_lags]] lag (sensor 40 = lag of sensor 5,
// tau 1800 s) WHEN sensor 5 reads 20 °C and then 30 °C THEN `nccomp status` shows the lag's value
// (sensor_40_lag, still near 20) and its input's (sensor_40_input, 30), and the metrics have both
// as nccompd_input_lag_value{sensor="40"} and nccompd_input_lag_input_value{sensor="40"};
// `promtool check metrics` passes on them.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/logging.hpp"
#include "daemon/loop.hpp"
#include "daemon/status.hpp"
#include "drivers/loopback/loopback_bus.hpp"
#include "tests/unit/daemon_modules/temp_dir.hpp"

namespace nccomp::daemon {
namespace {

using drivers::loopback::LoopbackBus;
using namespace std::chrono_literals;

double number_after(const std::string& s, const std::string& key) {
  const auto p = s.find(key);
  return p == std::string::npos ? std::nan("") : std::stod(s.substr(p + key.size()));
}

TEST(InputLagStatus, LagAndItsInputInStatusAndMetrics) {
  testing::TempDir d;
  auto loaded = config::load_file(d.write("nccompd.toml", R"([loopback]
[[registers]]
name = "T1_length_wear"
kind = "tool_length_wear"
bus = "loopback"
max_abs_um = 200
max_step_um = 5
max_rate_um_per_s = 100

[[input_lags]]
sensor = 40
input_sensor = 5
tau_s = 1800
)"));
  ASSERT_TRUE(loaded.config) << loaded.diagnostics.to_string();
  auto rt = std::make_unique<Runtime>();
  rt->engine = config::build_engine(*loaded.config);
  rt->register_bus = {0};
  core::rt::ConfigSwap<Runtime> swap(std::move(rt));
  LoopbackBus bus(256, 256);
  bus.start();
  Loop loop(LoopOptions{}, swap, {&bus}, nullptr, nullptr);
  EventLogger logger(loop);
  logger.start();
  loop.start();
  StatusContext c;
  c.loop = &loop;
  c.buses = {{"loopback", &bus}};
  c.logger = &logger;
  c.register_names = [] { return std::vector<std::string>{"T1_length_wear"}; };
  c.config_path = "nccompd.toml";
  c.state_path = "state.bin";
  const auto wait_for = [](const std::function<bool()>& done) {
    for (int i = 0; i < 500; ++i) {
      if (done()) return true;
      std::this_thread::sleep_for(10ms);
    }
    return false;
  };
  ASSERT_TRUE(bus.inject(core::TemperatureSample{0, 5, 20.0}));
  EXPECT_TRUE(wait_for([&] {
    return render_json(c).find("\"sensor_40_lag\":20") != std::string::npos;
  })) << render_json(c);
  ASSERT_TRUE(bus.inject(core::TemperatureSample{0, 5, 30.0}));
  EXPECT_TRUE(wait_for([&] {
    return render_json(c).find("\"sensor_40_input\":30") != std::string::npos;
  })) << render_json(c);
  // The loop stopped first: the lag keeps moving toward 30 at every cycle, and the three
  // renderings must show the same value.
  loop.stop();
  const std::string text = render_text(c);
  const std::string json = render_json(c);
  const std::string prom = render_prometheus(c);
  logger.stop();
  bus.stop();
  // The lag moved from 20 toward 30 by (1 - exp(-dt / 1800 s)) over the few ms since: barely.
  const double lag = number_after(json, "\"sensor_40_lag\":");
  EXPECT_GE(lag, 20.0) << json;
  EXPECT_LT(lag, 20.1) << json;
  EXPECT_NE(text.find("module input_lags: sensor_40_lag "), std::string::npos) << text;
  EXPECT_NE(text.find(", sensor_40_input 30\n"), std::string::npos) << text;
  // The JSON status prints 6 significant digits (20.0001), the metrics more (20.00005564).
  EXPECT_NEAR(number_after(prom, "\nnccompd_input_lag_value{sensor=\"40\"} "), lag, 1e-4) << prom;
  EXPECT_NE(prom.find("\nnccompd_input_lag_input_value{sensor=\"40\"} 30\n"), std::string::npos)
      << prom;
  EXPECT_NE(prom.find("# TYPE nccompd_input_lag_value gauge\n"), std::string::npos) << prom;
  EXPECT_NE(prom.find("# TYPE nccompd_input_lag_input_value gauge\n"), std::string::npos) << prom;
  if (::system("command -v promtool >/dev/null 2>&1") == 0) {
    const auto file = d.write("metrics.txt", prom);
    const std::string cmd = "promtool check metrics <" + file + " 2>&1";
    std::FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    std::string lint;
    char buf[512];
    std::size_t n = 0;
    while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) lint.append(buf, n);
    EXPECT_EQ(::pclose(p), 0) << lint;
    EXPECT_EQ(lint, "") << prom;
  }
}

// The keys the metrics take from the input_lags module, and the σ keys of
// nccompd_module_sigma_meters (S0's wear_sigma_um, S3's x_estimate_sigma_um).
TEST(InputLagStatus, MetricKeysAreParsedFromTheStatusKeys) {
  EXPECT_EQ(input_lag_key("sensor_40_lag"), (std::pair<std::string, std::string>{"40", "lag"}));
  EXPECT_EQ(input_lag_key("sensor_7_input"), (std::pair<std::string, std::string>{"7", "input"}));
  for (const char* bad : {"sensor__lag", "sensor_40", "sensor_40_lagx", "x_sensor_4_lag", ""}) {
    EXPECT_TRUE(input_lag_key(bad).first.empty()) << bad;
  }
  EXPECT_EQ(sigma_estimate_key("wear_sigma_um"), "wear_estimate_um");
  EXPECT_EQ(sigma_estimate_key("checkpoint_sigma_um"), "checkpoint_estimate_um");
  EXPECT_EQ(sigma_estimate_key("x_estimate_sigma_um"), "x_estimate_um");
  EXPECT_EQ(sigma_estimate_key("x_estimate_um"), "");
  EXPECT_EQ(sigma_estimate_key("_sigma_um"), "");
}

}  // namespace
}  // namespace nccomp::daemon
