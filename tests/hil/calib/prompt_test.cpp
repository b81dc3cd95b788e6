// `nccomp calibrate` as the operator runs it: the prompt on a terminal (a pty: the isatty
// branch, a wrong line retyped), and against a running nccompd (--daemon: a script with await,
// a pipe with --interactive, facet chords from a device export, a bad export refused at its line).
#include <gtest/gtest.h>
#include <poll.h>
#include <pty.h>

#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "core/calib/state.hpp"
#include "tests/hil/calib/daemon_process.hpp"

namespace nccomp::test::calib {
namespace {

struct Output {
  int status{-1};
  std::string text;
};

// Runs nccomp with args on a pseudo-terminal, typing `input` line by line after each prompt.
Output run_on_pty(const std::vector<std::string>& args, const std::vector<std::string>& input) {
  int master = -1;
  const pid_t pid = forkpty(&master, nullptr, nullptr, nullptr);
  if (pid == 0) {
    std::vector<char*> argv;
    std::vector<std::string> a = args;
    for (auto& s : a) argv.push_back(s.data());
    argv.push_back(nullptr);
    ::execv(NCCOMP_BIN, argv.data());
    ::_exit(127);
  }
  Output out;
  std::size_t next = 0;
  const auto end = std::chrono::steady_clock::now() + 30s;
  char buf[4096];
  while (std::chrono::steady_clock::now() < end) {
    pollfd p{master, POLLIN, 0};
    if (::poll(&p, 1, 100) > 0) {
      const ssize_t n = ::read(master, buf, sizeof buf);
      if (n <= 0) break;  // EIO once the child closed the terminal
      out.text.append(buf, static_cast<std::size_t>(n));
    }
    // Type the next line once a new prompt appeared.
    const auto prompts = [&] {
      std::size_t c = 0;
      for (auto pos = out.text.find("calibrate> "); pos != std::string::npos;
           pos = out.text.find("calibrate> ", pos + 1)) {
        ++c;
      }
      return c;
    }();
    if (next < input.size() && prompts > next) {
      const std::string l = input[next++] + "\n";
      (void)::write(master, l.data(), l.size());
    }
  }
  int st = 0;
  ::waitpid(pid, &st, 0);
  ::close(master);
  out.status = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  return out;
}

TEST(CalibratePrompt, TerminalPromptShowsTheNextStepAndLetsAWrongLineBeRetyped) {
  TempDir dir;
  const std::string ex = std::string(NCCOMP_SOURCE_DIR) + "/tools/calibrate/examples/";
  const std::string state = (dir.path / "p.state").string();
  const auto out = run_on_pty({"nccomp", "calibrate", "--config", ex + "machine.toml", "--state",
                               state, "--epoch", "1795766400"},
                              {"begin", "touch reference q + 1.0",
                               "touch reference x + lateral 247.0276", "bogus", "quit"});
  EXPECT_EQ(out.status, 0) << out.text;
  // The first prompt, then the reference-touch hint with the progress after a valid touch.
  EXPECT_NE(
      out.text.find("-- not calibrated: 'begin' starts an initial calibration\r\ncalibrate> "),
      std::string::npos)
      << out.text;
  EXPECT_NE(out.text.find("error: line 2, column 17: axis must be x, y or z, got 'q'"),
            std::string::npos)
      << out.text;
  EXPECT_NE(out.text.find("-- touch the reference disk with the reference probe (X lateral 1/2, "
                          "X axial 0/2, Y 0/2, Z 0/2)"),
            std::string::npos)
      << out.text;
  EXPECT_NE(out.text.find("error: line 4, column 1: unknown command 'bogus' (try 'help')"),
            std::string::npos);
  EXPECT_NE(out.text.find("saved state " + state), std::string::npos);
  std::ifstream in(state);
  std::ostringstream s;
  s << in.rdbuf();
  EXPECT_EQ(core::calib::from_text(s.str()).phase, core::calib::Phase::kReferenceTouches);
}

TEST(CalibratePrompt, DaemonScriptAndInteractiveModes) {
  TempDir dir;
  dir.write("nccompd.toml", config_text());
  Daemon d(dir.path);
  d.start();
  SimMachine m(test_config(), test_errors(), 0.2, 0.2, 0.1, 53);
  // A script against the daemon: begin, the reference touches, await the test grind.
  std::string script = "begin  # start\n";
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) script += touch_line(m.reference_touch(slot, 1, 0)) + "\n";
  }
  script += "await test-grind-lateral 10\nstatus\n";
  dir.write("s.calib", script);
  const std::string cmd = std::string(NCCOMP_BIN) + " calibrate --daemon " + d.socket() +
                          " --script " + (dir.path / "s.calib").string() + " 2>&1";
  std::string text;
  int status = -1;
  {
    FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    char buf[4096];
    std::size_t n = 0;
    while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) text.append(buf, n);
    status = WEXITSTATUS(::pclose(p));
  }
  EXPECT_EQ(status, 0) << text;
  EXPECT_NE(text.find("initial calibration started"), std::string::npos) << text;
  EXPECT_NE(text.find("reference touches: dx lateral"), std::string::npos) << text;
  EXPECT_NE(text.find("phase test-grind-lateral"), std::string::npos) << text;
  EXPECT_NE(text.find("-- grind the blank from +X and -X with dx"), std::string::npos) << text;
  // A device export with the chords of the first grind: a bad one is refused at its line, a good
  // one is entered.
  const auto now = d.ask("");
  ASSERT_TRUE(now);
  const double dx = dx_of(*now);
  const auto [p, q] = m.test_grind(false, dx);
  char csv[256];
  std::snprintf(csv, sizeof csv,
                "# facet microscope "
                "export\nface;chord_plus_mm;chord_minus_mm;operator\nlateral;%.6f;%.6f;mk\n",
                p, q);
  dir.write("device.csv", csv);
  dir.write("bad.csv", "face,chord_plus_mm,chord_minus_mm\nlateral,1.9,-2\n");
  // Interactive over a pipe: every command answered, a refused one does not end the session.
  const std::string cmd2 = "printf 'facets-file " + (dir.path / "bad.csv").string() +
                           "\\nfacets-file " + (dir.path / "device.csv").string() +
                           "\\nquit\\n' | " + std::string(NCCOMP_BIN) + " calibrate --daemon " +
                           d.socket() + " --interactive 2>&1";
  text.clear();
  {
    FILE* pp = ::popen(cmd2.c_str(), "r");
    ASSERT_NE(pp, nullptr);
    char buf[4096];
    std::size_t n = 0;
    while ((n = std::fread(buf, 1, sizeof buf, pp)) > 0) text.append(buf, n);
    status = WEXITSTATUS(::pclose(pp));
  }
  EXPECT_EQ(status, 0) << text;
  EXPECT_NE(text.find("bad.csv:2: chord_minus_mm must be in (0, 1000] mm, got '-2'"),
            std::string::npos)
      << text;
  EXPECT_NE(text.find("device.csv line 3:"), std::string::npos) << text;
  EXPECT_NE(text.find("facets lateral: c+"), std::string::npos) << text;
  EXPECT_NE(text.find("1 command(s) refused"), std::string::npos) << text;
  const auto a = d.ask("");
  EXPECT_TRUE(a->rfind("ok test-grind-lateral", 0) == 0 ||
              a->rfind("ok test-grind-end-face", 0) == 0)
      << *a;
  EXPECT_EQ(d.stop(), 0);
}

}  // namespace
}  // namespace nccomp::test::calib
