// Any bytes as /proc/net/tcp: the lookup ends in a uid or nullopt, never a crash, and never
// names (uid_t)-1 (no user). A uid found for one connection must be found again for it.
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "tools/page/peer_identity.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const nccomp::page::Endpoint browser{"127.0.0.1", 54312};
  const nccomp::page::Endpoint page{"127.0.0.1", 8470};
  const auto uid = nccomp::page::tcp_socket_uid(text, browser, page);
  if (uid && *uid == static_cast<uid_t>(-1)) std::abort();
  if (uid != nccomp::page::tcp_socket_uid(text, browser, page)) std::abort();
  (void)nccomp::page::tcp_socket_uid(text, page, browser);
  return 0;
}
