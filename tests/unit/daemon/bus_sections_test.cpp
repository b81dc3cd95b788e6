// GIVEN configs with [modbus] / [can] sections, WHEN the daemon's loader reads them, THEN the
// drivers' own parsers validate them, every error names file, line, column and key path (also in
// an included map file), every register on a bus must be mapped and every mapping must be a
// register of that bus, and the section builds its bus.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"
#include "drivers/can/can_bus.hpp"
#include "drivers/modbus/modbus_bus.hpp"

namespace nccomp::daemon::config {

using formats::Diagnostic;
using formats::format;
namespace {

namespace fs = std::filesystem;

class TempDir {
 public:
  TempDir() {
    path_ = fs::temp_directory_path() /
            ("nccomp_bus_cfg_" + std::to_string(::getpid()) + "_" + std::to_string(counter_++));
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  std::string write(const std::string& name, const std::string& text) const {
    std::ofstream(path_ / name) << text;
    return (path_ / name).string();
  }

 private:
  static inline int counter_ = 0;
  fs::path path_;
};

std::string registers(const std::string& bus, int n) {
  std::string s;
  for (int i = 0; i < n; ++i) {
    s += "[[registers]]\nname = \"" + bus + std::to_string(i) +
         "\"\nkind = \"tool_length_wear\"\n" + "bus = \"" + bus +
         "\"\nmax_abs_um = 100\nmax_step_um = 5\nmax_rate_um_per_s = 50\n";
  }
  return s;
}

// Line numbers below count from here: [modbus] is line 1.
const char* kModbus = R"([modbus]
transport = "tcp"
host = "127.0.0.1"
port = 1502
poll_rate_hz = 100
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.0001 }
[[modbus.offset]]
register_index = 0
address = 200
type = "int32"
scale = 0.1
[[modbus.offset]]
register_index = 1
address = 202
type = "int32"
scale = 0.1
)";

TEST(BusSections, ModbusSectionParsesAndBuildsItsBus) {
  TempDir d;
  const auto f = d.write("n.toml", std::string(kModbus) + registers("modbus", 2));
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const SectionParser* p = find_section_parser("modbus");
  ASSERT_NE(p, nullptr);
  ASSERT_TRUE(p->provides_bus());
  auto bus = p->make_bus(*r.config);
  auto* mb = dynamic_cast<drivers::modbus::ModbusBus*>(bus.get());
  ASSERT_NE(mb, nullptr);
  EXPECT_EQ(mb->config().port, 1502);
  ASSERT_EQ(mb->config().offsets.size(), 2U);
  EXPECT_EQ(mb->config().offsets[1].address, 202);
  EXPECT_DOUBLE_EQ(mb->config().offsets[1].encoding.scale, 0.1);
}

TEST(BusSections, WrongKeyInModbusNamesFileLineColumnAndKeyPath) {
  TempDir d;
  std::string text = kModbus;
  text.replace(text.find("poll_rate_hz"), 12, "poll_rate_Hz");
  const auto f = d.write("n.toml", text + registers("modbus", 2));
  auto r = load_file(f);
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  const Diagnostic& e = r.diagnostics.items()[0];
  EXPECT_EQ(e.where.file, f);
  EXPECT_EQ(e.where.line, 5);
  EXPECT_GT(e.where.column, 0);
  EXPECT_EQ(e.where.key_path, "modbus.poll_rate_Hz");
  EXPECT_EQ(e.message, "unknown key");
  EXPECT_EQ(format(e).rfind(f + ":5:", 0), 0U) << format(e);
}

TEST(BusSections, ErrorInAnIncludedMapNamesTheMapFile) {
  TempDir d;
  std::string map = kModbus;
  map.replace(map.find("address = 202"), 13, "address = 70000");
  const auto m = d.write("map.toml", map);
  const auto f = d.write("n.toml", "include = [\"map.toml\"]\n" + registers("modbus", 2));
  auto r = load_file(f);
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  const Diagnostic& e = r.diagnostics.items()[0];
  EXPECT_EQ(e.where.file, m);
  EXPECT_EQ(e.where.line, 15);
  EXPECT_EQ(e.where.key_path, "modbus.offset[1].address");
}

TEST(BusSections, RegisterWithoutMappingAndMappingWithoutRegisterAreErrors) {
  TempDir d;
  // GIVEN three registers on the bus but mappings for 0 and 1 only
  auto r = load_file(d.write("a.toml", std::string(kModbus) + registers("modbus", 3)));
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  EXPECT_EQ(r.diagnostics.items()[0].where.key_path, "registers[2].bus");
  EXPECT_NE(r.diagnostics.items()[0].message.find("no [[modbus.offset]] register_index = 2"),
            std::string::npos)
      << r.diagnostics.items()[0].message;
  // GIVEN one register but mappings for 0 and 1
  r = load_file(d.write("b.toml", std::string(kModbus) + registers("modbus", 1)));
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  EXPECT_EQ(r.diagnostics.items()[0].where.key_path, "modbus.offset[1].register_index");
  EXPECT_EQ(r.diagnostics.items()[0].where.line, 14);
  // GIVEN register 1 on another bus while the Modbus map maps it
  r = load_file(d.write("c.toml", std::string(kModbus) + "[loopback]\n" + registers("modbus", 1) +
                                      registers("loopback", 1)));
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  EXPECT_EQ(r.diagnostics.items()[0].where.key_path, "modbus.offset[1].register_index");
  EXPECT_NE(
      r.diagnostics.items()[0].message.find("is register 'loopback0', whose bus is 'loopback'"),
      std::string::npos)
      << r.diagnostics.to_string();
}

TEST(BusSections, ShippedModbusConfigPassesCheckConfig) {
  auto r = load_file(std::string(NCCOMP_SOURCE_DIR) + "/config/nccompd.toml");
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto bus = find_section_parser("modbus")->make_bus(*r.config);
  auto* mb = dynamic_cast<drivers::modbus::ModbusBus*>(bus.get());
  ASSERT_NE(mb, nullptr);
  // The register list and the reference map agree one to one.
  EXPECT_EQ(mb->config().offsets.size(), registers_section(*r.config).registers.size());
}

TEST(BusSections, CanSectionFromTheReferenceMap) {
  TempDir d;
  const auto f = d.write("n.toml", "include = [\"" + std::string(NCCOMP_SOURCE_DIR) +
                                       "/config/reference-nc-can.toml\"]\n" + registers("can", 4));
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto bus = find_section_parser("can")->make_bus(*r.config);
  ASSERT_NE(dynamic_cast<drivers::can::CanBus*>(bus.get()), nullptr);
  // A typo in [can] names the file, line and key path.
  const auto g = d.write("g.toml", R"([can]
interface = "vcan0"
ack_timeout = 0.05
)" + registers("can", 1));
  r = load_file(g);
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  EXPECT_EQ(r.diagnostics.items()[0].where.file, g);
  EXPECT_EQ(r.diagnostics.items()[0].where.line, 3);
  EXPECT_EQ(r.diagnostics.items()[0].where.key_path, "can.ack_timeout");
}

}  // namespace
}  // namespace nccomp::daemon::config
