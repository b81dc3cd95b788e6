// Who opened a loopback TCP connection (tools/page/peer_identity.hpp): the kernel's
// /proc/net/tcp table, a real connection made by another user, and the admin-group rule.
#include "tools/page/peer_identity.hpp"

#include <arpa/inet.h>
#include <grp.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <pwd.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <string>

namespace {

using nccomp::page::Endpoint;
using nccomp::page::is_loopback_ipv4;
using nccomp::page::loopback_client_uid;
using nccomp::page::may_change_machine;
using nccomp::page::tcp_socket_uid;

// Lines as Linux 6.1 prints them: the page listening on 127.0.0.1:8470 (0x2116), its end of a
// connection (uid 998) and the browser's end from port 54312 (0xD428, uid 1000).
constexpr const char* kTable =
    "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout "
    "inode\n"
    "   0: 0100007F:2116 00000000:0000 0A 00000000:00000000 00:00000000 00000000   998        0 "
    "6529632 1 000000008bf976d0 100 0 0 10 0\n"
    "   1: 0100007F:2116 0100007F:D428 01 00000000:00000000 00:00000000 00000000   998        0 "
    "6529669 1 00000000165d7532 20 4 1 10 -1\n"
    "   2: 0100007F:D428 0100007F:2116 01 00000000:00000000 00:00000000 00000000  1000        0 "
    "6529668 1 000000001cabbd4d 20 4 30 10 -1\n";

TEST(PeerIdentity, TheClientsEndOfTheConnectionNamesItsUser) {
  const Endpoint browser{"127.0.0.1", 54312};
  const Endpoint page{"127.0.0.1", 8470};
  EXPECT_EQ(tcp_socket_uid(kTable, browser, page), std::optional<uid_t>(1000));
  // The page's own end of the same connection is the page's user.
  EXPECT_EQ(tcp_socket_uid(kTable, page, browser), std::optional<uid_t>(998));
  EXPECT_EQ(tcp_socket_uid(kTable, Endpoint{"127.0.0.1", 54313}, page), std::nullopt);
  EXPECT_EQ(tcp_socket_uid(kTable, Endpoint{"127.0.0.2", 54312}, page), std::nullopt);
  EXPECT_EQ(tcp_socket_uid(kTable, Endpoint{"localhost", 54312}, page), std::nullopt);
  EXPECT_EQ(tcp_socket_uid(kTable, Endpoint{"127.0.0.1", 70000}, page), std::nullopt);
}

TEST(PeerIdentity, ATableNotInTheKernelsFormatNamesNobody) {
  const Endpoint browser{"127.0.0.1", 54312};
  const Endpoint page{"127.0.0.1", 8470};
  EXPECT_EQ(tcp_socket_uid("", browser, page), std::nullopt);
  EXPECT_EQ(tcp_socket_uid("header\n   2: 0100007F:D428 0100007F:2116 01\n", browser, page),
            std::nullopt);
  EXPECT_EQ(tcp_socket_uid("header\n   2: 0100007F:D428 0100007F:2116 01 0:0 0:0 0 -5 0 1\n",
                           browser, page),
            std::nullopt);
  EXPECT_EQ(tcp_socket_uid("h\n 2: 0100007F:D428 0100007F:2116 01 0:0 0:0 0 4294967295 0 1\n",
                           browser, page),
            std::nullopt);
}

TEST(PeerIdentity, LoopbackIsOneHundredTwentySevenSlashEight) {
  EXPECT_TRUE(is_loopback_ipv4("127.0.0.1"));
  EXPECT_TRUE(is_loopback_ipv4("127.1.2.3"));
  EXPECT_FALSE(is_loopback_ipv4("128.0.0.1"));
  EXPECT_FALSE(is_loopback_ipv4("10.0.0.1"));
  EXPECT_FALSE(is_loopback_ipv4("0.0.0.0"));
  EXPECT_FALSE(is_loopback_ipv4("::1"));
  EXPECT_FALSE(is_loopback_ipv4(""));
}

// GIVEN a listener on 127.0.0.1, WHEN a process of another user (nobody, when the test runs as
// root; else this user) connects, THEN the uid found for the connection is that user's.
TEST(PeerIdentity, ARealConnectionNamesTheUserOfTheConnectingProcess) {
  const int listener = ::socket(AF_INET, SOCK_STREAM, 0);
  ASSERT_GE(listener, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ASSERT_EQ(::bind(listener, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  ASSERT_EQ(::listen(listener, 1), 0);
  socklen_t len = sizeof addr;
  ASSERT_EQ(::getsockname(listener, reinterpret_cast<sockaddr*>(&addr), &len), 0);
  const uid_t want = ::geteuid() == 0 ? 65534 : ::geteuid();
  int hold[2];
  ASSERT_EQ(::pipe(hold), 0);
  const pid_t child = ::fork();
  if (child == 0) {
    ::close(hold[1]);
    if (::geteuid() == 0 &&
        (::setgroups(0, nullptr) != 0 || ::setgid(65534) != 0 || ::setuid(65534) != 0)) {
      ::_exit(10);
    }
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    if (fd < 0 || ::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
      ::_exit(11);
    }
    char c = 0;
    (void)!::read(hold[0], &c, 1);  // keeps the connection until the parent looked
    ::_exit(0);
  }
  ::close(hold[0]);
  sockaddr_in peer{};
  len = sizeof peer;
  const int conn = ::accept(listener, reinterpret_cast<sockaddr*>(&peer), &len);
  ASSERT_GE(conn, 0);
  const Endpoint client{"127.0.0.1", ntohs(peer.sin_port)};
  const Endpoint server{"127.0.0.1", ntohs(addr.sin_port)};
  const auto uid = loopback_client_uid(client, server);
  ::close(hold[1]);
  int st = 0;
  ::waitpid(child, &st, 0);
  ::close(conn);
  ::close(listener);
  ASSERT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0) << st;
  EXPECT_EQ(uid, std::optional<uid_t>(want));
  // Not a loopback client: nobody can be named.
  EXPECT_EQ(loopback_client_uid(Endpoint{"10.1.2.3", client.port}, server), std::nullopt);
}

TEST(PeerIdentity, RootAndMembersOfTheAdminGroupMayChangeTheMachine) {
  const auto root = may_change_machine(0, "no-such-group-xyz");
  EXPECT_TRUE(root.allowed);
  EXPECT_EQ(root.user, "root (uid 0)");

  const passwd* nobody = ::getpwuid(65534);
  ASSERT_NE(nobody, nullptr);
  const group* primary = ::getgrgid(nobody->pw_gid);
  ASSERT_NE(primary, nullptr);
  // The primary group counts: nobody is a member of its own group (nogroup on Debian).
  EXPECT_TRUE(may_change_machine(65534, primary->gr_name).allowed);
  const auto refused = may_change_machine(65534, "root");
  EXPECT_FALSE(refused.allowed);
  EXPECT_EQ(refused.why, std::string(nobody->pw_name) +
                             " (uid 65534) is not root and not in group 'root' (--admin-group)");
  const auto no_group = may_change_machine(65534, "no-such-group-xyz");
  EXPECT_FALSE(no_group.allowed);
  EXPECT_EQ(no_group.why, "group 'no-such-group-xyz' (--admin-group) does not exist");
  const auto no_user = may_change_machine(4000000000U, primary->gr_name);
  EXPECT_FALSE(no_user.allowed);
  EXPECT_EQ(no_user.why, "uid 4000000000 has no entry in the user database");
}

}  // namespace
