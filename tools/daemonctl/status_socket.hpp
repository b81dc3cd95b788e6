// The status socket of a running nccompd, as `nccomp status`, `warm-start`, `acknowledge` and
// `register` find it: --socket PATH, else the socket of --config FILE (nccompd reads its
// configuration: `nccompd --config FILE --print-status-socket`), else /run/nccompd/status.sock;
// and an operator command's request and answer on it (client/). Not real-time.
#pragma once

#include <string>

namespace nccomp::tools {

/// Throws CommandError(kExitInvalidInput) when the configuration cannot be read.
[[nodiscard]] std::string status_socket_path(const std::string& socket, const std::string& config);

/// Sends an operator command's request line to the daemon at path and returns its "ok ..."
/// answer. Throws CommandError(kExitFailure) when the daemon cannot be reached or does not
/// answer, CommandError(kExitInvalidInput) when it refuses ("error: <why>", a malformed or not
/// permitted command: the message is <why>).
[[nodiscard]] std::string operator_command(const std::string& path, const std::string& request);

}  // namespace nccomp::tools
