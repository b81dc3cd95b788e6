// The engine adapter: register checks at attach(), state through save_state()/load_state().
#include "core/calib/calib_module.hpp"

#include <gtest/gtest.h>

#include <stdexcept>
#include <vector>

#include "tests/support/alloc_counter.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

using core::engine::RegisterKind;
using core::engine::RegisterSpec;
using core::engine::RegisterTable;

std::vector<RegisterSpec> register_specs() {
  std::vector<RegisterSpec> specs(3);
  const char* names[] = {"X_offset", "Y_offset", "Z_offset"};
  for (std::size_t i = 0; i < 3; ++i) {
    specs[i].name = names[i];
    specs[i].kind = RegisterKind::kAxisOffset;
  }
  return specs;
}

CalibrationConfig module_config() {
  auto cfg = test_config();
  cfg.register_x = 0;
  cfg.register_y = 1;
  cfg.register_z = 2;
  cfg.touches_per_axis = 1;
  return cfg;
}

TEST(CalibrationModule, AttachChecksTheRegisters) {
  auto specs = register_specs();
  specs[1].kind = RegisterKind::kToolLengthWear;
  core::calib::CalibrationModule m(module_config());
  EXPECT_THROW(m.attach(RegisterTable(specs)), std::invalid_argument);
  auto cfg = module_config();
  cfg.register_z = 7;
  core::calib::CalibrationModule n(cfg);
  const auto good = register_specs();
  EXPECT_THROW(n.attach(RegisterTable(good)), std::invalid_argument);
  core::calib::CalibrationModule ok(module_config());
  EXPECT_NO_THROW(ok.attach(RegisterTable(good)));
}

TEST(CalibrationModule, StateRoundTripIsAllocationFree) {
  const auto specs = register_specs();
  core::calib::CalibrationModule a(module_config());
  a.attach(RegisterTable(specs));
  SimMachine m(module_config(), test_errors(), 0.3, 0.3, 0.1, 4);
  core::TimeNs now = 0;
  core::StepOutput out;
  ASSERT_TRUE(run_initial_calibration(a.calibrator(), m, now, out));
  m.set_drift([](double) { return std::array<double, 4>{6.0, 6.0, -3.0, 2.0}; });
  now += core::from_seconds(3600.0);
  const auto g0 = a.state_generation();
  std::array<core::Event, 4> touches{};
  for (std::size_t s = 0; s < 4; ++s) {
    touches[s] = m.machine_touch(s, 1, now);
  }
  out.clear();
  a.step(now, touches, out);
  EXPECT_GT(a.state_generation(), g0);

  core::calib::CalibrationModule b(module_config());
  b.attach(RegisterTable(specs));
  std::vector<std::byte> buf(a.state_capacity());
  std::size_t n = 0;
  bool loaded = false;
  {
    const AllocationScope scope;
    n = a.save_state(buf);
    loaded = b.load_state(std::span<const std::byte>(buf.data(), n));
    EXPECT_EQ(scope.count(), 0u);
  }
  ASSERT_EQ(n, core::calib::CalibrationModule::kStateBytes);
  ASSERT_TRUE(loaded);
  EXPECT_EQ(b.calibrator().phase(), core::calib::Phase::kReady);
  for (std::size_t axis = 0; axis < 3; ++axis) {
    EXPECT_DOUBLE_EQ(b.calibrator().target_um(axis, now + core::from_seconds(100.0)),
                     a.calibrator().target_um(axis, now + core::from_seconds(100.0)));
  }
  // Corrupt bytes are refused and the fresh state kept.
  core::calib::CalibrationModule c(module_config());
  c.attach(RegisterTable(specs));
  buf[4] = std::byte{0x7f};  // phase 127
  EXPECT_FALSE(c.load_state(std::span<const std::byte>(buf.data(), n)));
  EXPECT_FALSE(c.load_state(std::span<const std::byte>(buf.data(), n - 1)));
  EXPECT_EQ(c.calibrator().phase(), core::calib::Phase::kUncalibrated);
}

}  // namespace
}  // namespace nccomp::test::calib
