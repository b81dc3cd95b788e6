// ncsim's config: the shipped config parses, --set switches effects the daemon is not told about,
// and every refusal names file:line:column and the key.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "drivers/can/can_config.hpp"
#include "drivers/modbus/config.hpp"
#include "sim/ncsim/bus_map.hpp"
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
  } catch (const formats::DiagnosticsError& e) {
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
            "t.toml:4:17: effects.wear.rate_um_per_m: must be a number in [0, 10000], got -1");
  EXPECT_EQ(error_of(header() + "[effects.wear]\nrate = 1\n"),
            "t.toml:4:8: effects.wear.rate: unknown key");
  EXPECT_EQ(error_of(header() + "[effects.thermal]\nmode = \"cubic\"\n"),
            "t.toml:4:8: effects.thermal.mode: must be one of \"first_order\", \"replay\", got "
            "\"cubic\"");
  EXPECT_NE(error_of("[ncsim]\n").find("ncsim.bus_map: missing required key"), std::string::npos);
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

// GIVEN a config with several mistakes in different tables and one in a --set, WHEN it is
// parsed, THEN each is reported (file:line:column or --set, key path), not only the first.
TEST(NcsimConfig, EveryErrorOfAConfigIsReportedNotOnlyTheFirst) {
  EXPECT_EQ(error_of(header() + "[effects.wear]\nrate_um_per_m = -1\nrate = 1\n[nc]\ntool = 0\n",
                     {"thermal.enabled=maybe"}),
            "t.toml:7:8: nc.tool: must be an integer in [1, 9999], got 0\n"
            "t.toml:4:17: effects.wear.rate_um_per_m: must be a number in [0, 10000], got -1\n"
            "t.toml:5:8: effects.wear.rate: unknown key\n"
            "--set: effects.thermal.enabled: must be true or false");
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
  } catch (const formats::DiagnosticsError& e) {
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
  } catch (const formats::DiagnosticsError& e) {
    EXPECT_EQ(std::string(e.what()), path + ":1: no column \"w_mm\" in the header");
  }
}

// The demo NC's map is the reference map plus extra files (ncsim.bus_map_extra), merged as the
// daemon merges its includes: the offsets are appended, an entry's error names its own file, a
// key defined in two files is refused naming both.
TEST(NcsimConfig, BusMapExtraFilesAreAppended) {
  const SimConfig c =
      load_sim_config(std::string(NCCOMP_SOURCE_DIR) + "/config/demo/ncsim-demo.toml");
  ASSERT_EQ(c.bus_map_extra_texts.size(), 1U);
  EXPECT_NE(c.bus_map_extra_files[0].find("config/demo/nc-flags-modbus.toml"), std::string::npos);
  EXPECT_EQ(c.nc.measure_request_register, 10);
  ASSERT_EQ(c.nc.alarm_registers.size(), 1U);
  EXPECT_EQ(c.nc.alarm_registers[0], 9);
  const toml::table root =
      merged_bus_map(c.bus_map_text, c.bus_map_file, c.bus_map_extra_texts, c.bus_map_extra_files);
  const auto map = drivers::modbus::parse_modbus_table(*root["modbus"].as_table(), c.bus_map_file);
  ASSERT_EQ(map.offsets.size(), 11U);
  EXPECT_EQ(map.offsets[9].register_index, 9);
  EXPECT_EQ(map.offsets[9].address, 240);
  EXPECT_EQ(map.offsets[10].register_index, 10);
  EXPECT_EQ(map.offsets[10].address, 242);
  // The CAN profile: 4 registers of the reference map + 6 of nc-extra-can.toml.
  const toml::table can_root = merged_bus_map(c.can_bus_map_text, c.can_bus_map_file,
                                              c.can_bus_map_extra_texts, c.can_bus_map_extra_files);
  const auto can = drivers::can::parse_can_table(*can_root["can"].as_table(), c.can_bus_map_file);
  ASSERT_EQ(can.mapping.offsets.size(), 10U);
  EXPECT_EQ(can.mapping.offsets[9].register_index, 9);

  const std::string bad_type =
      "[[modbus.offset]]\nregister_index = 9\naddress = 240\ntype = \"int12\"\n";
  try {
    const toml::table r = merged_bus_map(c.bus_map_text, c.bus_map_file, {bad_type}, {"x.toml"});
    (void)drivers::modbus::parse_modbus_table(*r["modbus"].as_table(), c.bus_map_file);
    FAIL() << "accepted type int12";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("x.toml:4"), std::string::npos) << e.what();
  }
  try {
    (void)merged_bus_map(c.bus_map_text, c.bus_map_file, {"\n[modbus]\nport = 1\n"}, {"y.toml"});
    FAIL() << "accepted modbus.port twice";
  } catch (const formats::DiagnosticsError& e) {
    const std::string w = e.what();
    EXPECT_EQ(w.rfind("y.toml:3:8: modbus.port: already defined at ", 0), 0U) << w;
    EXPECT_NE(w.find("reference-nc-modbus.toml:"), std::string::npos) << w;
  }
  EXPECT_NE(error_of(header() + "bus_map_extra = \"one.toml\"\n")
                .find("ncsim.bus_map_extra: must be an array of strings"),
            std::string::npos);
}

// A continued run starts with the offsets the NC held at the end of the run it continues (a real
// NC keeps its registers): not 0, and not as writes of the new run.
TEST(NcsimConfig, ContinueKeepsTheOffsetRegistersOfTheNc) {
  const std::vector<std::uint16_t> known{0, 1, 2, 3, 4, 5, 6, 7, 8};
  const SimConfig c = load_sim_config(kConfig, {}, ProgramKind::kSideWall);
  Simulation first(c, ProgramKind::kSideWall, known);
  (void)first.write_offset(0.0, 0, -20.0);
  (void)first.write_offset(1.0, 0, -26.25);
  (void)first.write_offset(1.0, 6, 3.5);
  first.advance_to(core::from_seconds(1000.0));
  ASSERT_TRUE(first.done());
  const std::string dir = ::testing::TempDir() + "/ncsim_continue_registers";
  write_result(dir, first, RunInfo{ProgramKind::kSideWall, BusKind::kModbus, 0});
  const SimConfig next =
      load_sim_config(kConfig, continuation_overrides(dir), ProgramKind::kSideWall);
  Simulation second(next, ProgramKind::kSideWall, known);
  EXPECT_DOUBLE_EQ(second.reg(0), -26.25);
  EXPECT_DOUBLE_EQ(second.reg(6), 3.5);
  EXPECT_DOUBLE_EQ(second.reg(1), 0.0);
  EXPECT_TRUE(second.registers().log().empty());
  // A run continued from one that wrote nothing still has them.
  second.advance_to(core::from_seconds(1000.0));
  const std::string dir2 = dir + "_2";
  write_result(dir2, second, RunInfo{ProgramKind::kSideWall, BusKind::kModbus, 0});
  const SimConfig third =
      load_sim_config(kConfig, continuation_overrides(dir2), ProgramKind::kSideWall);
  EXPECT_DOUBLE_EQ(Simulation(third, ProgramKind::kSideWall, known).reg(0), -26.25);
  EXPECT_NE(error_of(header() + "initial_register_indices = [0, 6]\ninitial_registers_um = [1.0]\n")
                .find("ncsim.initial_registers_um: has 1 values for the 2 registers"),
            std::string::npos);
}

// `ncsim --continue DIR`: the end state a run writes is what the next run starts from.
TEST(NcsimConfig, ContinueReadsTheEndStateOfARun) {
  SimConfig c =
      load_sim_config(kConfig, {"ncsim.parts=2", "wear.rate_um_per_m=20"}, ProgramKind::kSideWall);
  const std::vector<std::uint16_t> known{0, 1, 2, 3, 4, 5, 6, 7, 8};
  Simulation sim(c, ProgramKind::kSideWall, known);
  sim.advance_to(core::from_seconds(1000.0));
  ASSERT_TRUE(sim.done());
  const std::string dir = ::testing::TempDir() + "/ncsim_continue";
  write_result(dir, sim, RunInfo{ProgramKind::kSideWall, BusKind::kModbus, 0});
  const auto sets = continuation_overrides(dir);
  ASSERT_EQ(sets.size(), 4U);
  EXPECT_EQ(sets[0], "ncsim.first_part=3");
  EXPECT_EQ(sets[1].rfind("ncsim.tool_cut_path_mm=", 0), 0U);
  EXPECT_EQ(sets[2], "ncsim.initial_register_indices=[]");  // no daemon wrote to this NC
  EXPECT_EQ(sets[3], "ncsim.initial_registers_um=[]");
  const SimConfig next = load_sim_config(kConfig, sets, ProgramKind::kSideWall);
  EXPECT_EQ(next.first_part, 3);
  EXPECT_NEAR(next.tool_cut_path_mm, sim.end_state().tool_cut_path_mm, 1e-6);
  EXPECT_GT(next.tool_cut_path_mm, 0.0);
  std::ifstream j(dir + "/result.json");
  std::stringstream js;
  js << j.rdbuf();
  EXPECT_NE(js.str().find("\"first_part\":1,\"end\":{\"next_part\":3,"), std::string::npos)
      << js.str();
  EXPECT_NE(js.str().find("\"alarms_seen\":0,\"alarms\":[]"), std::string::npos);
  std::ifstream mcsv(dir + "/measurements.csv");
  std::string line;
  std::getline(mcsv, line);
  EXPECT_EQ(line, "t_s,kind,part,checkpoint,cut_path_mm,true_um,reading_um,broken");
  int rows = 0;
  while (std::getline(mcsv, line)) {
    EXPECT_NE(line.find(",probe,"), std::string::npos) << line;
    ++rows;
  }
  EXPECT_EQ(rows, 8);  // 4 checkpoints × 2 parts
  {
    std::ofstream f(dir + "/end_state.toml");
    f << "[ncsim]\nfirst_part = 3\nwear_um = 4.0\n";
  }
  try {
    (void)continuation_overrides(dir);
    FAIL() << "accepted an unknown key";
  } catch (const formats::DiagnosticsError& e) {
    EXPECT_NE(std::string(e.what()).find("end_state.toml:3:11: ncsim.wear_um: unknown key"),
              std::string::npos)
        << e.what();
  }
  try {
    (void)continuation_overrides(dir + "/nowhere");
    FAIL() << "accepted a missing directory";
  } catch (const formats::DiagnosticsError& e) {
    EXPECT_NE(std::string(e.what()).find("--continue needs the end_state.toml"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace nccomp::sim::ncsim
