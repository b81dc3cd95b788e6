// Outputs of `nccomp analyze`: summary.json, report.md with SVG figures (written here, no
// plotting library), model.toml (model_io.hpp).
#pragma once

#include <string>
#include <vector>

#include "core/model/analysis.hpp"

namespace nccomp::tools::analyze {

/// summary.json: exactly the keys of issue 11.
std::string summary_json(const core::model::Dataset& data,
                         const core::model::AnalysisResult& result);

/// One scatter figure: residual against `column`, declared model (left) and final model (right).
std::string residual_svg(const core::model::Dataset& data,
                         const core::model::AnalysisResult& result, int column);

/// Columns worth a figure: those with at least two distinct known values (kind excluded).
std::vector<int> plotted_columns(const core::model::Dataset& data);

/// report.md; figures are referenced as plots/residual_<column>.svg.
std::string report_markdown(const core::model::Dataset& data,
                            const core::model::AnalysisResult& result,
                            const std::vector<std::string>& inputs,
                            const std::vector<int>& plotted);

/// File-name-safe form of a column name (UTF-8 headers such as "t1(°C)" become "t1__C_").
std::string safe_name(const std::string& column);

/// The effect's parameters as a JSON object (non-linear parameter with its unit, coefficients).
std::string params_json(const core::model::TermSpec& spec, const core::model::Model& model,
                        const std::vector<std::string>& extras);

}  // namespace nccomp::tools::analyze
