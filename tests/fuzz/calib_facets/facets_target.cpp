// Fuzz target of the facet export parser. Every input is parsed or refused with
// std::invalid_argument naming the source and line; parsed rows are valid (face, finite chords in
// (0, 1000] mm) and a calibrator in its lateral test grind takes them without leaving a valid
// state.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <string_view>

#include "core/calib/calibrator.hpp"
#include "core/calib/state.hpp"
#include "formats/calib/facet_import.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace cal = nccomp::formats::calib;
  namespace cc = nccomp::core::calib;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  std::vector<cal::FacetMeasurement> rows;
  try {
    rows = cal::parse_facet_export(text, "device.csv");
  } catch (const std::invalid_argument& e) {
    if (std::string_view(e.what()).rfind("device.csv:", 0) != 0) std::abort();
    return 0;
  }
  if (rows.empty()) std::abort();
  cc::CalibrationConfig cfg;
  cfg.max_test_grinds = 50;
  cc::Calibrator c;
  c.configure(cfg);
  nccomp::core::StepOutput out;
  c.begin_calibration(0, out);
  // Reference touches at their nominal triggers: Δx = 0 on every slot.
  for (std::uint8_t slot = 0; slot < 4; ++slot) {
    nccomp::core::CalibrationTouch t;
    t.probe = nccomp::core::ProbeKind::kReferenceProbe;
    t.axis = slot <= 1 ? 0 : static_cast<std::uint8_t>(slot - 1);
    t.variant = slot == 1 ? 1 : 0;
    t.trigger_position_mm = 0.0;
    const nccomp::core::Event e = t;
    c.step(0, {&e, 1}, out);
  }
  nccomp::core::TimeNs now = 0;
  for (const auto& r : rows) {
    if (!(std::isfinite(r.chord_plus_mm) && r.chord_plus_mm > 0.0 && r.chord_plus_mm <= 1000.0 &&
          std::isfinite(r.chord_minus_mm) && r.chord_minus_mm > 0.0 && r.chord_minus_mm <= 1000.0 &&
          r.line >= 2)) {
      std::abort();
    }
    out.clear();
    now += 1'000'000'000;
    (void)c.enter_facets(r.face, r.chord_plus_mm, r.chord_minus_mm, now, out);
    c.step(now, {}, out);
    if (cc::state_problem(c.export_state()) != nullptr) std::abort();
  }
  return 0;
}
