// GIVEN the loop running an engine with an [[input_sums]] sum (sensor 60 = -12.5 + 0.8 · sensor 1
// − 1.2 · sensor 2) WHEN only sensor 1 has a sample THEN no sum is shown; WHEN sensor 2 has one
// too THEN `nccomp status` shows sensor_60_sum and the metrics have
// nccompd_input_sum_value{sensor="60"}; `promtool check metrics` passes on them.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
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

TEST(InputSumStatus, SumInStatusAndMetricsOnceEveryInputHasASample) {
  testing::TempDir d;
  auto loaded = config::load_file(d.write("nccompd.toml", R"([loopback]
[[registers]]
name = "T1_length_wear"
kind = "tool_length_wear"
bus = "loopback"
max_abs_um = 200
max_step_um = 5
max_rate_um_per_s = 100

[[input_sums]]
sensor = 60
offset = -12.5
inputs = [1, 2]
weights = [0.8, -1.2]
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
  ASSERT_TRUE(bus.inject(core::TemperatureSample{0, 1, 20.0}));
  // The sample has gone through the loop, and 50 cycles more: the sum still waits for sensor 2.
  ASSERT_TRUE(wait_for([&] { return loop.stats().events_in >= 1; }));
  const std::uint64_t after = loop.stats().cycles;
  ASSERT_TRUE(wait_for([&] { return loop.stats().cycles > after + 50; }));
  EXPECT_EQ(render_json(c).find("sensor_60_sum"), std::string::npos) << render_json(c);
  EXPECT_EQ(render_prometheus(c).find("nccompd_input_sum_value"), std::string::npos);
  ASSERT_TRUE(bus.inject(core::TemperatureSample{0, 2, 10.0}));
  // -12.5 + 16 - 12 = -8.5
  EXPECT_TRUE(wait_for([&] {
    return render_json(c).find("\"sensor_60_sum\":-8.5") != std::string::npos;
  })) << render_json(c);
  loop.stop();
  const std::string text = render_text(c);
  const std::string prom = render_prometheus(c);
  logger.stop();
  bus.stop();
  EXPECT_NE(text.find("module input_sums: sensor_60_sum -8.5\n"), std::string::npos) << text;
  EXPECT_NE(prom.find("\nnccompd_input_sum_value{sensor=\"60\"} -8.5\n"), std::string::npos)
      << prom;
  EXPECT_NE(prom.find("# TYPE nccompd_input_sum_value gauge\n"), std::string::npos) << prom;
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

TEST(InputSumStatus, MetricKeyIsParsedFromTheStatusKey) {
  EXPECT_EQ(input_sum_key("sensor_60_sum"), "60");
  for (const char* bad :
       {"sensor__sum", "sensor_60", "sensor_60_sumx", "sensor_60_lag", "x_sum", ""}) {
    EXPECT_EQ(input_sum_key(bad), "") << bad;
  }
}

}  // namespace
}  // namespace nccomp::daemon
