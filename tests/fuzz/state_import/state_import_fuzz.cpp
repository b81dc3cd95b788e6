// Fuzz target: arbitrary bytes as the state file of an engine with every module nccompd ships.
// The engine is built by the daemon's own loader and cfg::build_engine() from nccompd-full.toml
// (config/nccompd.toml's registers, [creep] and [calibration], plus [checkpoints] and a fitted
// [model] that trims two checkpoint registers), and holds a valid state of a run (wear measured,
// parts probed, temperatures) before each import. Each input is imported twice: as it is, and
// XORed over that valid state from an offset its first two bytes choose. For any bytes:
//   - refused: the engine is unchanged (the same exported state, the same register states);
//   - accepted: every register's output is finite and within its max_abs_um;
//   - then 16 cycles with axis motion, a part, probe and laser measurements, temperatures, a
//     calibration touch set and an acknowledge: every write is finite, within max_abs_um and,
//     for offsets, within max_step_um and max_rate_um_per_s · Δt of the register's previous
//     value; the state exports again.
// A violation aborts (a finding); sanitizers catch the rest.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "core/common/output.hpp"
#include "core/common/types.hpp"
#include "core/engine/engine.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"

namespace {

namespace cfg = nccomp::daemon::config;
namespace core = nccomp::core;
namespace ce = nccomp::core::engine;

constexpr core::TimeNs kSecond = 1'000'000'000;

[[noreturn]] void fail(const char* what, int line) {
  std::fprintf(stderr, "fuzz_state_import: violated at line %d: %s\n", line, what);
  std::abort();
}
#define CHECK(cond) ((cond) ? void() : fail(#cond, __LINE__))

const cfg::Config& config() {
  static const auto loaded = [] {
    auto r = cfg::load_file(NCCOMP_FUZZ_CONFIG);
    CHECK(r.config != nullptr);
    return std::move(r.config);
  }();
  return *loaded;
}

/// One cycle's events: the tool cuts along X; now and then a part starts or ends, the laser
/// measures, the probe touches a checkpoint, the calibration probe touches, the operator
/// acknowledges.
std::vector<core::Event> events(int k, core::TimeNs now) {
  std::vector<core::Event> ev;
  core::AxisSample a;
  a.time_ns = now;
  a.position_mm = {10.0 * k, 5.0, -10.0, 0.0, 0.0, 0.0};
  a.program_path_mm = 10.0 * k;
  a.tool = 1;
  a.has_normal = true;
  a.normal = {0.0, 0.6, 0.8};
  ev.emplace_back(a);
  ev.emplace_back(core::TemperatureSample{now, 0, 21.0 + 0.1 * k});
  switch (k % 8) {
    case 1:
      ev.emplace_back(core::ProgramEvent{now, core::ProgramEventKind::kPartStart, 7 + k / 8});
      break;
    case 2: {
      core::ToolMeasurement m;
      m.time_ns = now;
      m.tool = 1;
      m.point_count = 7;
      for (std::size_t i = 0; i < 7; ++i)
        m.wear_um[i] = 2.0 + 0.5 * k + 0.1 * static_cast<double>(i);
      ev.emplace_back(m);
      break;
    }
    case 3:
    case 4: {
      core::ProbeMeasurement p;
      p.time_ns = now;
      p.part = 7 + k / 8;
      p.checkpoint = k % 4;
      p.raw_deviation_um = 3.0 - k;
      p.wall_angle_deg = 2.0;
      p.ball_radius_mm = 2.0;
      ev.emplace_back(p);
      break;
    }
    case 5:
      for (std::uint8_t axis = 0; axis < 3; ++axis) {
        for (int d = 0; d < 2; ++d) {
          core::CalibrationTouch t;
          t.time_ns = now;
          t.axis = axis;
          t.direction = static_cast<std::int8_t>(d == 0 ? 1 : -1);
          t.trigger_position_mm = axis == 2 ? -313.0 : 247.0 + 0.001 * k;
          ev.emplace_back(t);
        }
      }
      break;
    case 6:
      ev.emplace_back(core::ProgramEvent{now, core::ProgramEventKind::kPartEnd, 7 + k / 8});
      break;
    case 7: {
      core::OperatorCommand c;
      c.time_ns = now;
      c.sequence = static_cast<std::uint32_t>(k);
      c.kind = core::OperatorCommandKind::kAcknowledge;
      ev.emplace_back(c);
      break;
    }
    default:
      break;
  }
  return ev;
}

struct Watch {
  double output_um;
  core::TimeNs since_ns;
};

/// Steps e for `cycles` cycles from t0 and checks every write against the register's limits.
void run(ce::Engine& e, core::TimeNs t0, int cycles) {
  std::vector<Watch> last;
  for (std::size_t i = 0; i < e.register_count(); ++i) {
    last.push_back({e.register_state(i).output_um, t0});
  }
  core::StepOutput out;
  for (int k = 1; k <= cycles; ++k) {
    const core::TimeNs now = t0 + k * kSecond / 10;
    const auto ev = events(k, now);
    e.step(now, ev, out);
    for (const auto& w : out.writes) {
      CHECK(w.register_index < e.register_count());
      const auto& spec = e.register_spec(w.register_index);
      const auto& lim = spec.limits;
      Watch& prev = last[w.register_index];
      CHECK(std::isfinite(w.value_um));
      CHECK(std::fabs(w.value_um) <= lim.max_abs_um);
      if (spec.kind != ce::RegisterKind::kFlag) {
        const double change = std::fabs(w.value_um - prev.output_um);
        const double dt_s = core::seconds(now - prev.since_ns);
        const double slack = 1e-9 * std::max(1.0, std::fabs(w.value_um));
        CHECK(change <= lim.max_step_um + slack);
        CHECK(change <= lim.max_rate_um_per_s * dt_s + slack);
      }
      prev = {w.value_um, now};
    }
  }
}

std::vector<std::byte> export_of(const ce::Engine& e) {
  std::vector<std::byte> b(e.state_capacity());
  b.resize(e.export_state(b));
  CHECK(!b.empty());
  return b;
}

/// The state of a run: the engine stepped through 40 cycles of events from a fresh start.
/// NCCOMP_FUZZ_WRITE_STATE=FILE writes it to FILE (how corpus/valid_state was made).
const std::vector<std::byte>& valid_state() {
  static const std::vector<std::byte> state = [] {
    auto e = cfg::build_engine(config());
    run(*e, 0, 40);
    auto b = export_of(*e);
    if (const char* path = std::getenv("NCCOMP_FUZZ_WRITE_STATE")) {
      std::ofstream(path, std::ios::binary)
          .write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
    }
    return b;
  }();
  return state;
}

void import_and_step(std::span<const std::byte> bytes) {
  auto e = cfg::build_engine(config());
  const core::TimeNs t0 = 100 * kSecond;
  CHECK(e->import_state(valid_state(), t0));
  const auto before = export_of(*e);
  std::vector<ce::RegisterState> regs_before;
  for (std::size_t i = 0; i < e->register_count(); ++i) regs_before.push_back(e->register_state(i));

  const core::TimeNs t1 = t0 + kSecond;
  if (!e->import_state(bytes, t1)) {
    CHECK(export_of(*e) == before);
    for (std::size_t i = 0; i < e->register_count(); ++i) {
      const auto r = e->register_state(i);
      const auto& b = regs_before[i];
      CHECK(std::memcmp(&r.output_um, &b.output_um, sizeof(double)) == 0 &&
            std::memcmp(&r.target_um, &b.target_um, sizeof(double)) == 0 &&
            r.has_target == b.has_target);
    }
    return;
  }
  for (std::size_t i = 0; i < e->register_count(); ++i) {
    const double out_um = e->register_state(i).output_um;
    CHECK(std::isfinite(out_um) && std::fabs(out_um) <= e->register_spec(i).limits.max_abs_um);
  }
  run(*e, t1, 16);
  (void)export_of(*e);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto* bytes = reinterpret_cast<const std::byte*>(data);
  import_and_step({bytes, size});
  const auto& valid = valid_state();
  if (size >= 2) {
    std::vector<std::byte> s = valid;
    const std::size_t at =
        (static_cast<std::size_t>(data[0]) | static_cast<std::size_t>(data[1]) << 8U) % s.size();
    for (std::size_t i = 2; i < size && at + i - 2 < s.size(); ++i) s[at + i - 2] ^= bytes[i];
    import_and_step(s);
  }
  return 0;
}
