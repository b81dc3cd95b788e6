// Fuzz target: saved states and log tails read back at start-up.
//   - A valid engine state (with the machine context's entry) is exported, the input's bytes
//     are XORed over it from an offset the input chooses, and a fresh engine imports it: a
//     state that does not parse is refused, one that does must step and export again.
//   - The input itself as the context's state (MachineContext::load) and as an engine state.
//   - The input as the tail of a measurement log (the writer reads the last row's time_s).
// Any bytes must end in a refusal or in an engine that steps, never in a crash.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string_view>
#include <vector>

#include "core/common/output.hpp"
#include "core/engine/context.hpp"
#include "core/engine/engine.hpp"
#include "daemon/measurement_log.hpp"

namespace {

namespace core = nccomp::core;
namespace ce = nccomp::core::engine;

std::unique_ptr<ce::Engine> make_engine() {
  auto e = std::make_unique<ce::Engine>();
  e->configure({}, {});
  return e;
}

void run(ce::Engine& e, std::int64_t t0) {
  core::StepOutput out;
  for (int k = 0; k < 20; ++k) {
    core::AxisSample a;
    a.position_mm[0] = 2.0 * k;
    a.tool = 3 + k / 10;
    const std::vector<core::Event> ev = {a, core::TemperatureSample{0, 0, 21.0}};
    e.step(t0 + k * 1'000'000'000LL, ev, out);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto* bytes = reinterpret_cast<const std::byte*>(data);
  // 1. Mutations of a valid state.
  static const std::vector<std::byte> valid = [] {
    auto e = make_engine();
    run(*e, 0);
    std::vector<std::byte> b(e->state_capacity());
    b.resize(e->export_state(b));
    return b;
  }();
  if (size > 0 && !valid.empty()) {
    std::vector<std::byte> s = valid;
    const std::size_t at = data[0] % s.size();
    for (std::size_t i = 1; i < size && at + i - 1 < s.size(); ++i) s[at + i - 1] ^= bytes[i];
    auto e = make_engine();
    const std::int64_t now = (data[0] & 1) != 0 ? 5'000'000'000LL : 50'000'000'000LL;
    if (e->import_state(s, now)) {
      run(*e, now);
      std::vector<std::byte> again(e->state_capacity());
      (void)e->export_state(again);
      (void)e->context().machine_time_s();
    }
  }
  // 2. The input as a context state and as an engine state.
  ce::MachineContext c;
  if (c.load(std::span<const std::byte>(bytes, size), 1'000'000'000LL)) {
    core::AxisSample a;
    const std::vector<core::Event> ev = {a};
    c.update(2'000'000'000LL, ev);
    core::MeasurementRecord r;
    c.annotate(r);
  }
  auto e = make_engine();
  if (e->import_state(std::span<const std::byte>(bytes, size), 0)) run(*e, 0);
  // 3. The input as the tail of a log file.
  const std::string_view tail(reinterpret_cast<const char*>(data), size);
  const double t = nccomp::formats::measurement_log::last_row_time_s(tail, size % 2 == 0);
  if (!(std::isinf(t) || std::isfinite(t))) __builtin_trap();
  return 0;
}
