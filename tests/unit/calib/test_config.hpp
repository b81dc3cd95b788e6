// The configuration the S3 tests share: a plausible reference geometry, a 5 mm test blank.
#pragma once

#include "core/calib/config.hpp"
#include "tests/unit/calib/sim_machine.hpp"

namespace nccomp::test::calib {

inline CalibrationConfig test_config() {
  CalibrationConfig c;
  c.register_x = 40;
  c.register_y = 41;
  c.register_z = 42;
  c.reference_x_lateral_mm = 250.0;
  c.reference_x_axial_mm = 262.5;
  c.reference_y_mm = 40.0;
  c.reference_z_mm = -310.0;
  c.reference_contact_mm = 3.0;
  c.reference_axial_contact_mm = 4.5;
  c.touches_per_axis = 3;
  c.blank_radius_mm = 5.0;
  c.facet_tolerance_um = 2.0;
  c.max_test_grinds = 30;
  return c;
}

inline MachineErrors test_errors() {
  MachineErrors e;
  e.ex_um = 23.0;
  e.exa_um = 31.0;
  e.ey_um = -12.0;
  e.ez_um = 8.0;
  e.pretravel_lateral_um = 4.0;
  e.pretravel_axial_um = 6.5;
  return e;
}

}  // namespace nccomp::test::calib
