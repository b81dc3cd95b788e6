// Who is on the other end of an HTTP connection to nccomp-page (docs/operator-page.md,
// "Security"). TCP carries no credentials, but on this host the kernel records the uid that
// created each socket: the client's own end of a loopback connection is a line of
// /proc/net/tcp whose local address is the client's and whose remote address is the page's.
// Not real-time; blocking file reads and user database calls.
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace nccomp::page {

/// An IPv4 TCP endpoint as dotted quad and port.
struct Endpoint {
  std::string address;
  int port{-1};
};

/// True for 127.0.0.0/8: a connection from there was made on this host.
[[nodiscard]] bool is_loopback_ipv4(std::string_view address);

/// The uid owning the socket whose local end is `local` and remote end is `remote`, read from
/// the text of /proc/net/tcp (`proc_net_tcp`). nullopt when no line matches or the text is not
/// in the kernel's format.
[[nodiscard]] std::optional<uid_t> tcp_socket_uid(std::string_view proc_net_tcp,
                                                  const Endpoint& local, const Endpoint& remote);

/// The uid of the process that opened the client's end of the connection client -> server on
/// this host (reads /proc/net/tcp); nullopt for a client on another host or when unknown.
[[nodiscard]] std::optional<uid_t> loopback_client_uid(const Endpoint& client,
                                                       const Endpoint& server);

/// Whether a user may change the machine through the page: the daemon's rule for its status
/// socket ([status] admin_group): root, or a member of the admin group.
struct Permission {
  bool allowed{false};
  std::string user;  // "alice (uid 1000)"
  std::string why;   // refused: the reason, for the page and the log
};

/// Judges uid against admin_group with the group database (getgrouplist): the primary group
/// counts as membership too.
[[nodiscard]] Permission may_change_machine(uid_t uid, const std::string& admin_group);

}  // namespace nccomp::page
