#include "core/common/profile.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "core/common/output.hpp"

namespace nccomp::core {
namespace {

TEST(Profile, EveryShapeStartsAtZeroAndEndsAtOne) {
  for (auto s : {ProfileShape::kLinear, ProfileShape::kCosine, ProfileShape::kSmoothstep}) {
    EXPECT_DOUBLE_EQ(profile_fraction(s, 0.0), 0.0);
    EXPECT_DOUBLE_EQ(profile_fraction(s, 1.0), 1.0);
    EXPECT_DOUBLE_EQ(profile_fraction(s, -3.0), 0.0);
    EXPECT_DOUBLE_EQ(profile_fraction(s, 7.0), 1.0);
    EXPECT_DOUBLE_EQ(profile_fraction(s, std::nan("")), 0.0);
    EXPECT_NEAR(profile_fraction(s, 0.5), 0.5, 1e-12);  // all three are point-symmetric
  }
}

TEST(Profile, SmoothShapesHaveZeroSlopeAtBothEnds) {
  EXPECT_NEAR(profile_slope(ProfileShape::kCosine, 0.0), 0.0, 1e-12);
  EXPECT_NEAR(profile_slope(ProfileShape::kCosine, 1.0), 0.0, 1e-12);
  EXPECT_NEAR(profile_slope(ProfileShape::kSmoothstep, 0.0), 0.0, 1e-12);
  EXPECT_NEAR(profile_slope(ProfileShape::kSmoothstep, 1.0), 0.0, 1e-12);
  // Their steepest slopes: π/2 and 3/2 times the linear slope.
  EXPECT_NEAR(profile_slope(ProfileShape::kCosine, 0.5), M_PI / 2.0, 1e-12);
  EXPECT_NEAR(profile_slope(ProfileShape::kSmoothstep, 0.5), 1.5, 1e-12);
  EXPECT_DOUBLE_EQ(profile_slope(ProfileShape::kLinear, 0.3), 1.0);
}

TEST(Profile, TableInterpolatesLinearly) {
  ProfileTable t;
  t.n = 3;
  t.f = {0.0, 0.2, 1.0};
  EXPECT_NEAR(profile_fraction(ProfileShape::kTable, 0.25, &t), 0.1, 1e-12);
  EXPECT_NEAR(profile_fraction(ProfileShape::kTable, 0.75, &t), 0.6, 1e-12);
  EXPECT_NEAR(profile_slope(ProfileShape::kTable, 0.75, &t), 1.6, 1e-12);
}

TEST(Profile, StepIsTheWholeCorrectionAtOnce) {
  EXPECT_DOUBLE_EQ(profile_fraction(ProfileShape::kStep, 1e-9), 1.0);
  EXPECT_DOUBLE_EQ(profile_fraction(ProfileShape::kStep, 0.0), 0.0);
}

TEST(StepOutput, FixedVectorRefusesAndCountsWhenFull) {
  FixedVector<int, 2> v;
  EXPECT_TRUE(v.push(1));
  EXPECT_TRUE(v.push(2));
  EXPECT_FALSE(v.push(3));
  EXPECT_EQ(v.size(), 2U);
  EXPECT_EQ(v.overflows(), 1U);
  v.clear();
  EXPECT_TRUE(v.empty());
  StepOutput out;
  out.alarm(5, Severity::kAlarm, AlarmCode::kOffsetNonFinite, 3, 1.0);
  ASSERT_EQ(out.alarms.size(), 1U);
  EXPECT_EQ(out.alarms[0].code, AlarmCode::kOffsetNonFinite);
}

}  // namespace
}  // namespace nccomp::core
