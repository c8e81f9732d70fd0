// Validation metrics: how well simulated outputs match measured ones.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "engine/status.hpp"

namespace riccati {

// Per output, with y the measured and yhat the simulated samples (N of each):
struct OutputFit {
  std::string name;
  double rmse;         // sqrt(mean((y - yhat)^2)), in the output's unit
  double fit_percent;  // NRMSE fit as MATLAB's compare: 100 (1 - ||y - yhat|| / ||y - mean(y)||); 100 is perfect
  double vaf_percent;  // variance accounted for: 100 (1 - var(y - yhat) / var(y)); blind to a constant offset
  double rrse;         // relative root squared error: sqrt(sum (y - yhat)^2 / sum (y - mean(y))^2); 0 is perfect
};

// Compares measured and simulated outputs, both [ny x N], row by row; `names`
// has ny entries. Fit, VAF and RRSE are relative to how much the measured
// output varies, so for a constant measured output they are NaN (undefined)
// rather than an error; RMSE is still given. Errors (INVALID_ARGUMENT):
// sizes that differ, no samples, a non-finite value.
Result<std::vector<OutputFit>> compare_outputs(const Eigen::MatrixXd& measured, const Eigen::MatrixXd& simulated,
                                               const std::vector<std::string>& names);

}  // namespace riccati
