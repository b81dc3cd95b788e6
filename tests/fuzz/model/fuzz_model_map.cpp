// Fuzz target: mapping files and [model] tables (TOML). Any bytes must either parse or raise
// formats::DiagnosticsError; a model that parses as fitted must evaluate without crashing.
#include <cstddef>
#include <cstdint>
#include <string>

#include "core/model/model.hpp"
#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"

namespace io = nccomp::formats::model_io;
namespace cm = nccomp::core::model;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    (void)io::read_mapping_text(text, "map.toml");
  } catch (const nccomp::formats::DiagnosticsError&) {
  }
  try {
    io::ModelFile f = io::read_model_text(text, "model.toml", true);
    const cm::Model m(f.extra_columns, std::move(f.fitted_terms));
    cm::EvalState s = m.make_state();
    cm::Row r = cm::unknown_row();
    for (int i = 0; i < 4; ++i) {
      for (std::size_t c = 0; c < cm::kMaxColumns; ++c)
        r[c] = static_cast<double>(static_cast<std::size_t>(i) + c % 3);
      r[static_cast<std::size_t>(cm::Column::kKind)] = static_cast<double>(i % 3);
      (void)m.evaluate(r, s);
    }
  } catch (const nccomp::formats::DiagnosticsError&) {
  }
  return 0;
}
