// The client side of nccompd's status socket (client/protocol.hpp): one request per connection,
// the answer read until the daemon closes it, within a deadline. Used by `nccomp status`, the
// operator verbs and `nccomp calibrate --daemon`. Blocking; not real-time.
#pragma once

#include <string>
#include <string_view>

namespace nccomp::client {

/// How long a status request or an operator verb may take (the verbs answer within 3 s) [s].
inline constexpr double kDefaultTimeoutS = 5.0;

/// Sends `request` and a line break to the socket at socket_path and returns the whole answer.
/// Throws std::runtime_error naming the socket when it cannot connect or send, when the answer
/// is not complete within timeout_s of the connection, and when the daemon closes the connection
/// without answering.
[[nodiscard]] std::string query(const std::string& socket_path, std::string_view request,
                                double timeout_s = kDefaultTimeoutS);

}  // namespace nccomp::client
