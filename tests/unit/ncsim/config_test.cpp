// ncsim's config: the shipped config parses, --set switches effects the daemon is not told about,
// and every refusal names file:line:column and the key.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "sim/ncsim/config.hpp"
#include "sim/ncsim/result.hpp"

namespace nccomp::sim::ncsim {
namespace {

const std::string kConfig = std::string(NCCOMP_SOURCE_DIR) + "/config/ncsim.toml";

std::string header() {
  return std::string("[ncsim]\nbus_map = \"") + NCCOMP_SOURCE_DIR +
         "/config/reference-nc-modbus.toml\"\n";
}

std::string error_of(const std::string& text, const std::vector<std::string>& sets = {}) {
  try {
    (void)parse_sim_config(text, "t.toml", ".", sets);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(NcsimConfig, ShippedConfigParsesWithItsSideWallPlan) {
  const SimConfig c = load_sim_config(kConfig);
  EXPECT_EQ(c.lockstep_rate_hz, 1000.0);
  EXPECT_TRUE(c.effects.wear.enabled);
  EXPECT_EQ(c.effects.wear.rate_um_per_m, 8.0);
  EXPECT_EQ(c.nc.axis_register[2], 8);
  EXPECT_EQ(c.side_wall.plan.contour.size(), 2U);
  EXPECT_NE(c.bus_map_text.find("[modbus]"), std::string::npos);
}

TEST(NcsimConfig, SetSwitchesAnEffectAndTopLevelKeys) {
  const SimConfig c =
      load_sim_config(kConfig, {"thermal.enabled=false", "wear.rate_um_per_m=2.5", "ncsim.seed=42",
                                "broken_tool.enabled=true", "program.mould_face.stepover_mm=0.5"});
  EXPECT_FALSE(c.effects.thermal.enabled);
  EXPECT_EQ(c.effects.wear.rate_um_per_m, 2.5);
  EXPECT_EQ(c.seed, 42U);
  EXPECT_TRUE(c.effects.broken_tool.enabled);
  EXPECT_EQ(c.mould_face.stepover_mm, 0.5);
  // result.json shows what was in force.
  EXPECT_NE(effects_json(c.effects).find("\"thermal\":{\"enabled\":false"), std::string::npos);
  EXPECT_NE(effects_json(c.effects).find("\"broken_tool\":{\"enabled\":true"), std::string::npos);
}

TEST(NcsimConfig, RefusalsNameFileLineAndKey) {
  EXPECT_EQ(error_of(header() + "[effects.wear]\nrate_um_per_m = -1\n"),
            "t.toml:4:17: effects.wear.rate_um_per_m: must be in 0 .. 10000, got -1");
  EXPECT_EQ(error_of(header() + "[effects.wear]\nrate = 1\n"),
            "t.toml:4:8: effects.wear.rate: unknown key");
  EXPECT_EQ(error_of(header() + "[effects.thermal]\nmode = \"cubic\"\n"),
            "t.toml:4:8: effects.thermal.mode: must be one of \"first_order\", \"replay\", got "
            "\"cubic\"");
  EXPECT_NE(error_of("[ncsim]\n").find("ncsim.bus_map: required"), std::string::npos);
  EXPECT_NE(error_of(header() + "[nc\n").find("t.toml:3:"), std::string::npos);
  EXPECT_NE(error_of(header(), {"nosuch.key=1"}).find("nosuch: unknown key"), std::string::npos);
  EXPECT_EQ(error_of(header() + "[effects.wear]\nenabled = true\n", {"wear.rate=1"}),
            "--set: effects.wear.rate: unknown key");
  EXPECT_EQ(error_of(header(), {"wear.enabled=maybe"}),
            "--set: effects.wear.enabled: must be true or false");
  EXPECT_NE(error_of(header(), {"novalue"}).find("expected KEY=VALUE"), std::string::npos);
  EXPECT_NE(error_of(header() + "[effects.wear]\ncurve = \"phm2010\"\n").find("needs phm_file"),
            std::string::npos);
}

TEST(NcsimConfig, CsvReaderNamesLineAndColumn) {
  const std::string path = ::testing::TempDir() + "/ncsim_bad.csv";
  {
    std::ofstream f(path);
    f << "z_mm,u_mm\n0,0\n1,abc\n";
  }
  try {
    (void)read_csv_columns(path, {"z_mm", "u_mm"});
    FAIL() << "accepted a bad number";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), path + ":3: column \"u_mm\": not a finite number: \"abc\"");
  }
  // '#' comments and blank lines are skipped, before the header as well.
  const std::string ok = ::testing::TempDir() + "/ncsim_ok.csv";
  {
    std::ofstream f(ok);
    f << "# trajectory\n\nz_mm,u_mm\r\n0,0.5\r\n# mid\n1,-2e-3\n";
  }
  const auto cols = read_csv_columns(ok, {"u_mm", "z_mm"});
  ASSERT_EQ(cols[0].size(), 2U);
  EXPECT_EQ(cols[0][0], 0.5);
  EXPECT_EQ(cols[0][1], -2e-3);
  EXPECT_EQ(cols[1][1], 1.0);
  try {
    (void)read_csv_columns(path, {"z_mm", "w_mm"});
    FAIL() << "accepted a missing column";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), path + ":1: no column \"w_mm\" in the header");
  }
}

}  // namespace
}  // namespace nccomp::sim::ncsim
