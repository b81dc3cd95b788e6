// Tests of privilege separation (root only): a forked child switches to another user and groups
// (setgroups, setgid, setuid) and then talks to a Unix socket or runs a program, so that a test
// can be a member of a group or not without creating users or groups on the host.
#pragma once

#include <fcntl.h>
#include <grp.h>
#include <poll.h>
#include <pwd.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstring>
#include <optional>
#include <string>
#include <vector>

extern char** environ;

namespace nccomp::test {

struct Identity {
  uid_t uid{65534};
  gid_t gid{65534};
  std::vector<gid_t> groups;  // supplementary
};

/// The gid of a group of the host (e.g. "users", "adm"), if it has it.
inline std::optional<gid_t> gid_of(const char* name) {
  const group* g = ::getgrnam(name);
  return g != nullptr ? std::optional<gid_t>(g->gr_gid) : std::nullopt;
}

/// The user name of uid as the host's passwd database has it ("?" if none).
inline std::string user_name_of(uid_t uid) {
  const passwd* p = ::getpwuid(uid);
  return p != nullptr ? std::string(p->pw_name) : "?";
}

struct AsResult {
  int exit_code{-1};  // 0: the exchange ran; 10..13: switching identity or connecting failed
  pid_t pid{-1};      // the child's pid (what the peer sees in SO_PEERCRED)
  std::string answer;
};

namespace detail {
// In the child: async-signal-safe calls only (the parent has threads).
inline void become(const Identity& id, const gid_t* groups, std::size_t n) {
  if (::setgroups(n, groups) != 0 || ::setgid(id.gid) != 0 || ::setuid(id.uid) != 0) {
    ::_exit(10);
  }
}
inline int wait_exit(pid_t pid) {
  int st = 0;
  ::waitpid(pid, &st, 0);
  return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}
}  // namespace detail

/// Sends line + "\n" on the Unix socket at path as id, returns what the peer answered (read
/// until it closes, at most 20 s). The caller must be root.
inline AsResult request_as(const Identity& id, const std::string& path, const std::string& line) {
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::strncpy(addr.sun_path, path.c_str(), sizeof(addr.sun_path) - 1);
  const std::string request = line + "\n";
  const std::vector<gid_t> groups = id.groups;
  int out[2];
  if (::pipe2(out, O_CLOEXEC) != 0) return {};
  AsResult r;
  r.pid = ::fork();
  if (r.pid == 0) {
    ::close(out[0]);
    detail::become(id, groups.data(), groups.size());
    const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
    if (fd < 0 || ::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
      ::_exit(11);
    }
    if (::send(fd, request.data(), request.size(), MSG_NOSIGNAL) !=
        static_cast<ssize_t>(request.size())) {
      ::_exit(12);
    }
    ::shutdown(fd, SHUT_WR);
    char buf[4096];
    for (;;) {
      pollfd p{fd, POLLIN, 0};
      if (::poll(&p, 1, 20000) != 1) ::_exit(13);
      const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
      if (n <= 0) break;
      if (::write(out[1], buf, static_cast<std::size_t>(n)) != n) ::_exit(13);
    }
    ::_exit(0);
  }
  ::close(out[1]);
  char buf[4096];
  ssize_t n = 0;
  while ((n = ::read(out[0], buf, sizeof buf)) > 0) {
    r.answer.append(buf, static_cast<std::size_t>(n));
  }
  ::close(out[0]);
  r.exit_code = detail::wait_exit(r.pid);
  return r;
}

/// Runs argv as id with stdout and stderr into the files out and err; returns its exit status
/// (10: switching identity failed, 11: exec failed). The caller must be root.
inline AsResult run_as(const Identity& id, const std::vector<std::string>& argv,
                       const std::string& out, const std::string& err) {
  std::vector<std::string> args = argv;
  std::vector<char*> cargv;
  for (auto& a : args) cargv.push_back(a.data());
  cargv.push_back(nullptr);
  const std::vector<gid_t> groups = id.groups;
  AsResult r;
  r.pid = ::fork();
  if (r.pid == 0) {
    const int o = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int e = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (o < 0 || e < 0 || ::dup2(o, 1) < 0 || ::dup2(e, 2) < 0) ::_exit(11);
    detail::become(id, groups.data(), groups.size());
    ::execve(cargv[0], cargv.data(), environ);
    ::_exit(11);
  }
  r.exit_code = detail::wait_exit(r.pid);
  return r;
}

}  // namespace nccomp::test
