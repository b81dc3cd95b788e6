#include "core/checkpoint/probe.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace nccomp::core::checkpoint {
namespace {

TEST(ProbeCorrection, Delta0IsZeroOnAVerticalWall) {
  // GIVEN α = 0 WHEN correcting THEN δ0 = 0 and δ' = δ.
  const ProbeCorrection c = correct_probe(12.5, 0.0, 3.0);
  ASSERT_EQ(c.status, ProbeStatus::kOk);
  EXPECT_DOUBLE_EQ(c.delta0_um, 0.0);
  EXPECT_DOUBLE_EQ(c.corrected_um, 12.5);
}

TEST(ProbeCorrection, Delta0Numbers) {
  // r/cos α − r: 60° doubles the radius (δ0 = r), 10° with r = 1 mm gives 15.427 µm.
  EXPECT_NEAR(probe_delta0_um(3.0, 60.0), 3000.0, 1e-9);
  EXPECT_NEAR(probe_delta0_um(1.0, 10.0), 15.42661189, 1e-6);
  EXPECT_NEAR(probe_delta0_um(2.5, 5.0), 9.549594, 1e-5);
  // The side the wall leans to does not matter.
  EXPECT_NEAR(probe_delta0_um(1.0, -10.0), 15.42661189, 1e-6);
  const ProbeCorrection c = correct_probe(40.0, 10.0, 1.0);
  ASSERT_EQ(c.status, ProbeStatus::kOk);
  EXPECT_NEAR(c.corrected_um, 40.0 - 15.42661189, 1e-6);
  // r = 0 (an ideal point probe) needs no correction.
  EXPECT_DOUBLE_EQ(correct_probe(7.0, 45.0, 0.0).corrected_um, 7.0);
  // Just below the limit: huge but finite.
  const ProbeCorrection steep = correct_probe(0.0, 88.9, 1.0);
  ASSERT_EQ(steep.status, ProbeStatus::kOk);
  EXPECT_NEAR(steep.delta0_um, (1.0 / std::cos(88.9 * M_PI / 180.0) - 1.0) * 1000.0, 1e-6);
}

TEST(ProbeCorrection, RejectsBadInputs) {
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_EQ(correct_probe(1.0, 89.0, 1.0).status, ProbeStatus::kAngleTooSteep);
  EXPECT_EQ(correct_probe(1.0, -89.0, 1.0).status, ProbeStatus::kAngleTooSteep);
  EXPECT_EQ(correct_probe(1.0, 120.0, 1.0).status, ProbeStatus::kAngleTooSteep);
  EXPECT_EQ(correct_probe(1.0, 10.0, -0.5).status, ProbeStatus::kNegativeRadius);
  EXPECT_EQ(correct_probe(std::nan(""), 10.0, 1.0).status, ProbeStatus::kNonFinite);
  EXPECT_EQ(correct_probe(1.0, std::nan(""), 1.0).status, ProbeStatus::kNonFinite);
  EXPECT_EQ(correct_probe(1.0, 10.0, inf).status, ProbeStatus::kNonFinite);
  EXPECT_EQ(correct_probe(-inf, 10.0, 1.0).status, ProbeStatus::kNonFinite);
  // A rejected reading carries no value.
  EXPECT_DOUBLE_EQ(correct_probe(1.0, 89.0, 1.0).corrected_um, 0.0);
}

TEST(ProbeCorrection, ThrowingFormNamesTheProblem) {
  try {
    (void)corrected_deviation_um(5.0, 89.0, 1.0);
    FAIL() << "no throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("below 89 degrees"), std::string::npos) << e.what();
  }
  try {
    (void)corrected_deviation_um(5.0, 10.0, -1.0);
    FAIL() << "no throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("negative"), std::string::npos) << e.what();
  }
  EXPECT_NEAR(corrected_deviation_um(20.0, 60.0, 0.002), 18.0, 1e-9);
}

}  // namespace
}  // namespace nccomp::core::checkpoint
