// The client side of `nccomp calibrate --daemon SOCKET`: one "calibrate ..." request per
// connection on nccompd's status socket (daemon/command.hpp), the answer read to EOF. Not
// real-time.
#pragma once

#include <string>

namespace nccomp::tools::calibrate {

/// Sends "calibrate <command>\n" and returns the daemon's answer. Throws std::runtime_error
/// naming the socket when it cannot connect or the daemon does not answer within timeout_s.
std::string daemon_request(const std::string& socket_path, const std::string& command,
                           double timeout_s = 15.0);

}  // namespace nccomp::tools::calibrate
