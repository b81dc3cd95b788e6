// [modbus] in nccompd's config: parsed by the Modbus driver's own parser (one definition of
// the map for the daemon, ncsim and `modbus_map`), its errors turned into the loader's
// diagnostics (file:line:column: key path), cross-checked against [[registers]], and the bus
// built from it. Not real-time.
//
// Poll rate and loop rate: the loop takes at most one sample per cycle, so poll_rate_hz defaults
// to [daemon] rate_hz and a faster poll_rate_hz is refused. The loop rate is another section's,
// known only in cross_check(): parse() validates the map (with the lowest poll rate when the key
// is absent, so that an RTU bus budget is not judged on a rate the daemon will not use), and
// cross_check() parses it again with the loop rate and keeps that result.
//
// The I/O thread's real-time priority (io_sched_fifo_priority) is checked the same way against
// [daemon.realtime] sched_fifo_priority: it must be below the loop's, so that the loop always
// preempts the driver. What the thread got at start is logged from the bus's start() (a refusal
// as a warning), like the loop thread's set-up.
#include <spdlog/spdlog.h>

#include <memory>
#include <string>
#include <vector>

#include "daemon/config/config.hpp"
#include "daemon/sections/modbus/register_mapping.hpp"
#include "drivers/modbus/config.hpp"
#include "drivers/modbus/modbus_bus.hpp"

namespace nccomp::daemon::config {

using formats::Diagnostics;
using formats::Where;
using formats::where_of;
namespace {

namespace mb = drivers::modbus;

struct ModbusSection final : Section {
  /// Final after cross_check() (which runs on every config the loader returns).
  mutable mb::ModbusConfig config;
  /// The [modbus] table: valid while the loader runs (parse() and cross_check()) only.
  const toml::table* table{nullptr};
  std::string file;
  std::vector<MappedRegister> mapped;
};

class ModbusParser final : public SectionParser {
 public:
  std::string_view name() const noexcept override { return "modbus"; }

  std::unique_ptr<Section> parse(const toml::node& node, Diagnostics& diag) const override {
    const auto* t = node.as_table();
    if (t == nullptr) {
      diag.error(&node, "modbus", "must be a table ([modbus])");
      return nullptr;
    }
    const Where table_where = where_of(t, "modbus");
    auto s = std::make_unique<ModbusSection>();
    s->table = t;
    s->file = table_where.file;
    mb::ParseOptions provisional;
    provisional.default_poll_rate_hz = 0.01;  // the lowest allowed; cross_check() sets the real one
    auto parsed = mb::read_modbus_table(*t, table_where.file, provisional, diag);
    if (!parsed) {
      return nullptr;
    }
    s->config = std::move(*parsed);
    // Positions of the offset mappings, for the cross-check's messages (the driver's config
    // keeps indices only).
    if (const auto* arr = t->get_as<toml::array>("offset")) {
      for (std::size_t i = 0; i < arr->size(); ++i) {
        const auto* ot = arr->get(i)->as_table();
        const auto* idx = ot != nullptr ? ot->get("register_index") : nullptr;
        if (idx != nullptr && idx->is_integer()) {
          s->mapped.push_back(MappedRegister{
              static_cast<std::uint32_t>(*idx->value<std::int64_t>()),
              where_of(idx, "modbus.offset[" + std::to_string(i) + "].register_index")});
        }
      }
    }
    return s;
  }

  void cross_check(const Config& config, Diagnostics& diag) const override {
    const auto* s = config.find<ModbusSection>("modbus");
    if (s == nullptr) {
      return;
    }
    check_register_mapping(config, "modbus", "[[modbus.offset]] register_index", s->mapped, diag);
    const DaemonSection& daemon = daemon_section(config);
    const double loop_hz = daemon.rate_hz;
    mb::ParseOptions options;
    options.default_poll_rate_hz = loop_hz;
    options.max_poll_rate_hz = loop_hz;
    options.rate_source = "daemon.rate_hz";
    options.loop_sched_fifo_priority = daemon.sched_fifo_priority;
    options.loop_priority_source = "daemon.realtime.sched_fifo_priority";
    if (auto parsed = mb::read_modbus_table(*s->table, s->file, options, diag)) {
      s->config = std::move(*parsed);
    }
  }

  bool provides_bus() const noexcept override { return true; }

  std::unique_ptr<drivers::Bus> make_bus(const Config& config) const override {
    const auto* s = config.find<ModbusSection>("modbus");
    if (s == nullptr) {
      return nullptr;
    }
    auto bus = std::make_unique<mb::ModbusBus>(s->config);
    const mb::ModbusConfig& c = bus->config();
    bus->on_io_thread_setup([&c](const mb::IoThreadSetup& setup) {
      for (const mb::IoSetupLine& line : mb::describe_io_setup(setup, c)) {
        if (line.warning) {
          spdlog::warn("bus modbus: {}", line.text);
        } else {
          spdlog::info("bus modbus: {}", line.text);
        }
      }
    });
    return bus;
  }
};

}  // namespace

NCCOMP_REGISTER_CONFIG_SECTION(ModbusParser)

}  // namespace nccomp::daemon::config
