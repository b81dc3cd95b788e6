// [can] restart = "daemon" needs CAP_NET_ADMIN and AF_NETLINK sockets (issue 17, finding 9). The
// shipped unit allows neither; without them the driver refuses to start, naming the key and the
// drop-in, instead of finding out at the first bus-off (which would then never end). Each case
// runs in a forked child that takes the right away from itself the way the unit does: capset()
// drops CAP_NET_ADMIN (CapabilityBoundingSet= empty, no ambient capability), a seccomp filter
// makes socket(AF_NETLINK) fail with EAFNOSUPPORT (what RestrictAddressFamilies= installs).
#include <gtest/gtest.h>
#include <linux/audit.h>
#include <linux/capability.h>
#include <linux/filter.h>
#include <linux/seccomp.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstddef>
#include <cstring>
#include <functional>
#include <stdexcept>
#include <string>

#include "drivers/can/can_bus.hpp"
#include "drivers/can/can_config.hpp"

namespace nccomp::drivers::can {
namespace {

/// fn's result (or "throws: " + what()) computed in a forked child, so that what the child
/// takes away from itself stays there.
std::string in_child(const std::function<std::string()>& fn) {
  int p[2];
  if (::pipe(p) != 0) {
    return "pipe failed";
  }
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(p[0]);
    std::string out;
    try {
      out = fn();
    } catch (const std::exception& e) {
      out = std::string("throws: ") + e.what();
    }
    (void)!::write(p[1], out.data(), out.size());
    ::_exit(0);
  }
  ::close(p[1]);
  std::string out;
  std::array<char, 512> buf{};
  for (ssize_t n = 0; (n = ::read(p[0], buf.data(), buf.size())) > 0;) {
    out.append(buf.data(), static_cast<std::size_t>(n));
  }
  ::close(p[0]);
  int status = 0;
  ::waitpid(pid, &status, 0);
  return out;
}

bool has_net_admin() {
  __user_cap_header_struct h{_LINUX_CAPABILITY_VERSION_3, 0};
  std::array<__user_cap_data_struct, _LINUX_CAPABILITY_U32S_3> d{};
  return ::syscall(SYS_capget, &h, d.data()) == 0 &&
         (d[CAP_TO_INDEX(CAP_NET_ADMIN)].effective & CAP_TO_MASK(CAP_NET_ADMIN)) != 0;
}

/// In the child: CAP_NET_ADMIN out of the effective and permitted sets.
void drop_net_admin() {
  __user_cap_header_struct h{_LINUX_CAPABILITY_VERSION_3, 0};
  std::array<__user_cap_data_struct, _LINUX_CAPABILITY_U32S_3> d{};
  if (::syscall(SYS_capget, &h, d.data()) != 0) {
    throw std::runtime_error("capget failed");
  }
  d[CAP_TO_INDEX(CAP_NET_ADMIN)].effective &= ~CAP_TO_MASK(CAP_NET_ADMIN);
  d[CAP_TO_INDEX(CAP_NET_ADMIN)].permitted &= ~CAP_TO_MASK(CAP_NET_ADMIN);
  if (::syscall(SYS_capset, &h, d.data()) != 0) {
    throw std::runtime_error("capset failed");
  }
}

sock_filter stmt(std::uint16_t code, std::uint32_t k) { return sock_filter{code, 0, 0, k}; }
sock_filter jump(std::uint16_t code, std::uint32_t k, std::uint8_t jt, std::uint8_t jf) {
  return sock_filter{code, jt, jf, k};
}

/// In the child: socket(AF_NETLINK, ...) fails with EAFNOSUPPORT from now on.
void deny_netlink() {
#if defined(__x86_64__)
  constexpr std::uint32_t kArch = AUDIT_ARCH_X86_64;
#elif defined(__aarch64__)
  constexpr std::uint32_t kArch = AUDIT_ARCH_AARCH64;
#else
  throw std::runtime_error("no seccomp arch for this CPU");
#endif
  const auto at = [](std::size_t off) { return static_cast<std::uint32_t>(off); };
  std::array<sock_filter, 9> prog{
      stmt(BPF_LD | BPF_W | BPF_ABS, at(offsetof(seccomp_data, arch))),
      jump(BPF_JMP | BPF_JEQ | BPF_K, kArch, 1, 0),
      stmt(BPF_RET | BPF_K, SECCOMP_RET_ALLOW),
      stmt(BPF_LD | BPF_W | BPF_ABS, at(offsetof(seccomp_data, nr))),
      jump(BPF_JMP | BPF_JEQ | BPF_K, static_cast<std::uint32_t>(__NR_socket), 0, 3),
      stmt(BPF_LD | BPF_W | BPF_ABS, at(offsetof(seccomp_data, args))),  // domain, low word
      jump(BPF_JMP | BPF_JEQ | BPF_K, AF_NETLINK, 0, 1),
      stmt(BPF_RET | BPF_K, SECCOMP_RET_ERRNO | (EAFNOSUPPORT & SECCOMP_RET_DATA)),
      stmt(BPF_RET | BPF_K, SECCOMP_RET_ALLOW),
  };
  sock_fprog fprog{static_cast<unsigned short>(prog.size()), prog.data()};
  if (::prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0 ||
      ::prctl(PR_SET_SECCOMP, SECCOMP_MODE_FILTER, &fprog) != 0) {
    throw std::runtime_error("seccomp filter refused");
  }
}

/// start()'s error for [can] on an interface that does not exist, with `restart`.
std::string start_error(const std::string& restart) {
  CanBus bus(parse_can_config("[can]\ninterface = \"nccompnone0\"\nrestart = \"" + restart + "\"\n",
                              "test.toml"));
  try {
    bus.start();
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  bus.stop();
  return "(started)";
}

// GIVEN a process without CAP_NET_ADMIN (the shipped unit), WHEN restart = "daemon" is started,
// THEN it is refused, naming the key, what is missing and the drop-in.
TEST(CanRestartPermission, WithoutCapNetAdminDaemonRestartIsRefusedNamingTheDropIn) {
  EXPECT_EQ(in_child([] {
              drop_net_admin();
              return restart_permission_problem();
            }),
            "no CAP_NET_ADMIN in its effective capabilities");
  const std::string e = in_child([] {
    drop_net_admin();
    return start_error("daemon");
  });
  EXPECT_EQ(e.rfind("can: nccompnone0: can.restart = \"daemon\" needs CAP_NET_ADMIN and an "
                    "AF_NETLINK socket",
                    0),
            0U)
      << e;
  EXPECT_NE(e.find("this process has no CAP_NET_ADMIN in its effective capabilities."),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("drop-in nccompd-can-restart.conf as "
                   "/etc/systemd/system/nccompd.service.d/can-restart.conf"),
            std::string::npos)
      << e;
}

// GIVEN a process whose AF_NETLINK sockets are refused (RestrictAddressFamilies= without it),
// THEN the same refusal says so.
TEST(CanRestartPermission, WithoutNetlinkSocketsDaemonRestartIsRefused) {
  if (!has_net_admin()) {
    GTEST_SKIP() << "needs CAP_NET_ADMIN to tell the two causes apart";
  }
  const std::string want =
      "AF_NETLINK sockets refused: " + std::string(std::strerror(EAFNOSUPPORT));
  EXPECT_EQ(in_child([] {
              deny_netlink();
              return restart_permission_problem();
            }),
            want);
  const std::string e = in_child([] {
    deny_netlink();
    return start_error("daemon");
  });
  EXPECT_NE(e.find("this process has " + want + "."), std::string::npos) << e;
  EXPECT_EQ(in_child([] {
              drop_net_admin();
              deny_netlink();
              return restart_permission_problem();
            }),
            "no CAP_NET_ADMIN in its effective capabilities; " + want);
}

// GIVEN both rights (root, or the unit with the drop-in), THEN nothing is missing and start()
// goes on to the interface; restart = "kernel" needs neither right.
TEST(CanRestartPermission, WithBothRightsOrKernelRestartNothingIsRefused) {
  if (has_net_admin()) {
    EXPECT_EQ(restart_permission_problem(), "");
    const std::string e = start_error("daemon");
    EXPECT_EQ(e.find("can.restart"), std::string::npos) << e;
  }
  const std::string k = in_child([] {
    drop_net_admin();
    deny_netlink();
    return start_error("kernel");
  });
  EXPECT_EQ(k.find("can.restart"), std::string::npos) << k;
  EXPECT_NE(k, "(started)");
}

}  // namespace
}  // namespace nccomp::drivers::can
