#include "daemon/sections/calibration/calibration_section.hpp"

#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "core/calib/calib_module.hpp"
#include "core/common/config_issue.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/sections/calibration/daemon_link.hpp"
#include "formats/calib/config_toml.hpp"

namespace nccomp::daemon::sections {

std::unique_ptr<CalibrationSection> parse_calibration_section(const toml::node& node,
                                                              formats::Diagnostics& diag) {
  auto s = std::make_unique<CalibrationSection>();
  s->where = formats::where_of(&node, "calibration");
  if (node.as_table() == nullptr) {
    diag.error(&node, "calibration", "must be a table ([calibration])");
    return s;
  }
  formats::record_positions(node, "calibration", s->key_positions);
  s->config = formats::calib::parse_calibration(node, diag);
  return s;
}

const CalibrationSection* calibration_section(const config::Config& config) {
  return config.find<CalibrationSection>("calibration");
}

namespace {

class CalibrationParser final : public config::SectionParser {
 public:
  std::string_view name() const noexcept override { return "calibration"; }
  std::unique_ptr<config::Section> parse(const toml::node& node,
                                         formats::Diagnostics& diag) const override {
    return parse_calibration_section(node, diag);
  }
  void cross_check(const config::Config& config, formats::Diagnostics& diag) const override {
    const auto* s = calibration_section(config);
    if (s == nullptr) return;
    std::vector<core::engine::RegisterSpec> specs;
    for (const auto& e : config::registers_section(config).registers) {
      specs.push_back(e.spec);
    }
    try {
      auto m = std::make_unique<core::calib::CalibrationModule>(s->config);
      m->attach(core::engine::RegisterTable(specs));
    } catch (const core::ConfigInvalid& e) {
      formats::report(s->key_positions, s->where, e, diag);
    } catch (const std::invalid_argument& e) {
      diag.error(s->where, e.what());  // not a key's fault
    }
  }
  void add_modules(const config::Config& config,
                   std::vector<std::unique_ptr<core::engine::Module>>& modules) const override {
    if (const auto* s = calibration_section(config)) {
      auto c = s->config;
      if (!c.state_file.empty()) {
        c.state_file = config.resolve(c.state_file);
      }
      auto m = std::make_unique<core::calib::CalibrationModule>(std::move(c));
      // Before the engine restores the state: its wall-clock times map onto this clock.
      m->set_clock_offset_s(calibration_clock_offset_s());
      m->set_snapshot_sink(&calibration_snapshot_sink());
      modules.push_back(std::move(m));
    }
  }
};

NCCOMP_REGISTER_CONFIG_SECTION(CalibrationParser)

}  // namespace

}  // namespace nccomp::daemon::sections
