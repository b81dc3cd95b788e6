// GIVEN systemd/nccomp-publish.service, WHEN systemd-analyze rates its hardening offline, THEN the
// exposure is 2.0 or lower (as nccompd's unit), it runs as its own user in the group nccomp
// (the log and the status socket), and it starts `nccomp publish` on the shipped config path.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>

namespace {

std::string run(const std::string& cmd) {
  std::string out;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (p == nullptr) return out;
  char buf[4096];
  std::size_t n = 0;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) out.append(buf, n);
  ::pclose(p);
  return out;
}

const std::string kUnit = std::string(NCCOMP_SOURCE_DIR) + "/systemd/nccomp-publish.service";

TEST(PublishUnit, SecurityExposureIsAtMost2AndItRunsThePublisherUnprivileged) {
  ASSERT_EQ(std::system("command -v systemd-analyze > /dev/null 2>&1"), 0)
      << "systemd-analyze is missing: install the `systemd` package (scripts/setup)";
  const std::string out =
      run("systemd-analyze security --offline=true --no-pager '" + kUnit + "' 2>&1");
  std::smatch m;
  const std::regex re("Overall exposure level for nccomp-publish\\.service: ([0-9]+\\.[0-9]+)");
  ASSERT_TRUE(std::regex_search(out, m, re)) << out;
  EXPECT_LE(std::stod(m[1]), 2.0) << out;

  std::ifstream in(kUnit);
  std::stringstream s;
  s << in.rdbuf();
  const std::string unit = s.str();
  EXPECT_NE(unit.find("\nExecStart=/usr/bin/nccomp publish --config "
                      "/etc/nccomp/nccomp-publish.toml\n"),
            std::string::npos);
  EXPECT_NE(unit.find("\nUser=nccomp-publish\n"), std::string::npos);
  EXPECT_NE(unit.find("\nSupplementaryGroups=nccomp\n"), std::string::npos);
  EXPECT_NE(unit.find("\nStateDirectory=nccomp-publish\n"), std::string::npos);
}

}  // namespace
