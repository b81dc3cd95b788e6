// GIVEN systemd/nccomp-page.service, WHEN systemd-analyze rates its hardening offline, THEN the
// exposure is 2.0 or lower, as nccompd's unit; and it may read /proc/net/tcp (no ProcSubset=pid).
// GIVEN nccompd's and the page's sysusers.d entries applied to an empty root directory, THEN the
// user nccomp-page exists and is a member of nccomp (status socket) and nccomp-admin (acknowledge).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>

namespace {

namespace fs = std::filesystem;

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

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  return std::string{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

const std::string kSystemd = std::string(NCCOMP_SOURCE_DIR) + "/systemd/";

TEST(PageUnit, SecurityExposureIsAtMost2AndProcNetIsReadable) {
  ASSERT_EQ(std::system("command -v systemd-analyze > /dev/null 2>&1"), 0)
      << "systemd-analyze is missing: install the `systemd` package (scripts/setup)";
  const std::string out = run("systemd-analyze security --offline=true --no-pager '" + kSystemd +
                              "nccomp-page.service' 2>&1");
  std::smatch m;
  ASSERT_TRUE(std::regex_search(
      out, m, std::regex("Overall exposure level for nccomp-page\\.service: ([0-9]+\\.[0-9]+)")))
      << out;
  EXPECT_LE(std::stod(m[1]), 2.0) << out;
  const std::string unit = slurp(kSystemd + "nccomp-page.service");
  EXPECT_FALSE(std::regex_search(unit, std::regex("(^|\n)ProcSubset=pid"))) << unit;
  EXPECT_TRUE(std::regex_search(unit, std::regex("(^|\n)User=nccomp-page\n"))) << unit;
}

TEST(PageUnit, SysusersCreatesThePageUserInTheStatusAndAdminGroups) {
  if (std::system("command -v systemd-sysusers > /dev/null 2>&1") != 0) {
    GTEST_SKIP() << "systemd-sysusers is missing: install the `systemd` package (scripts/setup)";
  }
  const fs::path root =
      fs::temp_directory_path() / ("nccomp_page_sysusers_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "etc");
  const std::string out =
      run("systemd-sysusers --root='" + root.string() + "' '" + kSystemd +
          "nccompd.sysusers.conf' '" + kSystemd + "nccomp-page.sysusers.conf' 2>&1");
  const std::string group = slurp(root / "etc/group");
  const std::string passwd = slurp(root / "etc/passwd");
  fs::remove_all(root);
  EXPECT_TRUE(std::regex_search(passwd, std::regex("(^|\n)nccomp-page:x:[0-9]+:[0-9]+:"))) << out;
  EXPECT_TRUE(
      std::regex_search(group, std::regex("(^|\n)nccomp:x:[0-9]+:([^\n]*,)?nccomp-page(,|\n)")))
      << group;
  EXPECT_TRUE(std::regex_search(
      group, std::regex("(^|\n)nccomp-admin:x:[0-9]+:([^\n]*,)?nccomp-page(,|\n)")))
      << group;
}

}  // namespace
