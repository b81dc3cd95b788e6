// A candidate model in shadow (`nccomp model candidate FILE`, [model.shadow];
// docs/closing-the-loop.md, "A candidate in shadow"): every measurement the daemon logs is scored
// by the live model and by the candidate (or, after a promotion, by the model it replaced), and a
// rule decides from the per-part squared errors whether the other model is better.
//
// Off the loop: the measurement log's writer thread hands each record to observe(), the main
// thread takes the decisions (take_decision()) and carries them out as a `nccomp model load` /
// `rollback` would. The loop never sees the candidate, so it costs the loop nothing.
//
// The score of a model on a row: the error it leaves, (measured_um + applied_um) − prediction_um,
// the row's deviation without the compensation that was active, less what the model predicts
// (the target `nccomp analyze` fits). A part: the rows of one part number (in one session); a row
// without a part number (0) is a part of its own. A part is scored once a row of another part
// arrives.
//
// The rule: a one-sided exact sign test on the per-part differences of mean squared error
// (paired_test()). Thread-safe. Not real-time.
#pragma once

#include <array>
#include <cstdint>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/common/types.hpp"
#include "core/model/model.hpp"

namespace nccomp::daemon::sections {

enum class ShadowPromote { kAuto, kOperator };

/// [model.shadow].
struct ShadowOptions {
  /// Parts scored by both models before the rule decides (promotion, and demotion after it).
  int min_parts{10};
  /// Level of the one-sided sign test: the highest probability of promoting a candidate that
  /// is not better.
  double alpha{0.05};
  /// The candidate's RMS error must also be this much below the live model's [µm].
  double margin_um{0.0};
  ShadowPromote promote{ShadowPromote::kAuto};
  /// Decisions kept in the history.
  int history_size{20};
};

/// Running statistics of one model's errors: parts scored and the mean over parts of each part's
/// mean squared error.
struct ModelScore {
  std::uint64_t parts{0};
  std::uint64_t rows{0};
  double sum_part_mse_um2{0.0};
  void add_part(double mse_um2, std::uint64_t part_rows) noexcept;
  /// NaN before the first part.
  [[nodiscard]] double mse_um2() const noexcept;
  [[nodiscard]] double rms_um() const noexcept;
};

/// The paired comparison of the model in force (incumbent) and a challenger on the same parts.
struct PairedTest {
  int parts{0};
  int challenger_better{0};  // parts with a lower squared error for the challenger
  int incumbent_better{0};
  int ties{0};  // equal errors: no evidence either way, left out of the test
  /// P(at least challenger_better of challenger_better + incumbent_better | no difference).
  double p_value{1.0};
  double incumbent_rms_um{0.0};
  double challenger_rms_um{0.0};
  bool passed{false};  // p_value ≤ alpha and the RMS lower by at least margin_um
};

/// P(X ≥ k) for X ~ Binomial(n, 1/2); 1 for k ≤ 0.
[[nodiscard]] double sign_test_p(int k, int n) noexcept;

/// The rule on per-part mean squared errors (same parts, same order) [µm²].
[[nodiscard]] PairedTest paired_test(std::span<const double> incumbent_mse_um2,
                                     std::span<const double> challenger_mse_um2,
                                     const ShadowOptions& options);

/// What the shadow is doing.
enum class ShadowPhase {
  kNone,       // no other model: the live one is scored alone
  kCandidate,  // a candidate scored beside the live model
  kAnnounced,  // the candidate passed, promote = "operator": waiting for nccomp model promote
  kWatch,      // after a promotion: the model it replaced scored beside it (demotion)
};
[[nodiscard]] std::string_view phase_name(ShadowPhase p) noexcept;

/// One decision of the history.
struct ShadowDecision {
  std::string utc;
  /// candidate, promoted, announced, rejected, demoted, confirmed, refused.
  std::string action;
  std::string by;  // "shadow rule" or the operator (uid, user, pid)
  std::string live_file;
  std::string other_file;  // the candidate, or the model a promotion replaced
  PairedTest test;
};

/// One line of the history as status shows it.
[[nodiscard]] std::string describe(const ShadowDecision& d);
/// The history file's text: "nccomp_model_shadow 1", then one tab-separated line per decision.
[[nodiscard]] std::string history_to_text(const std::vector<ShadowDecision>& history);
/// Parses history_to_text()'s form; throws std::invalid_argument naming the line.
[[nodiscard]] std::vector<ShadowDecision> history_from_text(std::string_view text);

struct ShadowStatus {
  ShadowOptions options;
  ShadowPhase phase{ShadowPhase::kNone};
  std::string live_file;
  ModelScore live;  // since it became live
  std::string other_file;
  ModelScore other;   // since it came into the shadow
  PairedTest window;  // the comparison so far (parts paired since the other model came in)
  std::uint64_t rows_scored{0};
  std::uint64_t rows_skipped{0};        // a non-finite target or prediction
  std::vector<ShadowDecision> history;  // oldest first
};

class Shadow {
 public:
  /// log_context_names: the measurement log's context columns, in record order; a model's
  /// extra column of the same name is scored with the record's value.
  void configure(const ShadowOptions& options, std::vector<std::string> log_context_names);
  /// The model of the configuration that runs (start-up, every reload). A model other than the
  /// live one starts its score anew and ends a watch; the one it replaces is kept (watch_previous).
  /// A candidate that becomes live this way leaves the shadow.
  void set_live(const std::string& file, const std::string& hash, core::model::Model model);
  /// A new candidate: scored from the next part on.
  void set_candidate(const std::string& file, const std::string& hash, core::model::Model model);
  /// After a promotion: the model it replaced is scored beside it for min_parts parts.
  void watch_previous();
  /// No other model in the shadow.
  void clear();

  /// The writer thread: scores one record.
  void observe(const core::MeasurementRecord& r);
  /// A decision of the rule, once (the main thread carries it out and records it).
  [[nodiscard]] std::optional<ShadowDecision> take_decision();
  /// Appends to the history (the oldest dropped beyond history_size).
  void record(ShadowDecision d);
  void set_history(std::vector<ShadowDecision> history);
  [[nodiscard]] std::vector<ShadowDecision> history() const;

  [[nodiscard]] ShadowStatus status() const;
  [[nodiscard]] ShadowPhase phase() const;
  [[nodiscard]] std::string other_file() const;

 private:
  struct Scored {
    std::string file;
    std::string hash;
    core::model::Model model;
    core::model::EvalState state;
    ModelScore score;
    bool present{false};
  };
  void reset_window();
  void close_part();
  void decide();
  double error_um(Scored& m, const core::model::Row& row, double target_um);
  static void assign(Scored& s, const std::string& file, const std::string& hash,
                     core::model::Model model);

  mutable std::mutex mu_;
  ShadowOptions options_;
  std::vector<std::string> context_names_;
  std::array<double, core::kMaxContextValues> ctx_{};  // the row being scored
  ShadowPhase phase_{ShadowPhase::kNone};
  Scored live_;
  Scored other_;
  Scored previous_;  // the live model before the last change
  // The part being scored.
  bool open_{false};
  std::uint64_t open_session_{0};
  std::int32_t open_part_{0};
  std::uint64_t open_rows_{0};
  double open_live_sq_{0.0};
  double open_other_sq_{0.0};
  std::vector<double> window_live_;
  std::vector<double> window_other_;
  PairedTest window_test_;
  std::uint64_t rows_scored_{0};
  std::uint64_t rows_skipped_{0};
  std::optional<ShadowDecision> pending_;
  std::vector<ShadowDecision> history_;
};

}  // namespace nccomp::daemon::sections
