// GIVEN systemd/nccompd.service, WHEN systemd-analyze rates its hardening offline, THEN the
// exposure is 2.0 or lower (issue 9), and the unit has the service contract the daemon relies on.
// The drop-in systemd/nccompd-can-restart.conf ([can] restart = "daemon", issue 17) adds exactly
// CAP_NET_ADMIN and AF_NETLINK.
// GIVEN systemd/nccompd.sysusers.conf, WHEN systemd-sysusers applies it to an empty root
// directory, THEN it creates the daemon's user and group nccomp and the admin group nccomp-admin
// (the default [status] admin_group), the daemon's user not being a member of the latter.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <string>

namespace {

std::string run(const std::string& cmd) {
  std::string out;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (p == nullptr) {
    return out;
  }
  char buf[4096];
  std::size_t n = 0;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) {
    out.append(buf, n);
  }
  ::pclose(p);
  return out;
}

const std::string kUnit = std::string(NCCOMP_SOURCE_DIR) + "/systemd/nccompd.service";

TEST(SystemdUnit, SecurityExposureIsAtMost2) {
  ASSERT_EQ(std::system("command -v systemd-analyze > /dev/null 2>&1"), 0)
      << "systemd-analyze is missing: install the `systemd` package (scripts/setup)";
  const std::string out =
      run("systemd-analyze security --offline=true --no-pager '" + kUnit + "' 2>&1");
  std::smatch m;
  const std::regex re("Overall exposure level for nccompd\\.service: ([0-9]+\\.[0-9]+)");
  ASSERT_TRUE(std::regex_search(out, m, re)) << out;
  const double exposure = std::stod(m[1]);
  EXPECT_LE(exposure, 2.0) << out;
}

// Every syscall of `systemd-analyze syscall-filter GROUP`, groups expanded.
std::set<std::string> syscalls_of(const std::string& group, int depth = 0) {
  std::set<std::string> out;
  if (depth > 8) {
    return out;
  }
  std::istringstream in(run("systemd-analyze syscall-filter --no-pager '" + group + "' 2>&1"));
  bool first = true;
  for (std::string l; std::getline(in, l);) {
    const auto b = l.find_first_not_of(" \t");
    if (b == std::string::npos || l[b] == '#') {
      continue;
    }
    const std::string name = l.substr(b);
    if (first) {  // the group's own name
      first = false;
      continue;
    }
    if (name[0] == '@') {
      const auto sub = syscalls_of(name, depth + 1);
      out.insert(sub.begin(), sub.end());
    } else {
      out.insert(name);
    }
  }
  return out;
}

// The unit's syscall filter lets the daemon do what its real-time policy and its service contract
// need: SCHED_FIFO for the loop thread (pthread_setschedparam → sched_setscheduler), CPU
// affinity, mlockall, absolute-deadline sleeps, the signalfd, the notify socket.
TEST(SystemdUnit, SyscallFilterAllowsTheRealtimeCalls) {
  ASSERT_EQ(std::system("command -v systemd-analyze > /dev/null 2>&1"), 0);
  std::ifstream in(kUnit);
  std::set<std::string> allowed;
  std::set<std::string> denied;
  int filters = 0;
  for (std::string l; std::getline(in, l);) {
    if (l.rfind("SystemCallFilter=", 0) != 0) {
      continue;
    }
    ++filters;
    std::string v = l.substr(17);
    const bool deny = !v.empty() && v[0] == '~';
    std::istringstream words(deny ? v.substr(1) : v);
    for (std::string w; words >> w;) {
      auto set = w[0] == '@' ? syscalls_of(w) : std::set<std::string>{w};
      (deny ? denied : allowed).insert(set.begin(), set.end());
    }
  }
  ASSERT_EQ(filters, 2);
  ASSERT_GT(allowed.size(), 100U) << "group expansion failed";
  ASSERT_GT(denied.size(), 10U) << "group expansion failed";
  for (const char* call : {"sched_setscheduler", "sched_setaffinity", "mlockall", "clock_nanosleep",
                           "signalfd4", "eventfd2", "sendmsg", "getrusage"}) {
    EXPECT_EQ(allowed.count(call), 1U) << call << " is not allowed by the unit";
    EXPECT_EQ(denied.count(call), 0U) << call << " is denied by the unit";
  }
}

/// The unit (and the drop-in, if given) installed under a scratch root as systemd would find them,
/// rated by `systemd-analyze security --offline --root`: the output.
std::string security_with(const std::string& drop_in) {
  namespace fs = std::filesystem;
  std::string tmpl = (fs::temp_directory_path() / "nccomp-unit-XXXXXX").string();
  if (::mkdtemp(tmpl.data()) == nullptr) {
    return "mkdtemp failed";
  }
  const fs::path root = tmpl;
  const fs::path units = root / "etc/systemd/system";
  fs::create_directories(units / "nccompd.service.d");
  fs::copy_file(kUnit, units / "nccompd.service");
  if (!drop_in.empty()) {
    fs::copy_file(drop_in, units / "nccompd.service.d/can-restart.conf");
  }
  const std::string out = run("systemd-analyze security --offline=true --no-pager --root='" +
                              root.string() + "' nccompd.service 2>&1");
  fs::remove_all(root);
  return out;
}

/// The settings systemd-analyze marks as exposed ("✗ NAME ..." → NAME).
std::set<std::string> exposed(const std::string& security) {
  std::set<std::string> out;
  std::istringstream in(security);
  for (std::string l; std::getline(in, l);) {
    if (l.rfind("\u2717 ", 0) == 0) {
      const std::string rest = l.substr(std::string("\u2717 ").size());
      out.insert(rest.substr(0, rest.find(' ')));
    }
  }
  return out;
}

// GIVEN the unit with the drop-in for [can] restart = "daemon", WHEN systemd merges them, THEN
// exactly three settings open up: the CAP_NET_ADMIN bounding set, the ambient capability (the
// daemon runs as user nccomp) and AF_NETLINK sockets; nothing else changes.
TEST(SystemdUnit, CanRestartDropInAddsOnlyNetAdminAndNetlink) {
  ASSERT_EQ(std::system("command -v systemd-analyze > /dev/null 2>&1"), 0);
  const std::string drop_in = std::string(NCCOMP_SOURCE_DIR) + "/systemd/nccompd-can-restart.conf";
  const std::string plain = security_with("");
  const std::string merged = security_with(drop_in);
  const std::set<std::string> before = exposed(plain);
  const std::set<std::string> after = exposed(merged);
  ASSERT_GT(before.size(), 10U) << plain;
  std::set<std::string> added;
  for (const std::string& s : after) {
    if (before.count(s) == 0) {
      added.insert(s);
    }
  }
  EXPECT_EQ(added,
            (std::set<std::string>{"AmbientCapabilities=", "CapabilityBoundingSet=~CAP_NET_ADMIN",
                                   "RestrictAddressFamilies=~AF_NETLINK"}))
      << merged;
  for (const std::string& s : before) {
    EXPECT_EQ(after.count(s), 1U) << s << " closed by the drop-in?";
  }
  std::smatch m;
  const std::regex re("Overall exposure level for nccompd\\.service: ([0-9]+\\.[0-9]+)");
  ASSERT_TRUE(std::regex_search(merged, m, re)) << merged;
  std::printf("exposure with the drop-in: %s\n", m[1].str().c_str());
  // The lines the daemon's refusal and docs/can.md tell the operator to install.
  std::ifstream in(drop_in);
  const std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  for (const char* line :
       {"[Service]\n", "\nRestrictAddressFamilies=AF_NETLINK\n",
        "\nCapabilityBoundingSet=CAP_NET_ADMIN\n", "\nAmbientCapabilities=CAP_NET_ADMIN\n",
        "/etc/systemd/system/nccompd.service.d/can-restart.conf"}) {
    EXPECT_NE(text.find(line), std::string::npos) << line;
  }
}

TEST(SystemdUnit, HasTheServiceContract) {
  std::ifstream in(kUnit);
  const std::string unit{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  for (const char* line :
       {"Type=notify", "WatchdogSec=", "StateDirectory=nccompd", "LogsDirectory=nccompd",
        "ConfigurationDirectory=nccompd", "RuntimeDirectory=nccompd", "User=nccomp",
        "ExecReload=/bin/kill -HUP $MAINPID", "RestrictAddressFamilies=AF_CAN AF_INET AF_UNIX",
        "DevicePolicy=closed", "CapabilityBoundingSet=\n", "SystemCallFilter=@system-service"}) {
    EXPECT_NE(unit.find(line), std::string::npos) << line;
  }
  std::ifstream su(std::string(NCCOMP_SOURCE_DIR) + "/systemd/nccompd.sysusers.conf");
  const std::string sysusers{std::istreambuf_iterator<char>(su), std::istreambuf_iterator<char>()};
  EXPECT_NE(sysusers.find("u     nccomp"), std::string::npos);
}

TEST(SystemdUnit, SysusersCreatesTheDaemonUserAndTheAdminGroup) {
  if (std::system("command -v systemd-sysusers > /dev/null 2>&1") != 0) {
    GTEST_SKIP() << "systemd-sysusers is missing: install the `systemd` package (scripts/setup)";
  }
  namespace fs = std::filesystem;
  const fs::path root =
      fs::temp_directory_path() / ("nccomp_sysusers_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "etc");
  const std::string out = run("systemd-sysusers --root='" + root.string() + "' '" +
                              NCCOMP_SOURCE_DIR + "/systemd/nccompd.sysusers.conf' 2>&1");
  const auto slurp = [](const fs::path& p) {
    std::ifstream in(p);
    return std::string{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  };
  const std::string group = slurp(root / "etc/group");
  const std::string passwd = slurp(root / "etc/passwd");
  fs::remove_all(root);
  EXPECT_TRUE(std::regex_search(passwd, std::regex("(^|\n)nccomp:x:[0-9]+:[0-9]+:"))) << out;
  EXPECT_TRUE(std::regex_search(group, std::regex("(^|\n)nccomp:x:[0-9]+:\n"))) << group;
  // The admin group, with no members: an administrator adds the operators who may change the
  // machine (usermod -aG nccomp-admin), the daemon itself needs no membership.
  EXPECT_TRUE(std::regex_search(group, std::regex("(^|\n)nccomp-admin:x:[0-9]+:\n"))) << group;
  EXPECT_TRUE(std::regex_search(group, std::regex("(^|\n)dialout:x:[0-9]+:nccomp\n"))) << group;
  std::ifstream cfg(std::string(NCCOMP_SOURCE_DIR) + "/config/nccompd.toml");
  const std::string shipped{std::istreambuf_iterator<char>(cfg), std::istreambuf_iterator<char>()};
  EXPECT_NE(shipped.find("\nadmin_group = \"nccomp-admin\"\n"), std::string::npos);
}

}  // namespace
