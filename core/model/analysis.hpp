// Offline analysis of the measurement log (`nccomp analyze`): fit the declared terms, search the
// residual for an effect the model lacks, add the best supported one, refit, repeat while it is
// significant. Pure: data in, numbers out (the tool reads the CSV and writes the reports).
//
// Significance, so that noise does not become an "effect":
//   1. nested-model F-test on the fitted (earlier, time-ordered) rows, the non-linear parameter
//      counted as one more degree of freedom;
//   2. the p-value multiplied by the number of candidates and by the candidate's search
//      multiplicity (independent frequencies of a period search, decades of a time-constant grid,
//      change points): Bonferroni over everything that was tried;
//   3. the held-out (later) rows' RMS must drop as well.
// An effect is added only when the adjusted p-value is below `alpha` and the held-out check holds.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <string>
#include <utility>
#include <vector>

#include "core/model/model.hpp"

namespace nccomp::core::model {

/// The log's rows, column-wise (1e6 rows fit in memory as doubles: 8 MB per column).
struct Dataset {
  std::vector<std::string> extra_columns;
  /// kStandardColumns + extra_columns.size() columns; an empty vector = column all unknown.
  std::vector<std::vector<double>> columns;
  /// The deviation the model must explain [µm]: measured_um + applied_um (the error the machine
  /// made before the active compensation took its share).
  std::vector<double> target_um;
  /// The order of the rows in time over several files, for the time-ordered split: time_s
  /// within a file, each of nccompd's logs after the previous one (time_s starts again at every
  /// warm start); mapped foreign CSVs keep their time_s. Empty, or of another length than the
  /// rows: time_s itself.
  std::vector<double> order_s;
  /// Where each row was read, for messages: files[row_file[i]], line row_line[i] (0 = not from a
  /// file; vectors shorter than the rows: rows built in memory).
  std::vector<std::string> files;
  std::vector<std::uint32_t> row_file;
  std::vector<std::uint32_t> row_line;
  /// The reader's session of each row: one per file, and a new one at each warm start of a v2
  /// log (its `session` grows). Of another length than the rows: one session. row() gives it
  /// as kSessionColumn (analyze() renumbers it as sessions_of() first).
  std::vector<std::uint32_t> row_session;

  Dataset();
  [[nodiscard]] std::size_t rows() const { return target_um.size(); }
  [[nodiscard]] Row row(std::size_t i) const;
  /// Values of one column (empty if the column is absent).
  [[nodiscard]] const std::vector<double>& column(int index) const;
  /// "file:line" of row i, or "row <i+1>" when it was not read from a file.
  [[nodiscard]] std::string where(std::size_t i) const;
};

/// One term the search may add.
struct Candidate {
  TermSpec spec;
  /// Values of the non-linear parameter to try (empty for linear / polynomial forms).
  std::vector<double> grid;
  /// Number of effectively independent trials of the grid (for the multiplicity correction).
  double multiplicity{1.0};
  /// A per-group version of a shared candidate (SearchOptions::group_columns): its grid is
  /// scored group by group (the groups' rows are disjoint), the best point exactly.
  bool grouped{false};
};

struct SearchOptions {
  /// Kinds the added effects apply to (bit per kind).
  std::uint8_t kind_mask{0x7};
  /// Effect names never to try (e.g. "periodic_y").
  std::vector<std::string> exclude;
  /// Columns tried as an effect linear in that column: named thermal_drift for a temperature
  /// (is_temperature_column), linear_<column> otherwise.
  std::vector<int> linear_columns;
  /// Columns declared a temperature (true) or not (false), overriding the naming rule.
  std::vector<std::pair<int, bool>> column_is_temperature;
  /// Extra columns tried as thermal_drift, first-order lag of that column (speed, power).
  std::vector<int> lag_columns;
  /// Split every candidate per group of these columns (e.g. tool: one wear curve per tool).
  std::array<int, 2> per{-1, -1};
  /// Columns by which every candidate is also tried per group, one coefficient set per value of
  /// the column (axis / checkpoint, tool, part family), beside its shared version. Each is one
  /// more candidate in the multiple-testing correction, and its extra coefficients count in the
  /// F-test. A column with fewer than 2 or more than kMaxSearchGroups values among the fitted
  /// rows is not used (warning group_column_unused). Not together with `per`.
  std::vector<int> group_columns;
  /// Shortest period tried for periodic_x|y|z [mm].
  double period_min_mm{2.0};
};

/// The residual scale of the final model's prediction interval on the held-out rows.
enum class IntervalMethod : std::uint8_t {
  /// The residual standard deviation of the fit on the fitted rows: right when the later hours
  /// behave like the fitted ones (no drift the model lacks).
  kInSample,
  /// The larger of that and the RMS error of predicting later fitted rows from earlier ones:
  /// the fitted rows in time order cut into kIntervalFolds + 1 blocks of equal count, the final
  /// terms refitted on the blocks before block f and block f predicted, for the latest
  /// kIntervalFoldsUsed folds (the blocks nearest the held-out rows, each fitted on most rows).
  kValidation,
};
inline constexpr std::size_t kIntervalFolds = 4;
inline constexpr std::size_t kIntervalFoldsUsed = 2;

struct AnalysisConfig {
  std::vector<TermSpec> declared;
  SearchOptions search;
  /// Latest fraction of the rows (by time_s) held out of every fit.
  double heldout_fraction{0.2};
  /// Family-wise false-discovery level per search step.
  double alpha{0.01};
  std::size_t max_effects{4};
  /// When the best candidate is significant but worsens the held-out rows, try it together
  /// with the best next candidate (both must be significant, the pair must help held out).
  bool lookahead{true};
  /// Scale the F-test to the effective number of rows of an AR(1) residual. Off = rows are
  /// taken as independent and only the held-out check guards against serially correlated data.
  bool ar1_correction{true};
  /// Rows used for the non-linear grid search (the fits use all rows).
  std::size_t search_rows{10000};
  /// Rolling-origin validation inside the fitted rows: the search rows in time order are cut into
  /// rank_folds + 1 blocks, each later block predicted from the blocks before it, and the best
  /// candidates by BIC are refitted (F-tested) in the order of that error. 0 = BIC order only
  /// (the default: a session_offset or a per-group term of groups not yet seen cannot be
  /// predicted from earlier hours, and would rank last).
  std::size_t rank_folds{0};
  /// A row is an outlier when it differs from both neighbours of its (kind, point, tool) series
  /// by more than this many noise standard deviations (robust, from the median absolute
  /// successive difference), in the same direction; 0 = no outlier rule.
  double outlier_sigmas{10.0};
  /// A gap in time longer than this [s] between rows of one file (session) starts a new session;
  /// 0 = sessions are the files and warm starts only.
  double session_gap_s{0.0};
  /// Leave-one-session-out validation of the declared and the final model (--validate sessions).
  bool validate_sessions{false};
  /// How the scale of the prediction interval (PredictionInterval) is measured.
  IntervalMethod interval{IntervalMethod::kValidation};
  /// --validate sessions on one continuous recording: blocks of this length [s] from its first
  /// row's time (in the order over files) are held out in turn instead of the sessions; 0 = the
  /// sessions (files, warm starts, session_gap_s).
  double validate_block_s{0.0};
};

struct ErrorStats {
  double rms_um{0.0};
  double max_um{0.0};
  std::size_t rows{0};
};

struct FitStats {
  ErrorStats fitted;
  ErrorStats heldout;
  double rss{0.0};
  std::size_t parameters{0};
  /// parameters, with a shrunk session term counted by its effective degrees of freedom.
  double effective_parameters{0.0};
};

/// One effect added by the search.
struct AddedEffect {
  TermSpec spec;
  FitStats before;
  FitStats after;
  double p_value{1.0};  // adjusted (see file comment)
  double f_statistic{0.0};
  /// 95 % confidence interval [low, high] of each coefficient of the final fit on the fitted
  /// rows (t distribution; widened for an AR(1) residual when ar1_correction is on).
  std::vector<std::array<double, 2>> coef_ci95;
};

/// A candidate tried at one search step, for the report.
struct TriedCandidate {
  std::string name;
  std::string column;
  /// The candidate's per columns (-1 unused): set for a per-group version.
  std::array<int, 2> per{-1, -1};
  Form form{Form::kLinear};
  int degree{1};  // TermSpec::degree (the report shows it for kPoly and kLag)
  double parameter{0.0};
  double rss_reduction_fraction{0.0};  // on the search rows
  double p_value{1.0};                 // adjusted; 1 when not refitted
  bool heldout_improved{false};
  bool refitted{false};
};

/// Something the figures do not say by themselves (summary.json `warnings`).
/// Most groups of a per-group candidate (SearchOptions::group_columns).
inline constexpr std::size_t kMaxSearchGroups = 64;

struct Warning {
  std::string code;  // saturated, collinear, … (docs/analyze.md)
  std::string message;
};

/// What a least-squares fit found besides its coefficients.
struct FitInfo {
  std::size_t rows{0};        // rows that entered the fit
  std::size_t parameters{0};  // coefficients
  std::size_t rank{0};        // of the design: below parameters = collinear coefficients
  /// Set by the caller to get coef_variance.
  bool want_variance{false};
  /// Per coefficient (Model order), diagonal of the pseudo-inverse of X'X: its variance is this
  /// times the residual variance.
  std::vector<double> coef_variance;
  /// parameters, with each shrunk (session) coefficient counted as its diagonal entry of the
  /// hat matrix (X'X + Λ)⁻¹X'X: the effective degrees of freedom of a random effect.
  double effective_parameters{0.0};
  /// Set by the caller to get coef_covariance.
  bool want_covariance{false};
  /// (X'X + Λ)⁺ in Model order, row-major (parameters²): times the residual variance, the
  /// coefficients' covariance.
  std::vector<double> coef_covariance;
};

/// One fold of the leave-one-session-out validation: the session's rows predicted by the
/// declared and the final terms fitted on every other session's rows.
struct SessionFold {
  std::size_t session{0};
  std::size_t first_row{0};  // its first row (Dataset::where)
  ErrorStats declared;
  ErrorStats final_model;
};

/// The final model's prediction interval on the held-out rows (fitted on the fitted rows, as the
/// held-out figures) and how many held-out rows it covered.
struct PredictionInterval {
  double level{0.95};
  std::size_t rows{0};  // held-out rows with a measurement and a prediction
  double half_width_mean_um{0.0};
  double half_width_max_um{0.0};
  /// Share of those rows whose measurement is within its interval.
  double coverage{0.0};
  /// The method that set the scale: kValidation only when the validation blocks gave an error
  /// (validation_rows > 0), else kInSample.
  IntervalMethod method{IntervalMethod::kInSample};
  /// The fit's residual standard deviation [µm] (s).
  double sigma_in_sample_um{0.0};
  /// RMS error [µm] of the later fitted blocks predicted from the earlier ones, and the rows it
  /// is over (0: not measured). The interval's scale is max(s, this).
  double validation_rms_um{0.0};
  std::size_t validation_rows{0};
};

struct AnalysisResult {
  /// In the order found; see Warning.
  std::vector<Warning> warnings;
  FitStats declared;
  std::vector<AddedEffect> effects;
  /// Per search step (one more than effects when the search stopped on its own).
  std::vector<std::vector<TriedCandidate>> steps;
  FitStats final_stats;
  double noise_floor_um{0.0};
  /// Model fitted on the fitted rows only (the numbers above).
  Model fitted_model;
  /// The same terms refitted on all rows: what the daemon should load.
  Model final_model;
  /// Residuals [µm] of every row: declared model, final model (both fitted on the fitted rows).
  std::vector<double> declared_residual_um;
  std::vector<double> final_residual_um;
  /// 0 fitted, 1 held out, 2 in neither: a held-out row of a group no fitted row has
  /// (heldout_unseen_group), or an outlier.
  std::vector<std::uint8_t> heldout;
  /// Rows the robust rule took out of every fit and figure (row indices, in order).
  std::vector<std::size_t> outliers;
  double split_time_s{0.0};
  /// Session of every row (sessions_of()), and the folds of --validate sessions with the RMS
  /// over all their rows (empty / 0 rows when not asked for).
  std::vector<std::uint32_t> session;
  std::vector<SessionFold> session_folds;
  PredictionInterval prediction_interval;
  ErrorStats sessions_declared;
  ErrorStats sessions_final;
};

/// Raised for inputs the analysis cannot work with (too few rows, too many groups, …).
class AnalysisError : public std::exception {
 public:
  explicit AnalysisError(std::string what) : what_(std::move(what)) {}
  [[nodiscard]] const char* what() const noexcept override { return what_.c_str(); }

 private:
  std::string what_;
};

/// Upper tail P(F > f) of the F distribution with (d1, d2) degrees of freedom.
double f_distribution_upper_tail(double f, double d1, double d2);

/// Least-squares fit of `specs` on the rows where use[i] != 0. Groups are discovered from those
/// rows. Throws AnalysisError if nothing can be fitted or a coefficient is not finite.
Model fit_terms(const Dataset& data, const std::vector<TermSpec>& specs,
                const std::vector<std::uint8_t>& use, FitInfo* info = nullptr);

/// Residual target − prediction of every row (rows in order; lag filters run over all rows; a
/// session term learns a session it has no coefficient for from that session's earlier rows).
std::vector<double> residuals(const Dataset& data, const Model& model);

/// Noise floor [µm]: from successive differences of the residual within each (kind, point, tool)
/// series in time order; smooth effects cancel in the differences, the noise does not.
double noise_floor_um(const Dataset& data, const std::vector<double>& residual,
                      const std::vector<std::uint8_t>& use);

/// Lag-1 autocorrelation of the residual within each (kind, point, tool) series in row order.
double lag1_autocorrelation(const Dataset& data, const std::vector<double>& residual,
                            const std::vector<std::uint8_t>& use);

/// Whether `column` holds a temperature: as declared in options.column_is_temperature, else
/// temp_c and every column whose name ends in _c (°C, the unit-suffix convention).
bool is_temperature_column(int column, const std::vector<std::string>& extras,
                           const SearchOptions& options);

/// The value of `column` at each session's warm start: its first used row of the kinds in
/// kind_mask with a known value (earliest in order_s, else time_s), one per session
/// (Dataset::row_session) in order of session number.
std::vector<double> warm_start_values(const Dataset& data, int column,
                                      const std::vector<std::uint8_t>& use, std::uint8_t kind_mask);

/// The reference value of a linear term in a temperature column: the mean of its warm-start
/// values (what the machine starts from), 0 when there is none. Its constant then holds the
/// deviation at the warm start rather than an intercept at 0 °C.
double linear_reference(const std::vector<double>& warm_start);

/// The effect's name with its groups, as the reports show it: "thermal_drift" for a shared
/// term, "thermal_drift per=point" (or "per=tool+point") for a per-group one.
std::string effect_label(const std::string& name, const std::array<int, 2>& per,
                         const std::vector<std::string>& extras);

/// Name of the effect linear in `column`: thermal_drift for a temperature, linear_<column>.
std::string linear_effect_name(int column, const std::vector<std::string>& extras,
                               const SearchOptions& options);

/// The candidate effects for this data set (the effect names of issue 11). `declared`: the
/// model's declared terms; a term that applies to tool_wear rows makes `tool_wear` in the form
/// `wear` (proportional to the model's tool wear) a candidate for the other kinds.
std::vector<Candidate> make_candidates(const Dataset& data, const std::vector<std::uint8_t>& use,
                                       const SearchOptions& options,
                                       const std::vector<TermSpec>& declared = {});

/// Session of each row, numbered from 0 in order of first appearance: the reader's sessions
/// (Dataset::row_session), each split where time (order_s, else time_s) jumps by more than
/// gap_s from the session's previous row (gap_s > 0).
std::vector<std::uint32_t> sessions_of(const Dataset& data, double gap_s);

/// The whole analysis.
AnalysisResult analyze(const Dataset& data, const AnalysisConfig& config);

}  // namespace nccomp::core::model
