#include "daemon/sections/model/context_section.hpp"

#include <cmath>
#include <string>

#include "daemon/config/builtin_sections.hpp"

namespace nccomp::daemon::sections {

namespace {

class MeasurementContextParser final : public config::SectionParser {
 public:
  std::string_view name() const noexcept override { return "measurement_context"; }
  std::unique_ptr<config::Section> parse(const toml::node& node,
                                         formats::Diagnostics& diag) const override {
    auto s = std::make_unique<MeasurementContextSection>();
    s->where = formats::where_of(&node, "measurement_context");
    const auto* table = node.as_table();
    if (table == nullptr) {
      diag.error(&node, "measurement_context", "must be a table ([measurement_context])");
      return s;
    }
    formats::TableReader r(*table, "measurement_context", diag);
    s->options.temperature_sensor = static_cast<int>(r.integer("temperature_sensor", 0, -1, 255));
    s->options.warm_start_idle_s = r.number("warm_start_idle_s", 7200.0, 60.0, 7.0 * 86400.0);
    s->where = r.where("temperature_sensor");
    r.finish();
    return s;
  }
  void add_modules(const config::Config& config,
                   std::vector<std::unique_ptr<core::engine::Module>>& modules) const override {
    modules.push_back(
        std::make_unique<MeasurementContextModule>(measurement_context_options(config)));
  }
};

NCCOMP_REGISTER_CONFIG_SECTION(MeasurementContextParser)

}  // namespace

core::engine::ContextOptions measurement_context_options(const config::Config& config) {
  const auto* s = config.find<MeasurementContextSection>("measurement_context");
  return s != nullptr ? s->options : core::engine::ContextOptions{};
}

formats::Where measurement_context_where(const config::Config& config) {
  const auto* s = config.find<MeasurementContextSection>("measurement_context");
  return s != nullptr ? s->where : formats::Where{};
}

std::size_t MeasurementContextModule::status(
    std::span<core::engine::StatusValue> out) const noexcept {
  if (context_ == nullptr) return 0;
  std::size_t n = 0;
  auto put = [&](const char* key, double v) {
    if (n < out.size()) out[n++] = core::engine::StatusValue{key, v, nullptr};
  };
  const core::engine::MachineContext& c = *context_;
  put("machine_time_s", c.machine_time_s());
  put("idle_s", c.idle_s());
  put("warm_starts", static_cast<double>(c.warm_starts()));
  put("cold", c.cold() ? 1.0 : 0.0);
  put("tool", c.has_tool() ? static_cast<double>(c.tool()) : -1.0);
  put("cut_path_mm", c.cut_path_mm());
  if (std::isfinite(c.temp_c())) put("temp_c", c.temp_c());
  return n;
}

}  // namespace nccomp::daemon::sections
