// GIVEN successive answers of nccompd's status socket WHEN digested THEN each alarm and each
// acknowledgement is published once (also across a restart of the publisher: the memory is
// saved), a new daemon's alarms are new, and a model change is published.
#include "tools/mqtt/status_digest.hpp"

#include <gtest/gtest.h>

namespace nccomp::tools::mqtt {
namespace {

nlohmann::json status(int pid, nlohmann::json alarms, double acknowledged, int generation,
                      int terms) {
  return nlohmann::json{
      {"daemon", {{"pid", pid}, {"config_generation", generation}, {"hold", false}}},
      {"loop", {{"cycles", 10}, {"latency_us", {{"p99_9", 12.5}}}}},
      {"modules",
       {{{"name", "creep"},
         {"status", {{"acknowledged", acknowledged}, {"last_acknowledge", "halt"}}}},
        {{"name", "model"}, {"status", {{"applied_terms", terms}, {"machine_time_s", 3.5}}}}}},
      {"alarms", std::move(alarms)}};
}

nlohmann::json alarm(double t_s, int code, int subject) {
  return {{"time_s", t_s}, {"severity", "alarm"}, {"code", code},
          {"name", "x"},   {"subject", subject},  {"value", 1.5}};
}

TEST(StatusDigest, AlarmsAcknowledgementsAndModelChangesArePublishedOnce) {
  StatusMemory mem;
  constexpr std::int64_t kReal = 1'700'000'000'000'000'000;
  auto out = digest_status(status(100, {alarm(50.0, 23, 4)}, 0, 1, 2), mem, 80.0, kReal);
  ASSERT_EQ(out.size(), 2U);
  EXPECT_EQ(out[0].kind, "alarms");
  EXPECT_EQ(out[0].payload.at("event"), "alarm");
  EXPECT_EQ(out[0].payload.at("code"), 23);
  // Raised at 50 s of the monotonic clock, now is 80 s: 30 s before the wall clock's now.
  EXPECT_EQ(out[0].payload.at("utc"), "2023-11-14T22:12:50.000Z");
  EXPECT_EQ(out[1].kind, "model");
  EXPECT_EQ(out[1].payload.at("applied_terms"), 2);

  // The same list again, plus one alarm with the same code at another subject, and an
  // acknowledgement: only the new ones.
  out = digest_status(status(100, {alarm(50.0, 23, 4), alarm(50.0, 23, 5)}, 1, 1, 2), mem, 81.0,
                      kReal);
  ASSERT_EQ(out.size(), 2U);
  EXPECT_EQ(out[0].payload.at("subject"), 5);
  EXPECT_EQ(out[1].payload.at("event"), "acknowledge");
  EXPECT_EQ(out[1].payload.at("module"), "creep");
  EXPECT_EQ(out[1].payload.at("cleared"), "halt");

  // The memory survives a restart of the publisher.
  StatusMemory restored = StatusMemory::from_json(mem.to_json());
  EXPECT_TRUE(digest_status(status(100, {alarm(50.0, 23, 4), alarm(50.0, 23, 5)}, 1, 1, 2),
                            restored, 82.0, kReal)
                  .empty());

  // A reload that changes the model; then a new daemon (pid) with its own first alarm at the
  // same time and code: new.
  out = digest_status(status(100, {alarm(50.0, 23, 5)}, 1, 2, 3), restored, 83.0, kReal);
  ASSERT_EQ(out.size(), 1U);
  EXPECT_EQ(out[0].kind, "model");
  EXPECT_EQ(out[0].payload.at("config_generation"), 2);
  out = digest_status(status(200, {alarm(50.0, 23, 5)}, 0, 1, 3), restored, 84.0, kReal);
  ASSERT_EQ(out.size(), 2U);
  EXPECT_EQ(out[0].payload.at("daemon_pid"), 200);
  EXPECT_EQ(out[1].kind, "model");

  const auto s = daemon_summary(status(100, {}, 0, 1, 2));
  EXPECT_EQ(s.at("latency_us_p99_9"), 12.5);
  EXPECT_EQ(s.at("pid"), 100);
}

}  // namespace
}  // namespace nccomp::tools::mqtt
