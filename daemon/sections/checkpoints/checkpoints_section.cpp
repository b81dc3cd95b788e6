#include "daemon/sections/checkpoints/checkpoints_section.hpp"

#include <filesystem>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "core/checkpoint/plan.hpp"
#include "core/common/config_issue.hpp"
#include "daemon/config/builtin_sections.hpp"

namespace nccomp::daemon::sections {

namespace {

namespace fs = std::filesystem;
namespace ck = formats::checkpoints;

}  // namespace

std::unique_ptr<CheckpointsSection> parse_checkpoints_section(const toml::node& node,
                                                              formats::Diagnostics& diag) {
  auto s = std::make_unique<CheckpointsSection>();
  s->where = formats::where_of(&node, "checkpoints");
  const auto* table = node.as_table();
  if (table == nullptr) {
    diag.error(&node, "checkpoints", "must be a table ([checkpoints])");
    return s;
  }
  formats::record_positions(node, "checkpoints", s->key_positions);
  const auto& src = node.source();
  const std::string file = src.path ? *src.path : std::string();
  const fs::path base_dir = fs::path(file).parent_path();
  const std::size_t errors_before = diag.items().size();
  s->config = ck::parse_checkpoints(*table, file, base_dir, diag);
  if (diag.items().size() == errors_before) {
    try {
      s->checkpoint_count = core::checkpoint::make_plan(s->config.plan).checkpoints.size();
    } catch (const core::ConfigInvalid& e) {
      formats::report(s->key_positions, s->where, e, diag);
    } catch (const std::exception& e) {
      diag.error(s->where, e.what());
    }
  }
  return s;
}

const CheckpointsSection* checkpoints_section(const config::Config& config) {
  return config.find<CheckpointsSection>("checkpoints");
}

namespace {

class CheckpointsParser final : public config::SectionParser {
 public:
  std::string_view name() const noexcept override { return "checkpoints"; }
  std::unique_ptr<config::Section> parse(const toml::node& node,
                                         formats::Diagnostics& diag) const override {
    return parse_checkpoints_section(node, diag);
  }
  void cross_check(const config::Config& config, formats::Diagnostics& diag) const override {
    const auto* s = checkpoints_section(config);
    if (s == nullptr) return;
    std::vector<core::engine::RegisterSpec> specs;
    for (const auto& e : config::registers_section(config).registers) {
      specs.push_back(e.spec);
    }
    try {
      auto m = ck::make_checkpoint_module(s->config);
      m->attach(core::engine::RegisterTable(specs));
    } catch (const core::ConfigInvalid& e) {
      formats::report(s->key_positions, s->where, e, diag);
    } catch (const std::exception& e) {
      diag.error(s->where, e.what());  // not a key's fault
    }
  }
  void add_modules(const config::Config& config,
                   std::vector<std::unique_ptr<core::engine::Module>>& modules) const override {
    if (const auto* s = checkpoints_section(config)) {
      modules.push_back(ck::make_checkpoint_module(s->config));
    }
  }
};

NCCOMP_REGISTER_CONFIG_SECTION(CheckpointsParser)

}  // namespace

}  // namespace nccomp::daemon::sections
