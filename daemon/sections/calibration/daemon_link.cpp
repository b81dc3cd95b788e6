#include "daemon/sections/calibration/daemon_link.hpp"

#include <fmt/format.h>
#include <time.h>

#include <atomic>
#include <cmath>
#include <fstream>
#include <sstream>

#include "core/calib/state.hpp"
#include "core/rt/seqlock.hpp"
#include "formats/calib/render.hpp"

namespace nccomp::daemon::sections {

namespace cal = core::calib;
namespace tc = formats::calib;

namespace {

double clock_s(clockid_t id) {
  timespec ts{};
  clock_gettime(id, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

struct Clock {
  std::atomic<bool> set{false};
  std::atomic<double> offset_s{0.0};
};
Clock& clock_origin() {
  static Clock c;
  return c;
}

class SeqlockSink final : public cal::SnapshotSink {
 public:
  void publish(const cal::CalibSnapshot& s) noexcept override { lock_.store(s); }
  [[nodiscard]] cal::CalibSnapshot load() const noexcept { return lock_.load(); }

 private:
  core::rt::Seqlock<cal::CalibSnapshot> lock_;
};

SeqlockSink& sink() {
  static SeqlockSink s;
  return s;
}

// The newer of two states: the later calibration, then the later touch set.
bool newer(const cal::CalibState& a, const cal::CalibState& b) {
  const auto key = [](const cal::CalibState& s) {
    return std::pair{std::isfinite(s.result.time_s) ? s.result.time_s : -1e300,
                     std::isfinite(s.last_set_time_s) ? s.last_set_time_s : -1e300};
  };
  return key(a) > key(b);
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw std::invalid_argument("cannot be read");
  }
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

double calibration_clock_offset_s() {
  auto& c = clock_origin();
  if (c.set.load()) {
    return c.offset_s.load();
  }
  return clock_s(CLOCK_REALTIME) - clock_s(CLOCK_MONOTONIC);
}

cal::SnapshotSink& calibration_snapshot_sink() { return sink(); }

cal::CalibSnapshot latest_calibration_snapshot() { return sink().load(); }

std::vector<std::string> calibration_startup(core::engine::Engine& engine,
                                             const RegisterReader& read, core::TimeNs now_ns,
                                             double wall_now_s) {
  std::vector<std::string> lines;
  // The loop's clock at start-up is now_ns: monotonic, or 0 in lock-step (the peer's clock).
  const double offset = wall_now_s - core::seconds(now_ns);
  clock_origin().offset_s.store(offset);
  clock_origin().set.store(true);
  for (std::size_t m = 0; m < engine.module_count(); ++m) {
    auto* mod = dynamic_cast<cal::CalibrationModule*>(&engine.module(m));
    if (mod == nullptr) continue;
    const std::string name(mod->name());
    mod->rebase_clock(offset);
    auto& c = mod->calibrator();
    const auto held = c.export_state();
    if (held.phase != cal::Phase::kUncalibrated) {
      lines.push_back(fmt::format(
          "{}: resumed phase {}, calibrated {}, last touch set {}, {} recalibrations in the "
          "history",
          name, cal::to_string(held.phase), tc::format_utc(held.result.time_s),
          tc::format_utc(held.last_set_time_s), held.history_count));
    }
    const std::string& file = c.config().state_file;
    if (!file.empty()) {
      try {
        const cal::CalibState offline = cal::from_text(read_text(file));
        cal::validate(offline);
        if (held.phase == cal::Phase::kUncalibrated || newer(offline, held)) {
          c.import_state(offline);
          mod->mark_changed();
          lines.push_back(fmt::format(
              "{}: adopted the calibration of {} (phase {}, calibrated {}, last touch set {})",
              name, file, cal::to_string(offline.phase), tc::format_utc(offline.result.time_s),
              tc::format_utc(offline.last_set_time_s)));
        } else {
          lines.push_back(fmt::format(
              "{}: {} is not newer than the calibration the daemon holds; kept the daemon's", name,
              file));
        }
      } catch (const std::exception& e) {
        lines.push_back(fmt::format("{}: state_file {} refused: {}; the daemon's own state is kept",
                                    name, file, e.what()));
      }
    }
    // What the NC holds: program-coordinate touches are corrected by it, and the limiter slews
    // from it (never from 0).
    const std::array<std::uint16_t, 3> reg{c.config().register_x, c.config().register_y,
                                           c.config().register_z};
    std::string back;
    for (std::size_t a = 0; a < 3; ++a) {
      const auto v = read ? read(reg[a]) : std::optional<double>{};
      if (v && std::isfinite(*v)) {
        c.sync_register(a, *v, now_ns);
        back += fmt::format(" {} {:+.3f}", tc::axis_name(static_cast<std::int32_t>(a)), *v);
      }
    }
    lines.push_back(back.empty()
                        ? name +
                              ": axis registers cannot be read back; the limiter continues "
                              "from the values saved in the state"
                        : name + ": axis registers read back from the NC:" + back + " um");
  }
  return lines;
}

namespace {
[[maybe_unused]] const int kHook = register_startup_hook(
    "calibration",
    [](core::engine::Engine& engine, const RegisterReader& read, core::TimeNs now_ns) {
      return calibration_startup(engine, read, now_ns, clock_s(CLOCK_REALTIME));
    });
}  // namespace

}  // namespace nccomp::daemon::sections
