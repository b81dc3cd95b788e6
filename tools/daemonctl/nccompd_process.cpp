#include "tools/daemonctl/nccompd_process.hpp"

#include <fcntl.h>
#include <poll.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>

#include "tools/nccomp/command.hpp"

extern char** environ;

namespace nccomp::tools {

namespace {

namespace fs = std::filesystem;

bool executable_file(const fs::path& p) {
  struct stat st {};
  return ::stat(p.c_str(), &st) == 0 && S_ISREG(st.st_mode) && ::access(p.c_str(), X_OK) == 0;
}

// Both ends close on exec: the child gets its copies through posix_spawn's dup2 only.
std::array<int, 2> make_pipe() {
  std::array<int, 2> fds{-1, -1};
  if (::pipe2(fds.data(), O_CLOEXEC) != 0) {
    throw CommandError(kExitFailure, std::string("pipe: ") + std::strerror(errno));
  }
  return fds;
}

}  // namespace

std::string find_nccompd() {
  if (const char* e = std::getenv("NCCOMPD"); e != nullptr && *e != '\0') {
    if (!executable_file(e)) {
      throw CommandError(kExitFailure, std::string("NCCOMPD=") + e + " is not an executable file");
    }
    return e;
  }
  std::vector<fs::path> candidates;
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    const fs::path dir = self.parent_path();
    candidates = {dir / "nccompd", dir / ".." / "sbin" / "nccompd",
                  dir / ".." / "daemon" / "nccompd"};
  }
  if (const char* path = std::getenv("PATH"); path != nullptr) {
    const std::string_view p(path);
    for (std::size_t b = 0; b <= p.size();) {
      const std::size_t e = std::min(p.find(':', b), p.size());
      if (e > b) candidates.push_back(fs::path(std::string(p.substr(b, e - b))) / "nccompd");
      b = e + 1;
    }
  }
  candidates.emplace_back("/usr/sbin/nccompd");
  for (const auto& c : candidates) {
    if (executable_file(c)) return c.lexically_normal().string();
  }
  throw CommandError(kExitFailure,
                     "cannot find nccompd (beside nccomp, in PATH or in /usr/sbin): set NCCOMPD "
                     "to its path");
}

ProgramRun run_program(const std::string& program, const std::vector<std::string>& args) {
  const auto out = make_pipe();
  const auto err = make_pipe();
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, out[1], STDOUT_FILENO);
  posix_spawn_file_actions_adddup2(&actions, err[1], STDERR_FILENO);
  std::vector<std::string> storage{program};
  storage.insert(storage.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : storage) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = -1;
  const int rc = ::posix_spawn(&pid, program.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(out[1]);
  ::close(err[1]);
  if (rc != 0) {
    ::close(out[0]);
    ::close(err[0]);
    throw CommandError(kExitFailure, "cannot run " + program + ": " + std::strerror(rc));
  }
  ProgramRun run;
  // Both pipes until both are closed: a child that fills one while we wait on the other would
  // block forever.
  std::array<pollfd, 2> fds{pollfd{out[0], POLLIN, 0}, pollfd{err[0], POLLIN, 0}};
  std::array<std::string*, 2> sinks{&run.out, &run.err};
  int open = 2;
  char buf[4096];
  while (open > 0) {
    if (::poll(fds.data(), fds.size(), -1) < 0) {
      if (errno == EINTR) continue;
      break;
    }
    for (std::size_t i = 0; i < fds.size(); ++i) {
      if (fds[i].fd < 0 || fds[i].revents == 0) continue;
      const ssize_t n = ::read(fds[i].fd, buf, sizeof buf);
      if (n > 0) {
        sinks[i]->append(buf, static_cast<std::size_t>(n));
      } else if (n == 0 || errno != EINTR) {
        ::close(fds[i].fd);
        fds[i].fd = -1;
        --open;
      }
    }
  }
  for (const auto& f : fds) {
    if (f.fd >= 0) ::close(f.fd);
  }
  int st = 0;
  while (::waitpid(pid, &st, 0) < 0 && errno == EINTR) {
  }
  run.exit_code = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  return run;
}

std::string run_nccompd_config_flag(const std::string& file, const std::string& flag) {
  const std::string nccompd = find_nccompd();
  ProgramRun r = run_program(nccompd, {"--config", file, flag});
  if (r.exit_code == 0) {
    std::cerr << r.err;
    return r.out;
  }
  // The errors as they are, the summary line as nccomp's own error.
  std::string summary;
  constexpr std::string_view kPrefix = "nccompd: ";
  std::string& e = r.err;
  while (!e.empty() && e.back() == '\n') e.pop_back();
  const std::size_t last = e.rfind('\n') == std::string::npos ? 0 : e.rfind('\n') + 1;
  if (r.exit_code == kExitInvalidInput && std::string_view(e).substr(last).starts_with(kPrefix)) {
    summary = e.substr(last + kPrefix.size());
    e.erase(last);
  } else if (!e.empty()) {
    e += '\n';
  }
  std::cout << r.out;
  std::cerr << e;
  if (!summary.empty()) {
    throw CommandError(kExitInvalidInput, summary);
  }
  throw CommandError(kExitFailure,
                     nccompd + " " + flag + " exited with status " + std::to_string(r.exit_code));
}

}  // namespace nccomp::tools
