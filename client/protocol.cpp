#include "client/protocol.hpp"

namespace nccomp::client {

std::string acknowledge_request() { return std::string(kAcknowledgeVerb); }

std::string warm_start_request(bool at_next_motion) {
  return std::string(kWarmStartVerb) + (at_next_motion ? " at-next-motion" : " now");
}

std::string register_release_request(std::string_view name) {
  return std::string(kRegisterVerb) + " release " + std::string(name);
}

std::string calibrate_request(std::string_view command) {
  return std::string(kCalibrateVerb) + " " + std::string(command);
}

std::string model_load_request(std::string_view path) {
  return std::string(kModelVerb) + " load " + std::string(path);
}

std::string model_rollback_request() { return std::string(kModelVerb) + " rollback"; }

std::string model_status_request() { return std::string(kModelVerb) + " status"; }

std::string model_candidate_request(std::string_view path) {
  return std::string(kModelVerb) + " candidate " + std::string(path);
}

std::string model_promote_request() { return std::string(kModelVerb) + " promote"; }

bool is_error(std::string_view answer) noexcept { return answer.starts_with(kErrorPrefix); }

std::string error_reason(std::string_view answer) {
  if (is_error(answer)) answer.remove_prefix(kErrorPrefix.size());
  while (!answer.empty() && answer.back() == '\n') answer.remove_suffix(1);
  return std::string(answer);
}

CalibrateAnswer parse_calibrate_answer(std::string_view answer) {
  CalibrateAnswer a;
  if (!answer.starts_with("ok ")) {
    a.text = std::string(answer);
    return a;
  }
  a.ok = true;
  const auto nl = answer.find('\n');
  const std::string_view head = answer.substr(3, nl == std::string_view::npos ? nl : nl - 3);
  a.phase = std::string(head.substr(0, head.find(' ')));
  a.text = nl == std::string_view::npos ? std::string() : std::string(answer.substr(nl + 1));
  return a;
}

}  // namespace nccomp::client
