// Fuzz target of the engine's start-up read-back and the warm-start and acknowledge commands: the
// bytes are 12-byte records, each an anchor or adopt of a register with a value read back from
// the NC (plausible, or raw float bits: NaN, infinities, huge), a module target, an
// OperatorCommand kWarmStart or kAcknowledge with any sequence and codes, or a cycle (optional
// axis motion, a time step).
// Whatever arrives: nothing crashes; every value written is finite, never more than max_step_um
// from what the NC held before (the anchored value or the previous write) and never beyond
// max_abs_um, whatever the NC held; a register anchored beyond max_abs_um gets no write at all
// (held until a release, which this target never sends); a valid warm-start command is counted and
// restarts the machine time, a valid acknowledgement is counted (its sequence published) and leaves
// the machine time alone, an invalid command is counted as an invalid event and changes nothing.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <vector>

#include "core/engine/engine.hpp"

namespace {

namespace ce = nccomp::core::engine;
namespace core = nccomp::core;

constexpr std::size_t kRegs = 3;
constexpr double kMaxAbs = 200.0;
constexpr double kMaxStep = 5.0;

double value(const std::uint8_t* p) {
  if ((p[0] & 0x0F) == 0x0F) {
    float f = 0.0F;
    std::memcpy(&f, p, 4);
    return static_cast<double>(f);
  }
  std::int32_t i = 0;
  std::memcpy(&i, p, 4);
  return static_cast<double>(i % 300000) / 1000.0;  // ±300 µm: inside and beyond max_abs
}

class Targets final : public ce::Module {
 public:
  std::string_view name() const noexcept override { return "targets"; }
  void attach(const ce::RegisterTable&) override {}
  void step(core::TimeNs now_ns, std::span<const core::Event>,
            core::StepOutput& out) noexcept override {
    for (std::size_t i = 0; i < kRegs; ++i) {
      if (set[i]) out.writes.push(core::OffsetWrite{now_ns, static_cast<std::uint16_t>(i), v[i]});
    }
  }
  std::vector<std::uint16_t> written_registers() const override { return {0, 1, 2}; }
  bool set[kRegs]{};
  double v[kRegs]{};
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::vector<ce::RegisterSpec> specs;
  for (std::size_t i = 0; i < kRegs; ++i) {
    // Not "r" + std::to_string(i): GCC 12 at -O3 reports a false -Wrestrict on it.
    std::string name = std::to_string(i);
    name.insert(name.begin(), 'r');
    specs.push_back(
        {name, ce::RegisterKind::kToolRadiusWear, core::LimiterConfig{kMaxAbs, kMaxStep, 100.0}});
  }
  auto targets = std::make_unique<Targets>();
  Targets* t = targets.get();
  std::vector<std::unique_ptr<ce::Module>> mods;
  mods.push_back(std::move(targets));
  ce::Engine e;
  e.configure(std::move(specs), std::move(mods));

  // What the NC holds per register (NaN = unknown: nothing anchored or written yet).
  double nc[kRegs] = {std::nan(""), std::nan(""), std::nan("")};
  bool beyond[kRegs] = {false, false, false};
  core::TimeNs now = 1'000'000'000;
  double x_mm = 0.0;
  std::uint64_t valid_commands = 0;
  std::uint64_t acknowledgements = 0;
  std::uint64_t invalid_events = 0;
  core::StepOutput out;
  for (std::size_t off = 0; off + 12 <= size; off += 12) {
    const std::uint8_t* r = data + off;
    const std::size_t reg = r[1] % (kRegs + 1);  // kRegs: an unknown register
    switch (r[0] % 5) {
      case 0:
      case 1: {
        const double v = value(r + 2);
        const auto a =
            r[0] % 5 == 0 ? e.anchor_register(reg, v, now) : e.adopt_register(reg, v, now);
        const bool ok = reg < kRegs && std::isfinite(v);
        if (a.anchored != ok) std::abort();
        if (a.adopted && (!ok || std::fabs(v) > kMaxAbs)) std::abort();
        if (ok) nc[reg] = v;
        if (ok) beyond[reg] = std::fabs(v) > kMaxAbs;
        continue;
      }
      case 2:
        if (reg < kRegs) {
          t->set[reg] = true;
          t->v[reg] = value(r + 2);
        }
        continue;
      case 3: {
        core::OperatorCommand c;
        const bool ack = (r[11] & 1) != 0;
        c.kind =
            ack ? core::OperatorCommandKind::kAcknowledge : core::OperatorCommandKind::kWarmStart;
        c.sequence = r[2] % 4;  // 0 is invalid
        for (std::size_t k = 0; k < 4; ++k) c.code[k] = static_cast<std::int8_t>(r[3 + k] % 3);
        c.value = {value(r + 7), 0.0};
        const bool codes_zero = c.code[1] == 0 && c.code[2] == 0 && c.code[3] == 0;
        const bool valid =
            c.sequence > 0 && codes_zero && (c.code[0] == 0 || (!ack && c.code[0] == 1));
        const core::Event ev = c;
        const auto time_before = e.context().machine_time_s(now);
        const bool cold_before = e.context().cold();
        now += 1'000'000;
        e.step(now, {&ev, 1}, out);
        if (ack) {
          acknowledgements += valid ? 1 : 0;
          // Taken by every module in this cycle: the sender's sequence is published at once.
          if (valid && e.counters().last_acknowledge_sequence != c.sequence) std::abort();
          // Not the machine context's: the warm-start state does not move.
          if (e.context().cold() != cold_before) std::abort();
          if (!cold_before && e.context().machine_time_s(now) < time_before) std::abort();
        } else {
          valid_commands += valid ? 1 : 0;
          if (valid && c.code[0] == 0 && e.context().machine_time_s(now) > 0.0) std::abort();
          if (valid && c.code[0] == 1 && !e.context().cold()) std::abort();
        }
        invalid_events += valid ? 0 : 1;
        break;
      }
      default: {
        now += static_cast<core::TimeNs>(r[2]) * 1'000'000;
        core::AxisSample a;
        a.axis_count = 3;
        if (r[3] & 1) x_mm += 0.5;
        a.position_mm[0] = x_mm;
        const core::Event ev = a;
        e.step(now, {&ev, 1}, out);
        break;
      }
    }
    for (const auto& w : out.writes) {
      const std::size_t i = w.register_index;
      if (i >= kRegs || !std::isfinite(w.value_um) || beyond[i]) std::abort();
      if (std::fabs(w.value_um) > kMaxAbs) std::abort();
      if (!std::isnan(nc[i]) && std::fabs(w.value_um - nc[i]) > kMaxStep + 1e-9) std::abort();
      nc[i] = w.value_um;
    }
    const auto& k = e.counters();
    if (k.warm_start_commands != valid_commands || k.events_invalid != invalid_events ||
        k.acknowledge_commands != acknowledgements) {
      std::abort();
    }
    if (!(e.context().machine_time_s() >= 0.0) || !std::isfinite(e.context().machine_time_s())) {
      std::abort();
    }
  }
  // The state keeps what the NC holds.
  std::vector<std::byte> buf(e.state_capacity());
  const std::size_t n = e.export_state(buf);
  if (n == 0) std::abort();
  return 0;
}
