// GIVEN the status-socket protocol (client/protocol.hpp), WHEN nccomp builds a verb's request or
// reads an answer, THEN the request is the line the daemon's verbs parse and the answer's parts
// are what the daemon wrote.
#include "client/protocol.hpp"

#include <gtest/gtest.h>

namespace nccomp::client {
namespace {

TEST(ClientProtocol, VerbRequestsAreTheLinesTheDaemonParses) {
  EXPECT_EQ(acknowledge_request(), "acknowledge");
  EXPECT_EQ(warm_start_request(false), "warm-start now");
  EXPECT_EQ(warm_start_request(true), "warm-start at-next-motion");
  EXPECT_EQ(register_release_request("T1_length_wear"), "register release T1_length_wear");
  EXPECT_EQ(register_release_request("all"), "register release all");
  EXPECT_EQ(calibrate_request("facets lateral 1.99 1.98"), "calibrate facets lateral 1.99 1.98");
  EXPECT_EQ(calibrate_request(""), "calibrate ");
  EXPECT_EQ(model_load_request("/srv/fit 2/model.toml"), "model load /srv/fit 2/model.toml");
  EXPECT_EQ(model_rollback_request(), "model rollback");
  EXPECT_EQ(model_status_request(), "model status");
  EXPECT_EQ(model_candidate_request("/srv/fit 3/model.toml"),
            "model candidate /srv/fit 3/model.toml");
  EXPECT_EQ(model_promote_request(), "model promote");
}

TEST(ClientProtocol, ARefusalGivesItsReasonWithoutThePrefixAndLineBreaks) {
  EXPECT_TRUE(is_error("error: busy: 32 clients\n"));
  EXPECT_FALSE(is_error("ok acknowledged: none\n"));
  EXPECT_FALSE(is_error("loop: 1000 Hz\nerror: in the middle\n"));
  EXPECT_EQ(error_reason("error: permission denied: 'acknowledge' changes the machine\n\n"),
            "permission denied: 'acknowledge' changes the machine");
  // Several lines of reason are kept (the hint after a calibrator's refusal).
  EXPECT_EQ(error_reason("error: calibrate x: refused\n-- next: begin\n"),
            "calibrate x: refused\n-- next: begin");
}

TEST(ClientProtocol, TheCalibrateAnswerGivesPhaseAndTheLinesToShow) {
  const CalibrateAnswer ok =
      parse_calibrate_answer("ok reference_touches touch_requested\ntouch set 1\n-- hint\n");
  EXPECT_TRUE(ok.ok);
  EXPECT_EQ(ok.phase, "reference_touches");
  EXPECT_EQ(ok.text, "touch set 1\n-- hint\n");
  const CalibrateAnswer bare = parse_calibrate_answer("ok ready");
  EXPECT_TRUE(bare.ok);
  EXPECT_EQ(bare.phase, "ready");
  EXPECT_EQ(bare.text, "");
  const CalibrateAnswer refused = parse_calibrate_answer("error: calibrate: no module\n");
  EXPECT_FALSE(refused.ok);
  EXPECT_EQ(refused.phase, "");
  EXPECT_EQ(refused.text, "error: calibrate: no module\n");
}

}  // namespace
}  // namespace nccomp::client
