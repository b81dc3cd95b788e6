// Fuzz target for the S3 parsers. Every input must either parse or be refused with the
// parser's own exception type; a parsed state must survive import and a step.
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>

#include "core/calib/calibrator.hpp"
#include "core/calib/state.hpp"
#include "formats/calib/config_toml.hpp"
#include "formats/calib/script.hpp"
#include "tools/calibrate/session.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) {
    return 0;
  }
  const std::string_view text(reinterpret_cast<const char*>(data) + 1, size - 1);
  namespace cal = nccomp::tools::calibrate;
  switch (data[0]) {
    case 's': {
      // A script: parse every line and run it in a session on the default geometry.
      std::ostringstream sink;
      nccomp::core::calib::CalibrationConfig cfg;
      cfg.touches_per_axis = 1;
      cal::Session session(cfg, 0.0, sink);
      std::size_t line_no = 0;
      std::size_t pos = 0;
      while (pos <= text.size()) {
        const auto nl = text.find('\n', pos);
        const auto line = text.substr(pos, nl == std::string_view::npos ? text.npos : nl - pos);
        ++line_no;
        try {
          const auto cmd = cal::parse_line(line, line_no);
          // Keep waits short: the fuzzer looks for crashes, not for long runs.
          if (const auto* w = std::get_if<cal::CmdWait>(&cmd); w == nullptr || w->duration_s < 50) {
            if (!session.run(cmd, line_no)) {
              break;
            }
          }
        } catch (const cal::ScriptError&) {
        }
        if (nl == std::string_view::npos) {
          break;
        }
        pos = nl + 1;
      }
      break;
    }
    case 't': {
      try {
        const auto state = nccomp::core::calib::from_text(text);
        nccomp::core::calib::Calibrator c;
        c.configure(nccomp::core::calib::CalibrationConfig{});
        c.import_state(state);
        nccomp::core::StepOutput out;
        c.step(nccomp::core::from_seconds(10.0), {}, out);
        (void)nccomp::core::calib::to_text(c.export_state());
      } catch (const std::invalid_argument&) {
      }
      break;
    }
    default: {
      try {
        (void)nccomp::formats::calib::load_calibration_config_text(text, "fuzz.toml");
      } catch (const std::invalid_argument&) {
      }
      break;
    }
  }
  return 0;
}
