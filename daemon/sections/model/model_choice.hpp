// The operator's choice of model (`nccomp model load FILE`, `nccomp model rollback`;
// docs/closing-the-loop.md): it replaces the `file` of the configuration's [model] section for
// as long as that section names the file it named when the choice was made (an operator who
// edits `file` in the configuration chooses again). The daemon keeps it in its state directory,
// so the live model and the one kept for rollback survive a restart. Not real-time.
#pragma once

#include <optional>
#include <string>
#include <string_view>

namespace nccomp::daemon::sections {

/// One model: its file ("" = no model) and a hash of its bytes, and since when it is live.
struct ModelRecord {
  std::string file;
  std::string hash;       // 16 hex digits of FNV-1a 64 over the file's bytes; "" without a file
  std::string since_utc;  // ISO 8601 UTC, when it became live
};

struct ModelChoice {
  /// The configuration's [model] file (resolved) the choice replaces.
  std::string configured;
  ModelRecord live;
  /// The model before the live one: what `nccomp model rollback` returns to ("" = none).
  ModelRecord previous;
};

/// The choice the [model] parser applies (nullopt: none, the configuration's file). Thread-safe.
[[nodiscard]] std::optional<ModelChoice> model_choice();
void set_model_choice(std::optional<ModelChoice> choice);

/// The hash of a file's bytes (ModelRecord::hash); throws std::runtime_error if unreadable.
[[nodiscard]] std::string model_file_hash(const std::string& path);
/// Now, ISO 8601 UTC to the second.
[[nodiscard]] std::string utc_now();

/// Text form: "nccomp_model_choice 1" then one "key value" line per field (configured,
/// live_file, live_hash, live_since, previous_file, previous_hash, previous_since).
[[nodiscard]] std::string to_text(const ModelChoice& c);
/// Parses to_text()'s form; throws std::invalid_argument naming the line and key.
[[nodiscard]] ModelChoice model_choice_from_text(std::string_view text);

}  // namespace nccomp::daemon::sections
