// GIVEN the loop running the engine built from config/nccompd.toml (on the loopback bus), WHEN
// a tool is measured, THEN `nccomp status` (text, JSON, Prometheus) shows each module's own
// status: creep's mode and wear, calibration's phase. The loop thread publishes, the status
// renderer reads: a seqlock between two threads (TSAN).
#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <sstream>
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

std::string shipped_config_on_loopback() {
  std::ifstream in(std::string(NCCOMP_SOURCE_DIR) + "/config/nccompd.toml");
  std::ostringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const auto inc = text.find("include = [");
  if (inc != std::string::npos) text.erase(inc, text.find('\n', inc) - inc);
  for (auto p = text.find("bus = \"modbus\""); p != std::string::npos;
       p = text.find("bus = \"modbus\"", p)) {
    text.replace(p, 14, "bus = \"loopback\"");
  }
  return text + "\n[loopback]\n";
}

bool wait_for(const std::function<bool()>& done) {
  for (int i = 0; i < 500; ++i) {
    if (done()) return true;
    std::this_thread::sleep_for(10ms);
  }
  return false;
}

TEST(ModuleStatus, StatusShowsEachModulesOwnValues) {
  testing::TempDir d;
  auto loaded = config::load_file(d.write("nccompd.toml", shipped_config_on_loopback()));
  ASSERT_TRUE(loaded.config) << loaded.diagnostics.to_string();
  auto rt = std::make_unique<Runtime>();
  rt->engine = config::build_engine(*loaded.config);
  std::vector<std::string> names;
  for (const auto& e : config::registers_section(*loaded.config).registers) {
    rt->register_bus.push_back(0);
    names.push_back(e.spec.name);
  }
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
  c.register_names = [names] { return names; };
  c.config_path = "nccompd.toml";
  c.state_path = "state.bin";

  ASSERT_TRUE(bus.inject(core::ToolChange{0, 1, false}));
  core::AxisSample a;
  a.tool = 1;
  a.program_path_mm = 0.0;
  ASSERT_TRUE(bus.inject(a));
  core::ToolMeasurement m;
  m.tool = 1;
  m.wear_um[0] = 12.0;
  ASSERT_TRUE(bus.inject(m));
  EXPECT_TRUE(wait_for([&] {
    return render_json(c).find("\"wear_measured_um\":12,") != std::string::npos;
  })) << render_json(c);
  const std::string json = render_json(c);
  EXPECT_NE(json.find("{\"name\":\"creep\",\"status\":{\"mode\":\"creeping\",\"tool\":1,"),
            std::string::npos)
      << json;
  // Nothing fed in yet (no path cut since the measurement): all 12 µm still to creep.
  EXPECT_NE(json.find("\"wear_in_force_um\":0,\"wear_measured_um\":12,\"creep_remaining_um\":12,"
                      "\"creeps_in_progress\":1,"),
            std::string::npos)
      << json;
  EXPECT_NE(json.find("{\"name\":\"calibration\",\"status\":{\"phase\":\"uncalibrated\","),
            std::string::npos)
      << json;
  const std::string text = render_text(c);
  EXPECT_NE(text.find("module creep: mode creeping, tool 1, wear_in_force_um 0, wear_measured_um "
                      "12, creep_remaining_um 12,"),
            std::string::npos)
      << text;
  const std::string prom = render_prometheus(c);
  EXPECT_NE(prom.find("nccompd_module_value{module=\"creep\",key=\"wear_measured_um\"} 12\n"),
            std::string::npos)
      << prom;
  loop.stop();
  logger.stop();
  bus.stop();
}

}  // namespace
}  // namespace nccomp::daemon
