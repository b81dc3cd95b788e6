// The compensation model of `nccomp analyze` and of the daemon: a sum of terms over the
// measurement context (architecture.md, "Measurement log" and "What the analysis must do").
//
// Every term is linear in its coefficients once its one non-linear parameter (a time constant,
// a period, a change point, a scale length) is fixed:
//
//   prediction_um(row) = Σ_terms Σ_b coef[group(row)][b] · basis_b(row)
//
// A term may be split per group (e.g. one constant per checkpoint, one wear slope per tool):
// the group is the value of up to two context columns; each group gets its own coefficients.
//
// Lifecycle: a Model is built and fitted off the loop (it allocates); make_state() sizes the
// evaluation state; evaluate() is real-time safe: no allocation, no locks, no I/O.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace nccomp::core::model {

/// Context columns of a row. The first eleven are the measurement log's v1 columns; the rest are
/// named extra columns (e.g. a second temperature, spindle speed) declared by the model.
enum class Column : std::uint8_t {
  kTime = 0,   // time_s
  kPart = 1,   // part
  kTool = 2,   // tool
  kKind = 3,   // kind: 0 tool_wear, 1 contour, 2 calib
  kPoint = 4,  // point
  kX = 5,      // x_mm
  kY = 6,      // y_mm
  kZ = 7,      // z_mm
  kAngle = 8,  // angle_deg
  kPath = 9,   // path_mm
  kTemp = 10,  // temp_c
};
inline constexpr std::size_t kStandardColumns = 11;
inline constexpr std::size_t kMaxColumns = 32;
inline constexpr std::size_t kMaxExtraColumns = kMaxColumns - kStandardColumns;
/// Row index of the session (warm start) the row belongs to, after the named columns: set by the
/// analysis (sessions_of()) and by the daemon (its warm-start count), never read from a file.
inline constexpr std::size_t kSessionColumn = kMaxColumns;
/// Basis functions of one term (sine: 2, polynomial and interaction: up to 3).
inline constexpr std::size_t kMaxBasis = 3;
inline constexpr double kUnknown = std::numeric_limits<double>::quiet_NaN();

/// The names of the standard columns, in Column order (the measurement log's header names).
inline constexpr std::array<std::string_view, kStandardColumns> kStandardColumnNames = {
    "time_s", "part", "tool",      "kind",    "point", "x_mm",
    "y_mm",   "z_mm", "angle_deg", "path_mm", "temp_c"};

/// One measurement's context; NaN = unknown (an empty CSV cell).
using Row = std::array<double, kMaxColumns + 1>;

/// Row with every column unknown.
Row unknown_row() noexcept;

/// The shape of a term, i.e. its basis functions of the column value v.
enum class Form : std::uint8_t {
  kConstant = 0,  // [1]
  kLinear = 1,    // [v]
  kPoly = 2,      // [u, u², …, u^degree], u = (v − center) / scale
  kExpRise = 3,  // [1 − exp(−v / scale)] for v ≥ 0: first-order warm-up (time) or break-in (path)
  kSine = 4,       // [sin(2π v / scale), cos(2π v / scale)]: scale = period
  kStep = 5,       // [v ≥ center ? 1 : 0]: level change at `center`
  kLag = 6,        // [first-order lag of v over time_s with time constant `scale` [s]]
  kExpGrowth = 7,  // [exp(v / scale) − 1] for v ≥ 0: accelerating wear at the end of tool life
  kHinge = 8,      // [max(0, v − center)]: a rate that changes at `center` (wear stage change)
  // [W]: the model's own tool-wear prediction at the row (Model::wear_reference(): the terms
  // that apply to tool_wear rows, evaluated with kind = tool_wear and point = `center`, the edge
  // support point): an error proportional to the tool wear, whatever shape the wear curve has.
  // It may not apply to tool_wear rows itself. `column` is path_mm (what the wear grows with).
  kWear = 9,
  // [a − center, b − center_b, (a − center)(b − center_b)], a = `column`, b = `column_b`: an
  // interaction with its main effects (ball-screw growth ∝ position × temperature rise, whatever
  // the screw's fixed end and reference temperature). Written "a*b".
  kInteraction = 10,
  // [1] per session (kSessionColumn): one offset per session, a random effect shrunk toward 0
  // (between-session standard deviation `scale` [µm], measurement noise `center` [µm]). A
  // session the fit did not see is learned from its own measurements (Model::observe()): the
  // posterior mean scale² Σr / (n scale² + center²) of its first n residuals r.
  kSession = 11,
};

std::string_view form_name(Form f) noexcept;
/// Parses a form name; returns false on an unknown name.
bool parse_form(std::string_view name, Form& out) noexcept;
/// Number of basis functions of a form.
std::size_t basis_count(Form f, int degree) noexcept;
/// True for forms whose `scale` / `center` is found by the non-linear search.
bool has_nonlinear_parameter(Form f) noexcept;

/// What a term is: fixed before the linear fit.
struct TermSpec {
  /// Operator-facing name: "offset", "wear", or an effect name (thermal_drift, position_x, …).
  std::string name;
  Form form{Form::kConstant};
  /// Column of v (ignored for kConstant); index into Row.
  int column{-1};
  /// Up to two columns whose values split the term into groups; -1 = unused.
  std::array<int, 2> per{-1, -1};
  /// Bit k set = the term applies to rows of kind k (0 tool_wear, 1 contour, 2 calib).
  std::uint8_t kind_mask{0x7};
  /// Polynomial degree (kPoly).
  int degree{1};
  /// kPoly: centre of u. kStep, kHinge: the change point (in the column's unit).
  double center{0.0};
  /// kPoly: scale of u. kExpRise, kExpGrowth: scale length. kSine: period. kLag: time constant [s].
  /// kSession: between-session standard deviation [µm] (`center`: the measurement noise [µm]).
  double scale{1.0};
  /// kInteraction: the second column b and its centre (`center` is that of `column`).
  int column_b{-1};
  double center_b{0.0};
};

/// The term's column as written in model.toml and the reports: "a*b" for an interaction.
std::string term_column_name(const TermSpec& spec, const std::vector<std::string>& extras);

/// A fitted term: its spec, its groups and one coefficient per group and basis function.
struct Term {
  TermSpec spec;
  /// Group keys (values of spec.per columns); one empty-key group when the term is not split.
  std::vector<std::array<double, 2>> groups;
  /// groups.size() × basis_count, row-major; [µm per basis unit].
  std::vector<double> coef;
};

/// Basis values of one term at one row. Returns the number of basis functions written into
/// `out` (0 when the term does not apply to the row: wrong kind, unknown column value).
/// `aux` is what the form needs beyond the row: kLag, the term's filter state; kWear, the
/// model's tool-wear prediction at the row. Real-time safe.
std::size_t term_basis(const TermSpec& spec, const Row& row, double aux,
                       std::span<double, kMaxBasis> out) noexcept;

/// Index of the row's group in `groups`, or -1 when the row's group was never fitted.
/// Real-time safe.
int find_group(const TermSpec& spec, const std::vector<std::array<double, 2>>& groups,
               const Row& row) noexcept;

/// What a session term has learned of the current session (Model::observe()).
struct SessionLearning {
  double session{kUnknown};  // the session learned (a Row's kSessionColumn value)
  double count{0.0};         // residuals taken
  double sum_um{0.0};        // their sum [µm]
};

/// Filter state of the lag terms; sized by Model::make_state(), advanced row by row.
struct EvalState {
  std::vector<double> lag_value;  // per term (unused entries stay 0)
  std::vector<double> lag_input;  // the input held since the previous row
  double last_time_s{0.0};
  bool started{false};
  SessionLearning session;
};

/// Posterior mean [µm] of the offset of a session with `count` residuals summing to `sum_um`,
/// prior N(0, between_sigma_um²), measurement noise noise_sigma_um: the BLUP of one session.
/// Real-time safe.
double session_posterior_um(double count, double sum_um, double between_sigma_um,
                            double noise_sigma_um) noexcept;

/// Advances the lag filters of `terms` to the row's time (zero-order hold of the input).
/// Restarts the filters when time goes backwards (a new log file). Real-time safe.
void advance_state(std::span<const TermSpec> specs, const Row& row, EvalState& state) noexcept;

class Model {
 public:
  Model() = default;
  Model(std::vector<std::string> extra_columns, std::vector<Term> terms);

  /// Names of the extra columns, which take Row indices kStandardColumns, kStandardColumns+1, …
  [[nodiscard]] const std::vector<std::string>& extra_columns() const { return extra_columns_; }
  [[nodiscard]] const std::vector<Term>& terms() const { return terms_; }
  [[nodiscard]] const std::vector<TermSpec>& specs() const { return specs_; }

  /// Evaluation state with room for every term. Allocates: call when configuring.
  [[nodiscard]] EvalState make_state() const;

  /// Predicted deviation [µm] at `row`, advancing the lag filters to the row's time. Rows must
  /// come in time order. Real-time safe: no allocation, no locks, no I/O.
  double evaluate(const Row& row, EvalState& state) const noexcept;

  /// Contribution [µm] of term `index` at `row`, with the state already advanced to the row.
  /// Real-time safe.
  [[nodiscard]] double evaluate_term(std::size_t index, const Row& row,
                                     const EvalState& state) const noexcept;

  /// Learns the row's session offset from its measured deviation `target_um` (measured_um +
  /// applied_um), after evaluate() at that row: the residual of every other term goes into the
  /// session term's posterior (a session with fitted coefficients is not learned; a new session
  /// value starts from the prior, 0). No-op without a session term. Real-time safe.
  void observe(const Row& row, double target_um, EvalState& state) const noexcept;

  /// Index of the session term (kSession), or -1.
  [[nodiscard]] int session_term() const noexcept { return session_term_; }

  /// The tool wear the model predicts at `row` [µm]: Σ of the terms that apply to tool_wear rows
  /// (kWear and kLag terms excepted), evaluated with kind = tool_wear and point = `point`. The
  /// basis of kWear terms. Real-time safe.
  [[nodiscard]] double wear_reference(const Row& row, double point) const noexcept;

 private:
  std::vector<std::string> extra_columns_;
  std::vector<Term> terms_;
  std::vector<TermSpec> specs_;  // copy of the terms' specs, contiguous for advance_state()
  int session_term_{-1};
};

/// Column index for a name: a standard column, or an extra column in `extras`; -1 if unknown.
int column_index(std::string_view name, const std::vector<std::string>& extras) noexcept;
/// Name of a column index (standard or extra); "?" if out of range.
std::string column_name(int index, const std::vector<std::string>& extras);

}  // namespace nccomp::core::model
