// Start-up of the S0 modules (docs/creep.md, "`[creep.interval]`"): a measurement request that was
// up when nccompd stopped must not stick. If the NC still holds its request register at 1 (or the
// bus cannot read it back), the NC may already have reacted to that rising edge and its answer
// may be lost: the module lowers the register for request_rearm_s and raises it again
// (WearCompensator::rearm_request()). A measurement the bus delivers meanwhile (one published
// while nccompd was down, docs/daemon.md) answers the request as usual and ends it.
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include "core/creep/creep_module.hpp"
#include "daemon/daemon.hpp"

namespace nccomp::daemon::sections {
namespace {

std::vector<std::string> rearm_requests(core::engine::Engine& engine, const RegisterReader& read) {
  std::vector<std::string> lines;
  for (std::size_t i = 0; i < engine.module_count(); ++i) {
    auto* m = dynamic_cast<core::creep::CreepModule*>(&engine.module(i));
    if (m == nullptr) {
      continue;
    }
    const auto& comp = m->compensator();
    const std::int32_t reg = comp.config().output.measurement_due_register;
    if (reg < 0 || !comp.state().measurement_due_flag) {
      continue;
    }
    const auto nc = read(static_cast<std::uint16_t>(reg));
    std::ostringstream line;
    line << m->name() << ": the measurement request was up when nccompd stopped";
    if (nc && std::fabs(*nc) < 0.5) {
      line << "; the NC's request register reads 0, so writing 1 is a rising edge";
    } else {
      m->rearm_request();
      if (!comp.rearming()) {
        line << (nc ? " and the NC still holds it" : " (the NC's register cannot be read back)")
             << "; request_rearm_s = 0: it stays up";
      } else {
        line << (nc ? " and the NC still holds it" : " (the NC's register cannot be read back)")
             << ": it is lowered for " << comp.config().output.request_rearm_s
             << " s and raised again, so that the NC sees a rising edge";
      }
    }
    lines.push_back(line.str());
  }
  return lines;
}

[[maybe_unused]] const int kRegistered = register_startup_hook(
    "creep", [](core::engine::Engine& engine, const RegisterReader& read, core::TimeNs /*now*/) {
      return rearm_requests(engine, read);
    });

}  // namespace
}  // namespace nccomp::daemon::sections
