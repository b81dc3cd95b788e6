// The status-socket protocol of nccompd (docs/daemon.md, "nccomp status" and "Operator commands"),
// shared by the daemon's status server and verbs and by nccomp: a client connects to the Unix
// socket, sends one request line and reads the answer until the daemon closes the connection.
// A request is a status form ("text", "json", "metrics") or an operator command: a verb and its
// arguments. An operator command is answered "ok ..." (and more lines) or "error: <why>".
// Pure text; no I/O (client/status_client.hpp talks to the socket).
#pragma once

#include <string>
#include <string_view>

namespace nccomp::client {

/// Where nccompd listens unless [status] socket_path says otherwise.
inline constexpr std::string_view kDefaultSocketPath = "/run/nccompd/status.sock";

/// The status forms (an empty request is "text").
inline constexpr std::string_view kStatusText = "text";
inline constexpr std::string_view kStatusJson = "json";
inline constexpr std::string_view kStatusMetrics = "metrics";

/// The operator verbs.
inline constexpr std::string_view kAcknowledgeVerb = "acknowledge";
inline constexpr std::string_view kWarmStartVerb = "warm-start";
inline constexpr std::string_view kRegisterVerb = "register";
inline constexpr std::string_view kCalibrateVerb = "calibrate";
inline constexpr std::string_view kModelVerb = "model";

/// "acknowledge": clear every module's latched alarms.
[[nodiscard]] std::string acknowledge_request();
/// "warm-start now", or "warm-start at-next-motion" (the machine is cold).
[[nodiscard]] std::string warm_start_request(bool at_next_motion);
/// "register release NAME" (NAME may be "all").
[[nodiscard]] std::string register_release_request(std::string_view name);
/// "calibrate COMMAND" (a line of the calibration command language; "" asks for the status).
[[nodiscard]] std::string calibrate_request(std::string_view command);
/// "model load PATH" (PATH absolute: the daemon's working directory is not the caller's; the
/// rest of the line, spaces included), "model rollback", "model status".
[[nodiscard]] std::string model_load_request(std::string_view path);
[[nodiscard]] std::string model_rollback_request();
[[nodiscard]] std::string model_status_request();
/// "model candidate PATH" (PATH absolute), "model promote": the candidate in shadow.
[[nodiscard]] std::string model_candidate_request(std::string_view path);
[[nodiscard]] std::string model_promote_request();

/// The prefix of a refusal.
inline constexpr std::string_view kErrorPrefix = "error: ";
/// True if the answer is a refusal ("error: <why>").
[[nodiscard]] bool is_error(std::string_view answer) noexcept;
/// The <why> of a refusal, without its trailing line breaks (the rest of the answer if any).
[[nodiscard]] std::string error_reason(std::string_view answer);

/// The calibrate verb's answer: "ok <phase> <request>\n" and lines to show, or "error: ...".
struct CalibrateAnswer {
  bool ok{false};
  std::string phase;  // ok: the calibrator's phase
  std::string text;   // ok: the lines after the first; else the whole answer
};
[[nodiscard]] CalibrateAnswer parse_calibrate_answer(std::string_view answer);

}  // namespace nccomp::client
