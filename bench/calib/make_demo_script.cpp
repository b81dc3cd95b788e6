// Writes the example scripts of docs/calibration.md from the simulated machine of the tests
// (known errors: Ex = +23, Exa = +31, Ey = -12, Ez = +8 um; reference-probe pretravel 4 um
// lateral, 6.5 um axial; touch and chord noise 0.5 um), so that the documented run recovers
// numbers the reader can check.
//
//   calib_demo_script CONFIG_TOUCHES_PER_AXIS initial.calib recalibrate.calib
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>

#include "core/calib/calibrator.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace {

using nccomp::core::Event;
using nccomp::core::from_seconds;
using nccomp::core::StepOutput;
using nccomp::core::TimeNs;
using nccomp::core::calib::Calibrator;
using nccomp::core::calib::Face;
using nccomp::core::calib::Phase;
using nccomp::test::calib::SimMachine;

const char* kAxis[] = {"x", "x", "y", "z"};
const char* kVariant[] = {" lateral", " axial", "", ""};

void touch_line(std::ofstream& f, const char* probe, const nccomp::core::CalibrationTouch& t,
                std::size_t slot) {
  char buf[160];
  std::snprintf(buf, sizeof buf, "touch %s %s %s%s %.4f\n", probe, kAxis[slot],
                t.direction > 0 ? "+" : "-", kVariant[slot], t.trigger_position_mm);
  f << buf;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 4) {
    std::fprintf(stderr,
                 "usage: calib_demo_script TOUCHES_PER_AXIS initial.calib recalibrate.calib\n");
    return 2;
  }
  auto cfg = nccomp::test::calib::test_config();
  cfg.touches_per_axis = std::atoi(argv[1]);
  cfg.temperature_sensor = 0;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, nccomp::test::calib::test_errors(), 0.5, 0.5, 0.1, 2026);
  StepOutput out;
  TimeNs now = 0;
  std::ofstream f(argv[2]);
  f << "# Initial calibration, simulated machine (see docs/calibration.md).\n"
       "time 0\ntemperature 0 20.4\nbegin\n"
       "# reference probe in the holder, reference disk on the spindle\n";
  c.begin_calibration(now, out);
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < cfg.touches_per_axis; ++i) {
      const auto t = m.reference_touch(slot, 1, now);
      touch_line(f, "reference", t, slot);
      const Event e = t;
      c.step(now, {&e, 1}, out);
    }
  }
  double t_s = 0.0;
  for (const bool end : {false, true}) {
    f << (end ? "# test grind on the end face from +X and -X\n"
              : "# test grind of the blank from +X and -X (A turned 180 deg)\n");
    while (c.phase() == (end ? Phase::kTestGrindEndFace : Phase::kTestGrindLateral)) {
      t_s += 600.0;
      now = from_seconds(t_s);
      const auto [plus, minus] = m.test_grind(end, c.grind_correction_um());
      char buf[160];
      // A grind and its measurement take 10 min; the X register carries the grind's dx by then.
      std::snprintf(buf, sizeof buf, "wait 600\nfacets %s %.4f %.4f\n",
                    end ? "end-face" : "lateral", plus, minus);
      f << buf;
      c.enter_facets(end ? Face::kEndFace : Face::kLateral, plus, minus, now, out);
    }
  }
  t_s += 300.0;
  now = from_seconds(t_s);
  f << "# machine probe on the grinding head touches the test body: the nominals\n"
    << "wait 300\n";
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < cfg.touches_per_axis; ++i) {
      const auto t = m.machine_touch(slot, 1, now);
      touch_line(f, "machine", t, slot);
      const Event e = t;
      c.step(now, {&e, 1}, out);
    }
  }
  f << "wait 60\nstatus\n";
  f.close();

  // Recalibration, next session (time 0 = one hour later): the machine has warmed up.
  m.set_drift([](double t) {
    const double f1 = 1.0 - std::exp(-(t + 3600.0) / 5400.0);
    return std::array<double, 4>{30.0 * f1, 34.0 * f1, -12.0 * f1, 18.0 * f1};
  });
  std::ofstream g(argv[3]);
  g << "# Recalibration one hour later (run with the state file of the initial calibration).\n"
       "time 0\ntemperature 0 23.9\n# hourly touch cycle of the machine probe\n";
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < cfg.touches_per_axis; ++i) {
      touch_line(g, "machine", m.machine_touch(slot, 1, 0), slot);
    }
  }
  g << "wait 300\nstatus\nwait 300\n"
       "# a touch cycle with dirt on the sphere: Y reads 60 um off\n"
       "time 1800\ntemperature 0 24.6\n";
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < cfg.touches_per_axis; ++i) {
      auto t = m.machine_touch(slot, 1, from_seconds(1800.0));
      if (slot == 2) {
        t.trigger_position_mm += 0.060;
      }
      touch_line(g, "machine", t, slot);
    }
  }
  g << "# cleaned and repeated\n";
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < cfg.touches_per_axis; ++i) {
      touch_line(g, "machine", m.machine_touch(slot, 1, from_seconds(1800.0)), slot);
    }
  }
  g << "wait 1800\nstatus\n";
  return 0;
}
