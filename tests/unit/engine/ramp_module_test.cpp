#include "core/engine/ramp_module.hpp"

#include <gtest/gtest.h>

#include <limits>
#include <vector>

namespace nccomp::core::engine {
namespace {

TEST(RampModule, RampsAtRateAndStopsAtTarget) {
  RampModule r(RampConfig{"r", "a", 1.0, -1.0, 2.0});
  const std::vector<RegisterSpec> specs{{"a", RegisterKind::kToolRadiusWear, {}}};
  r.attach(RegisterTable(specs));
  StepOutput out;
  r.step(0, {}, out);
  EXPECT_DOUBLE_EQ(r.value_um(), 1.0);
  r.step(from_seconds(0.5), {}, out);
  EXPECT_NEAR(r.value_um(), 0.0, 1e-12);
  r.step(from_seconds(5.0), {}, out);
  EXPECT_DOUBLE_EQ(r.value_um(), -1.0);
  EXPECT_TRUE(r.done());
  ASSERT_EQ(out.writes.size(), 3U);
  EXPECT_DOUBLE_EQ(out.writes[2].value_um, -1.0);
}

TEST(RampModule, RejectsBadConfigAndBadState) {
  EXPECT_THROW(RampModule(RampConfig{"r", "a", 0.0, 1.0, 0.0}), std::invalid_argument);
  EXPECT_THROW(RampModule(RampConfig{"r", "a", 0.0, std::numeric_limits<double>::infinity(), 1.0}),
               std::invalid_argument);
  RampModule r(RampConfig{"r", "a", 0.0, 1.0, 1.0});
  std::vector<std::byte> b(r.state_capacity());
  ASSERT_EQ(r.save_state(b), b.size());
  EXPECT_FALSE(r.load_state(std::span<const std::byte>(b.data(), b.size() - 1)));
  b[0] = std::byte{9};  // unknown version
  EXPECT_FALSE(r.load_state(b));
}

}  // namespace
}  // namespace nccomp::core::engine
