#include "tools/page/peer_identity.hpp"

#include <arpa/inet.h>
#include <grp.h>
#include <pwd.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <vector>

namespace nccomp::page {

namespace {

// The kernel prints an endpoint as the raw __be32 in %08X and the port in %04X.
std::optional<std::string> kernel_form(const Endpoint& e) {
  in_addr a{};
  if (e.port < 0 || e.port > 65535 || ::inet_pton(AF_INET, e.address.c_str(), &a) != 1) {
    return std::nullopt;
  }
  char buf[16];
  std::snprintf(buf, sizeof buf, "%08X:%04X", a.s_addr, static_cast<unsigned>(e.port));
  return std::string(buf);
}

bool equal_nocase(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return std::toupper(static_cast<unsigned char>(x)) ==
                  std::toupper(static_cast<unsigned char>(y));
         });
}

std::string user_label(const std::string& name, uid_t uid) {
  return (name.empty() ? std::string("?") : name) + " (uid " + std::to_string(uid) + ")";
}

}  // namespace

bool is_loopback_ipv4(std::string_view address) {
  in_addr a{};
  const std::string s(address);
  return ::inet_pton(AF_INET, s.c_str(), &a) == 1 && (ntohl(a.s_addr) >> 24) == 127;
}

std::optional<uid_t> tcp_socket_uid(std::string_view proc_net_tcp, const Endpoint& local,
                                    const Endpoint& remote) {
  const auto want_local = kernel_form(local);
  const auto want_remote = kernel_form(remote);
  if (!want_local || !want_remote) return std::nullopt;
  std::istringstream in{std::string(proc_net_tcp)};
  std::string line;
  std::getline(in, line);  // the header
  while (std::getline(in, line)) {
    // sl local_address rem_address st tx_queue:rx_queue tr:tm->when retrnsmt uid ...
    std::istringstream f(line);
    std::string sl, loc, rem, st, queues, timer, retr, uid_text;
    if (!(f >> sl >> loc >> rem >> st >> queues >> timer >> retr >> uid_text)) continue;
    if (!equal_nocase(loc, *want_local) || !equal_nocase(rem, *want_remote)) continue;
    if (uid_text.empty() || uid_text.size() > 10 ||
        !std::all_of(uid_text.begin(), uid_text.end(),
                     [](char c) { return c >= '0' && c <= '9'; })) {
      return std::nullopt;
    }
    const unsigned long long uid = std::stoull(uid_text);
    if (uid > 0xFFFFFFFEULL) return std::nullopt;  // (uid_t)-1 is no user
    return static_cast<uid_t>(uid);
  }
  return std::nullopt;
}

std::optional<uid_t> loopback_client_uid(const Endpoint& client, const Endpoint& server) {
  if (!is_loopback_ipv4(client.address)) return std::nullopt;
  std::ifstream f("/proc/net/tcp");
  if (!f) return std::nullopt;
  std::ostringstream text;
  text << f.rdbuf();
  // The client's socket: its local end is the client's address, its remote end the page's.
  return tcp_socket_uid(text.str(), client, server);
}

Permission may_change_machine(uid_t uid, const std::string& admin_group) {
  Permission p;
  std::vector<char> buf(16384);
  passwd pw{};
  passwd* pw_found = nullptr;
  ::getpwuid_r(uid, &pw, buf.data(), buf.size(), &pw_found);
  const std::string name = pw_found != nullptr ? std::string(pw.pw_name) : std::string();
  p.user = user_label(name, uid);
  if (uid == 0) {
    p.allowed = true;
    return p;
  }
  if (pw_found == nullptr) {
    p.why = "uid " + std::to_string(uid) + " has no entry in the user database";
    return p;
  }
  std::vector<char> gbuf(16384);
  group gr{};
  group* gr_found = nullptr;
  ::getgrnam_r(admin_group.c_str(), &gr, gbuf.data(), gbuf.size(), &gr_found);
  if (gr_found == nullptr) {
    p.why = "group '" + admin_group + "' (--admin-group) does not exist";
    return p;
  }
  const gid_t admin_gid = gr.gr_gid;
  int n = 64;
  std::vector<gid_t> groups(static_cast<std::size_t>(n));
  if (::getgrouplist(pw.pw_name, pw.pw_gid, groups.data(), &n) < 0) {
    groups.resize(static_cast<std::size_t>(n));
    ::getgrouplist(pw.pw_name, pw.pw_gid, groups.data(), &n);
  }
  groups.resize(static_cast<std::size_t>(std::max(n, 0)));
  if (std::find(groups.begin(), groups.end(), admin_gid) != groups.end()) {
    p.allowed = true;
    return p;
  }
  p.why = p.user + " is not root and not in group '" + admin_group + "' (--admin-group)";
  return p;
}

}  // namespace nccomp::page
