// Fuzz target of the module's command path: the bytes are a sequence of 20-byte records, each an
// OperatorCommand (any kind, codes and values, NaN and infinities included), a CalibrationTouch
// or a time step. Whatever arrives, the module never crashes, its state stays valid
// (state_problem() == nullptr), every command is answered under its sequence number, and every
// register write is finite and within the limiter's absolute limit.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "core/calib/calib_module.hpp"
#include "core/calib/snapshot.hpp"
#include "core/calib/state.hpp"

namespace {

struct Sink final : nccomp::core::calib::SnapshotSink {
  void publish(const nccomp::core::calib::CalibSnapshot& s) noexcept override { last = s; }
  nccomp::core::calib::CalibSnapshot last{};
};

double value(const std::uint8_t* p) {
  // Mostly plausible magnitudes, sometimes the raw bits (NaN, inf, huge).
  std::int32_t i = 0;
  std::memcpy(&i, p, 4);
  if ((p[0] & 0x0F) == 0x0F) {
    float f = 0.0F;
    std::memcpy(&f, p, 4);
    return static_cast<double>(f);
  }
  return static_cast<double>(i % 400000) / 1000.0;  // ±400 mm in µm steps
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace cc = nccomp::core::calib;
  namespace core = nccomp::core;
  std::vector<core::engine::RegisterSpec> specs(4);
  for (std::size_t i = 0; i < 4; ++i) {
    // Not "r" + std::to_string(i): GCC 12 at -O3 reports a false -Wrestrict on it.
    specs[i].name = std::string{'r', static_cast<char>('0' + i)};
    specs[i].kind =
        i < 3 ? core::engine::RegisterKind::kAxisOffset : core::engine::RegisterKind::kFlag;
  }
  cc::CalibrationConfig cfg;
  cfg.register_x = 0;
  cfg.register_y = 1;
  cfg.register_z = 2;
  cfg.request_register = 3;
  cfg.touches_per_axis = 1;
  cfg.blank_radius_mm = 5.0;
  cfg.touch_positions =
      size > 0 && (data[0] & 1) ? cc::TouchPositions::kProgram : cc::TouchPositions::kMachine;
  cc::CalibrationModule m(cfg);
  m.attach(core::engine::RegisterTable(specs));
  Sink sink;
  m.set_snapshot_sink(&sink);
  core::StepOutput out;
  core::TimeNs now = 0;
  std::uint32_t seq = 0;
  for (std::size_t off = 1; off + 20 <= size; off += 20) {
    const std::uint8_t* r = data + off;
    core::Event e;
    bool command = false;
    bool ignored = false;  // an OperatorCommand that is not the calibrator's
    switch (r[0] % 3) {
      case 0: {
        core::OperatorCommand c;
        c.sequence = ++seq;
        c.kind = static_cast<core::OperatorCommandKind>(r[1] % 10);  // 9: unknown
        for (std::size_t k = 0; k < 4; ++k) c.code[k] = static_cast<std::int8_t>(r[2 + k]);
        c.value = {value(r + 6), value(r + 10)};
        // Chords in a plausible range half of the time.
        if (r[14] & 1) c.value = {1.9 + (r[15] - 128) * 1e-4, 1.9 + (r[16] - 128) * 1e-4};
        e = c;
        // kWarmStart is the engine's machine context's, kAcknowledge clears latched alarms and
        // the calibrator latches none: neither is answered here.
        command = c.kind != core::OperatorCommandKind::kWarmStart &&
                  c.kind != core::OperatorCommandKind::kAcknowledge;
        ignored = !command;
        break;
      }
      case 1: {
        core::CalibrationTouch t;
        t.probe = static_cast<core::ProbeKind>(r[1] % 3);
        t.axis = static_cast<std::uint8_t>(r[2] % 4);
        t.direction = static_cast<std::int8_t>(static_cast<std::int8_t>(r[3]) % 3);
        t.variant = static_cast<std::uint8_t>(r[4] % 3);
        t.trigger_position_mm = value(r + 6);
        e = t;
        break;
      }
      default:
        now += static_cast<core::TimeNs>(r[1]) * 1'000'000'000;
        continue;
    }
    now += 1'000'000;
    out.clear();
    m.step(now, {&e, 1}, out);
    if (cc::state_problem(m.calibrator().export_state()) != nullptr) std::abort();
    if (command && sink.last.last_command.sequence != seq) std::abort();
    if (ignored && sink.last.last_command.sequence == seq) std::abort();
    for (const auto& w : out.writes) {
      if (!std::isfinite(w.value_um) || std::fabs(w.value_um) > cfg.max_abs_um) std::abort();
    }
  }
  std::vector<std::byte> buf(m.state_capacity());
  const std::size_t n = m.save_state(buf);
  cc::CalibrationModule again(cfg);
  again.attach(core::engine::RegisterTable(specs));
  if (!again.load_state(std::span<const std::byte>(buf.data(), n))) std::abort();
  return 0;
}
