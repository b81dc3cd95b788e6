// GIVEN systemd/nccompd.service, WHEN systemd-analyze rates its hardening offline, THEN the
// exposure is 2.0 or lower (issue 9), and the unit has the service contract the daemon relies on.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <regex>
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

}  // namespace
