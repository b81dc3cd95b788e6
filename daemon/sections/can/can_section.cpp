// [can] in nccompd's config: read by the CAN driver's own reader (one definition of the signal
// map for the daemon, ncsim and the HIL tests), which reports every error of the map into the
// loader's diagnostics (file:line:column: key path), cross-checked against [[registers]], and the
// bus built from it.
// Not real-time.
#include <memory>
#include <string>
#include <vector>

#include "daemon/config/config.hpp"
#include "daemon/sections/modbus/register_mapping.hpp"
#include "drivers/can/can_bus.hpp"
#include "drivers/can/can_config.hpp"

namespace nccomp::daemon::config {

using formats::Diagnostics;
using formats::Where;
using formats::where_of;
namespace {

namespace cn = drivers::can;

struct CanSection final : Section {
  cn::CanConfig config;
  std::vector<MappedRegister> mapped;
};

class CanParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "can"; }

  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    const auto* t = node.as_table();
    if (t == nullptr) {
      diag.error(&node, "can", "must be a table ([can])");
      return nullptr;
    }
    const Where table_where = where_of(t, "can");
    auto s = std::make_unique<CanSection>();
    auto parsed = cn::read_can_table(*t, table_where.file, diag);
    if (!parsed) {
      return nullptr;
    }
    s->config = std::move(*parsed);
    // Positions of the offset mappings, for the cross-check's messages.
    if (const auto* arr = t->get_as<toml::array>("offset")) {
      for (std::size_t i = 0; i < arr->size(); ++i) {
        const auto* ot = arr->get(i)->as_table();
        const auto* idx = ot != nullptr ? ot->get("register") : nullptr;
        if (idx != nullptr && idx->is_integer()) {
          s->mapped.push_back(
              MappedRegister{static_cast<std::uint32_t>(*idx->value<std::int64_t>()),
                             where_of(idx, "can.offset[" + std::to_string(i) + "].register")});
        }
      }
    }
    return s;
  }

  void cross_check(const Config& config, Diagnostics& diag) const override {
    if (const auto* s = config.find<CanSection>("can")) {
      check_register_mapping(config, "can", "[[can.offset]] register", s->mapped, diag);
    }
  }

  bool provides_bus() const noexcept override { return true; }

  std::unique_ptr<drivers::Bus> make_bus(const Config& config) const override {
    const auto* s = config.find<CanSection>("can");
    if (s == nullptr) {
      return nullptr;
    }
    return std::make_unique<cn::CanBus>(s->config);
  }
};

}  // namespace

NCCOMP_REGISTER_CONFIG_SECTION(CanParser)

}  // namespace nccomp::daemon::config
