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
// experiment, t, then per output: measured, model, residual (normalised),
// used (1, or 0 where the mask left it out); one row per sample of every
// experiment.
std::string estimation_csv(const v1::EstimationResult& r, const ModelNames& names);

// Per state and parameter: smoothed at the start and end with its std, and
// the mean std filtered and smoothed.
std::string smoothing_table(const v1::SmoothingResult& r);
// t, the smoothed [x; theta], their std, the filtered ones and their std,
// the model's outputs at the smoothed estimate and the filter's innovations.
std::string smoothing_csv(const v1::SmoothingResult& r, const ModelNames& names);

}  // namespace riccati::cli
