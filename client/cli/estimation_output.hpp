// What `riccati` prints of the results of output error, maximum likelihood
// and smoothing: the parameters with their standard errors, intervals and
// correlations, the warnings, each experiment's fit and residual
// diagnostics, the noise levels estimated; the smoothed states. Tables for
// people and CSV for tools; JSON is the result as it is (to_json).
#pragma once

#include <string>
#include <vector>

#include "riccati/v1/jobs.pb.h"
#include "riccati/v1/models.pb.h"

namespace riccati::cli {

// The names a result does not carry (states, inputs, outputs), from the
// model when riccatid gave it; numbered ("x1", "u1", "y1") where empty.
struct ModelNames {
  std::vector<std::string> states, inputs, outputs;
};
ModelNames model_names(const v1::ModelInfo& model);
// The method's short name ("filter", "oe", "ml").
std::string method_name(v1::IdentificationMethod method);

// The one naming of exported columns and rows (CSV here, the MAT file's
// name lists, Python's to_frame(); docs/results.md): a state or parameter
// by its name ("h1", "A1"), anything else as quantity.name ("y.h1",
// "y_model.h1", "residual.h1", "std.A1"). `quantity` empty: the name alone.
std::string column(const std::string& quantity, const std::string& name);
// `names` when it has `count` of them, else numbered after `prefix` ("y1", "y2").
std::vector<std::string> sized_names(const std::vector<std::string>& names, std::size_t count, const char* prefix);

// Parameters flagged as hard to tell apart: |r| above this.
constexpr double kHighCorrelation = 0.95;

// `riccati result` (and identify) for --method oe and ml: the optimiser's
// end, the parameter table (with `initial` and `truth` when they have one
// value per parameter), the correlations, the warnings, the noise levels
// (ml), and per experiment its initial states, fit and diagnostics.
std::string estimation_table(const v1::EstimationResult& r, const std::vector<double>& initial,
                             const std::vector<double>& truth, const ModelNames& names);
// The lower triangle of the correlation matrix, |r| > kHighCorrelation
// marked with '*'; fixed parameters left out.
std::string correlation_table(const v1::EstimationResult& r);
// A table per test, rows named by the outputs and inputs: per output the
// Ljung-Box test, per output and input the cross-correlation test, and the
// NIS band when the method has one; each with its statistic, limit, p-value,
// degrees of freedom and verdict, as riccatid computed them.
std::string diagnostics_table(const v1::Diagnostics& d, const ModelNames& names);
// experiment, t, then per output y.o (measured), y_model.o, residual.o
// (y - y_model, in the output's unit), residual_normalised.o (what the
// method's diagnostics test: OE divided by sigma, ML whitened by the
// innovation covariance; 0 where left out), used.o (1, or 0 where the mask
// left it out); one row per sample of every experiment.
std::string estimation_csv(const v1::EstimationResult& r, const ModelNames& names);

// Per state and parameter: smoothed at the start and end with its std, and
// the mean std filtered and smoothed.
std::string smoothing_table(const v1::SmoothingResult& r);
// t, the smoothed [x; theta] (h1, A1), their std (std.h1), the filtered
// ones (filtered.h1) and their std (filtered_std.h1), the model's outputs
// at the smoothed estimate (y_model.o) and the filter's innovations
// (innovation.o).
std::string smoothing_csv(const v1::SmoothingResult& r, const ModelNames& names);

}  // namespace riccati::cli
