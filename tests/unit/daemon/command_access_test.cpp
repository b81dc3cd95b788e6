// GIVEN every operator verb nccompd registers (the sections linked as in nccompd), WHEN a caller
// who is not root, not the daemon's user and not in the admin group sends it, THEN it is refused
// before its handler runs ("permission denied"), unless its registration says it is read-only
// (only the calibration status is); a verb added later without an access rule changes the
// machine. WHEN the caller is root, the daemon's user or in the admin group (effective or
// supplementary), THEN the handler runs (here it answers that this process takes no commands).
#include <grp.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <stdexcept>
#include <string>
#include <vector>

#include "daemon/commands/command.hpp"

namespace nccomp::daemon {
namespace {

constexpr uid_t kOperator = 4242;
constexpr gid_t kOperatorGroup = 4242;

// Group 0 stands for the admin group: every host has it, and it has a name.
CommandPolicy policy() {
  const group* g = ::getgrgid(0);
  return CommandPolicy{g != nullptr ? g->gr_name : "root", 4343};
}

Caller caller(uid_t uid, gid_t gid, std::vector<gid_t> groups) {
  Caller c;
  c.known = true;
  c.pid = 777;
  c.uid = uid;
  c.gid = gid;
  c.groups = std::move(groups);
  c.groups_known = true;
  return c;
}

std::string send(const std::string& line, const Caller& who, const CommandPolicy& p = policy()) {
  std::string answer;
  EXPECT_TRUE(dispatch_command(line, who, p, answer)) << line;
  return answer;
}

bool denied(const std::string& answer) {
  return answer.rfind("error: permission denied: ", 0) == 0;
}

TEST(OperatorCommands, EveryVerbButTheCalibrationStatusNeedsTheAdminGroup) {
  const Caller op = caller(kOperator, kOperatorGroup, {100});
  const auto verbs = registered_verbs();
  for (const char* v : {"acknowledge", "warm-start", "calibrate"}) {
    EXPECT_NE(std::find(verbs.begin(), verbs.end(), v), verbs.end()) << v;
  }
  for (const auto& verb : verbs) {
    const std::string answer = send(verb + " now", op);
    EXPECT_EQ(answer.rfind("error: permission denied: '" + verb + "' changes the machine; uid " +
                               std::to_string(kOperator) + " (",
                           0),
              0U)
        << answer;
  }
  for (const char* line :
       {"acknowledge", "acknowledge all", "warm-start", "warm-start now",
        "warm-start at-next-motion", "calibrate begin", "calibrate discard",
        "calibrate recalibrate", "calibrate facets lateral 1.99 1.98",
        "calibrate touch machine x + lateral 10.0", "calibrate statusx", "calibrate status now",
        "model load /srv/fit/model.toml", "model rollback", "model", "model status now",
        "model candidate /srv/fit/model.toml", "model promote"}) {
    EXPECT_TRUE(denied(send(line, op))) << line;
  }
  // The model's status is read-only too.
  EXPECT_EQ(send("model status", op), "error: this process takes no model commands\n");
  // The calibration status (what `nccomp calibrate --daemon` polls) is read-only: it reaches the
  // handler, which answers that this process (no loop) takes no commands.
  for (const char* line : {"calibrate", "calibrate status", "  calibrate   Status  "}) {
    EXPECT_EQ(send(line, op), "error: this process takes no operator commands\n") << line;
  }
}

TEST(OperatorCommands, RootTheDaemonsUserAndAdminMembersPass) {
  const gid_t admin = 0;
  const std::vector<Caller> allowed = {
      caller(0, 0, {}),                                 // root
      caller(4343, 4343, {}),                           // the daemon's own user
      caller(kOperator, kOperatorGroup, {100, admin}),  // supplementary member
      caller(kOperator, admin, {100}),                  // effective group
  };
  for (const Caller& c : allowed) {
    EXPECT_EQ(send("acknowledge", c), "error: this process takes no operator commands\n")
        << c.uid << " " << c.gid;
    EXPECT_FALSE(denied(send("calibrate begin", c)));
  }
}

TEST(OperatorCommands, UnreadableCredentialsAndAMissingGroupRefuse) {
  Caller unknown;
  EXPECT_EQ(send("acknowledge", unknown),
            "error: permission denied: 'acknowledge' changes the machine; the caller's "
            "credentials cannot be read\n");
  Caller no_groups = caller(kOperator, kOperatorGroup, {});
  no_groups.groups_known = false;
  EXPECT_NE(send("acknowledge", no_groups).find("(its supplementary groups cannot be read)"),
            std::string::npos);
  const CommandPolicy missing{"nccomp-admin-that-does-not-exist", 4343};
  EXPECT_EQ(send("warm-start", caller(kOperator, kOperatorGroup, {0}), missing),
            "error: permission denied: 'warm-start' changes the machine; group "
            "'nccomp-admin-that-does-not-exist' ([status] admin_group) does not exist on this "
            "host: only root and the daemon's own user may\n");
  EXPECT_EQ(send("warm-start", caller(0, 0, {}), missing),
            "error: this process takes no operator commands\n");
}

TEST(OperatorCommands, AVerbIsRegisteredWithAnAccessRule) {
  EXPECT_THROW(register_command_handler("test-no-rule", {}, nullptr), std::logic_error);
  EXPECT_FALSE(is_command("test-no-rule"));
  EXPECT_TRUE(is_command("  calibrate begin"));
  EXPECT_FALSE(is_command("json"));
}

}  // namespace
}  // namespace nccomp::daemon
