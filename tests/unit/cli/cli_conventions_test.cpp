// GIVEN every binary the packages install (nccompd, nccomp, ncsim, ncsim_peer, modbus_nc,
// can_nc, modbus_map, nccomp-page, nccomp-analyzed), WHEN each runs as a process:
// - with --help, THEN exit 0 and a help text on stdout;
// - with --version, THEN exit 0 and "<name> <version>" where the version is the newest entry of
//   debian/changelog (read here, independently of the build's generated header);
// - with an unknown option, THEN exit 2 (a usage error; CLI11's own codes are 100+);
// - with an invalid input file, THEN exit 3;
// and every subcommand of nccomp (as listed by `nccomp --help`) answers --help with 0 and an
// unknown option with 2. The bash completion of nccomp, sourced into bash, offers every
// subcommand and a subcommand's options.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

extern char** environ;

namespace {

namespace fs = std::filesystem;

struct Proc {
  int exit_code{-1};
  std::string out;
  std::string err;
};

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

class CliConventions : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("nccomp_cli_conv_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  Proc run(std::vector<std::string> args) const {
    std::vector<char*> argv;
    for (auto& s : args) {
      argv.push_back(s.data());
    }
    argv.push_back(nullptr);
    const fs::path out = dir_ / "stdout";
    const fs::path err = dir_ / "stderr";
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&fa, 2, err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    pid_t pid = -1;
    Proc r;
    if (posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), environ) != 0) {
      ADD_FAILURE() << "cannot start " << args[0];
      posix_spawn_file_actions_destroy(&fa);
      return r;
    }
    posix_spawn_file_actions_destroy(&fa);
    int st = 0;
    ::waitpid(pid, &st, 0);
    r.exit_code = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
    r.out = slurp(out);
    r.err = slurp(err);
    return r;
  }

  std::string write(const std::string& name, const std::string& text) const {
    std::ofstream(dir_ / name) << text;
    return (dir_ / name).string();
  }

  fs::path dir_;
};

/// The version of the newest debian/changelog entry: "nccomp (0.1.0) unstable; ..." -> 0.1.0.
std::string changelog_version() {
  std::ifstream in(std::string(NCCOMP_SOURCE_DIR) + "/debian/changelog");
  std::string first;
  std::getline(in, first);
  std::smatch m;
  EXPECT_TRUE(std::regex_search(first, m, std::regex(R"(^nccomp \(([^)]+)\))"))) << first;
  return m.size() > 1 ? m[1].str() : "";
}

struct Binary {
  const char* name;
  const char* path;
};

const std::vector<Binary>& binaries() {
  static const std::vector<Binary> b = {{"nccompd", NCCOMPD_BIN},
                                        {"nccomp", NCCOMP_BIN},
                                        {"ncsim", NCSIM_BIN},
                                        {"ncsim_peer", NCSIM_PEER_BIN},
                                        {"modbus_nc", MODBUS_NC_BIN},
                                        {"can_nc", CAN_NC_BIN},
                                        {"modbus_map", MODBUS_MAP_BIN},
                                        {"nccomp-page", NCCOMP_PAGE_BIN},
                                        {"nccomp-analyzed", NCCOMP_ANALYZED_BIN}};
  return b;
}

/// Subcommand names from `nccomp --help` ("Subcommands:" then one "  name  description" a line).
std::vector<std::string> subcommands(const std::string& help) {
  std::vector<std::string> subs;
  std::istringstream in(help);
  std::string line;
  bool in_list = false;
  const std::regex item(R"(^  ([a-z][a-z0-9-]*)\s)");
  while (std::getline(in, line)) {
    if (line == "Subcommands:") {
      in_list = true;
      continue;
    }
    std::smatch m;
    if (in_list && std::regex_search(line, m, item)) {
      subs.push_back(m[1].str());
    }
  }
  return subs;
}

TEST_F(CliConventions, EveryBinaryAnswersHelpAndVersionWithZero) {
  const std::string version = changelog_version();
  ASSERT_FALSE(version.empty());
  for (const Binary& b : binaries()) {
    SCOPED_TRACE(b.name);
    const Proc help = run({b.path, "--help"});
    EXPECT_EQ(help.exit_code, 0) << help.err;
    EXPECT_NE(help.out.find(b.name), std::string::npos) << help.out;
    EXPECT_NE(help.out.find("--version"), std::string::npos) << help.out;
    const Proc ver = run({b.path, "--version"});
    EXPECT_EQ(ver.exit_code, 0) << ver.err;
    EXPECT_EQ(ver.out, std::string(b.name) + " " + version + "\n");
  }
}

TEST_F(CliConventions, AnUnknownOptionIsAUsageErrorWithStatus2) {
  for (const Binary& b : binaries()) {
    SCOPED_TRACE(b.name);
    const Proc r = run({b.path, "--no-such-option"});
    EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
    EXPECT_FALSE(r.err.empty());
  }
  // Missing arguments are usage errors too.
  EXPECT_EQ(run({NCCOMP_BIN}).exit_code, 2);
  EXPECT_EQ(run({NCCOMP_BIN, "no-such-subcommand"}).exit_code, 2);
  EXPECT_EQ(run({NCCOMP_BIN, "check-config"}).exit_code, 2);
  EXPECT_EQ(run({NCSIM_BIN, "--program", "mould_face"}).exit_code, 2);
  EXPECT_EQ(run({NCSIM_BIN, "--config", "x.toml", "--program", "spiral", "--out", "o"}).exit_code,
            2);
  EXPECT_EQ(run({MODBUS_NC_BIN, "--port", "70000"}).exit_code, 2);
  EXPECT_EQ(run({CAN_NC_BIN, "map.toml"}).exit_code, 2);
  EXPECT_EQ(run({CAN_NC_BIN, "map.toml", "serve", "--count", "many"}).exit_code, 2);
  EXPECT_EQ(run({MODBUS_MAP_BIN}).exit_code, 2);
  EXPECT_EQ(run({NCSIM_PEER_BIN, "--map", "m.toml"}).exit_code, 2);
  EXPECT_EQ(run({NCCOMPD_BIN, "--config"}).exit_code, 2);
  EXPECT_EQ(run({NCCOMP_PAGE_BIN, "--listen", "localhost"}).exit_code, 2);
  EXPECT_EQ(run({NCCOMP_PAGE_BIN, "--poll-interval-s", "0"}).exit_code, 2);
}

TEST_F(CliConventions, EverySubcommandAnswersHelpWithZeroAndAnUnknownOptionWith2) {
  const Proc help = run({NCCOMP_BIN, "--help"});
  ASSERT_EQ(help.exit_code, 0);
  const std::vector<std::string> subs = subcommands(help.out);
  const std::set<std::string> listed(subs.begin(), subs.end());
  for (const char* known : {"status", "check-config", "analyze", "calibrate", "plan", "report",
                            "grind-path", "acknowledge", "warm-start"}) {
    EXPECT_EQ(listed.count(known), 1U) << known << " missing from:\n" << help.out;
  }
  for (const std::string& sub : subs) {
    SCOPED_TRACE(sub);
    const Proc h = run({NCCOMP_BIN, sub, "--help"});
    EXPECT_EQ(h.exit_code, 0) << h.err;
    EXPECT_NE(h.out.find("Usage:"), std::string::npos) << h.out;
    const Proc bad = run({NCCOMP_BIN, sub, "--no-such-option"});
    EXPECT_EQ(bad.exit_code, 2) << bad.out << bad.err;
  }
}

TEST_F(CliConventions, AnInvalidInputFileExitsWith3) {
  // Not TOML at all: every loader must refuse it as input, not as a usage or run-time error.
  const std::string bad = write("bad.toml", "this is = = not toml\n");
  const std::string out = (dir_ / "out").string();
  const std::vector<std::vector<std::string>> cases = {
      {NCCOMPD_BIN, "--config", bad},
      {NCCOMP_ANALYZED_BIN, "--config", bad},
      {NCCOMP_BIN, "check-config", bad},
      {NCCOMP_BIN, "plan", bad},
      {NCCOMP_BIN, "calibrate", "--config", bad, "--script", bad},
      {NCCOMP_BIN, "analyze", "--log", bad, "--config", bad, "--out", out},
      {NCCOMP_BIN, "report", (dir_ / "no-such-result").string()},
      {NCCOMP_BIN, "grind-path", "--profile", (dir_ / "no-such.csv").string(), "--wheel-width-mm",
       "20", "--arc-height-mm", "0"},
      {NCSIM_BIN, "--config", bad, "--program", "mould_face", "--out", out},
      {NCSIM_PEER_BIN, "--map", bad, "--lockstep", (dir_ / "ls.sock").string()},
      {CAN_NC_BIN, bad, "check"},
      {MODBUS_MAP_BIN, bad},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c[0] + " " + c[1]);
    const Proc r = run(c);
    EXPECT_EQ(r.exit_code, 3) << r.out << r.err;
    EXPECT_FALSE(r.err.empty());
  }
}

// nccomp(1) cannot drift from the binary: every subcommand `nccomp --help` lists has its section
// ("## name") in man/nccomp.1.scd, and every long option its `--help` lists is named there.
TEST_F(CliConventions, TheManPageOfNccompDocumentsEverySubcommandAndOption) {
  const std::string page = slurp(std::string(NCCOMP_SOURCE_DIR) + "/man/nccomp.1.scd");
  ASSERT_FALSE(page.empty());
  const std::vector<std::string> subs = subcommands(run({NCCOMP_BIN, "--help"}).out);
  ASSERT_FALSE(subs.empty());
  for (const std::string& sub : subs) {
    SCOPED_TRACE(sub);
    const auto begin = page.find("\n## " + sub + "\n");
    ASSERT_NE(begin, std::string::npos) << "no section '## " << sub << "'";
    const auto end = page.find("\n#", begin + 1);
    const std::string section = page.substr(begin, end - begin);
    // The subcommand's own options and those of its subcommands (nccomp register release ...),
    // which are documented in the same section under their full name.
    const std::string sub_help = run({NCCOMP_BIN, sub, "--help"}).out;
    std::vector<std::pair<std::string, std::string>> helps = {{sub, sub_help}};
    for (const std::string& nested : subcommands(sub_help)) {
      EXPECT_NE(section.find("nccomp " + sub + " " + nested + "*"), std::string::npos)
          << "nccomp " << sub << " " << nested << " is not in nccomp(1)";
      helps.emplace_back(sub + " " + nested, run({NCCOMP_BIN, sub, nested, "--help"}).out);
    }
    const std::regex option(R"(--[a-z][a-z0-9-]*)");
    for (const auto& [what, text] : helps) {
      std::istringstream help(text);
      std::string line;
      while (std::getline(help, line)) {
        if (line.rfind("  ", 0) != 0 || line.find_first_not_of(' ') == std::string::npos ||
            line[line.find_first_not_of(' ')] != '-') {
          continue;  // description lines
        }
        const std::string names = line.substr(0, line.find(' ', line.find_first_not_of(' ')));
        for (std::sregex_iterator it(names.begin(), names.end(), option), e; it != e; ++it) {
          if (it->str() == "--help") {
            continue;
          }
          EXPECT_TRUE(std::regex_search(section, std::regex(it->str() + "([^A-Za-z0-9_-]|$)")))
              << it->str() << " of nccomp " << what << " is not in nccomp(1)";
        }
      }
    }
  }
}

TEST_F(CliConventions, BashCompletionOffersEverySubcommandAndItsOptions) {
  const Proc help = run({NCCOMP_BIN, "--help"});
  const std::vector<std::string> subs = subcommands(help.out);
  ASSERT_FALSE(subs.empty());
  const std::string script = std::string(NCCOMP_SOURCE_DIR) + "/tools/nccomp/nccomp.bash";
  // COMP_WORDS[0] is the command as typed: the built binary here, `nccomp` once installed.
  const auto complete = [&](const std::string& words, int cword) {
    return run({"/bin/bash", "-c",
                "source " + script + " && complete -p nccomp >/dev/null && COMP_WORDS=(" +
                    NCCOMP_BIN + " " + words + ") && COMP_CWORD=" + std::to_string(cword) +
                    " && _nccomp && printf '%s\\n' \"${COMPREPLY[@]}\""});
  };
  Proc all = complete("''", 1);
  ASSERT_EQ(all.exit_code, 0) << all.err;
  std::string expected;
  for (const std::string& s : subs) {
    expected += s + "\n";
  }
  EXPECT_EQ(all.out, expected);
  EXPECT_EQ(complete("st", 1).out, "status\n");
  EXPECT_EQ(complete("--ver", 1).out, "--version\n");
  const Proc opts = complete("status --", 2);
  EXPECT_EQ(opts.out, "--help\n--socket\n--config\n--json\n--metrics\n");
  const Proc profile = complete("grind-path --prof", 2);
  EXPECT_EQ(profile.out, "--profile\n");
}

}  // namespace
