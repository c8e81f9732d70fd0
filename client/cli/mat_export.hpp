// `riccati result JOB --export FILE.mat`: a result as MATLAB variables in
// the 1999 toolbox's layout (a row per signal, a column per sample, as its
// T, U, Y), written with matio (level 5, as MATLAB's -v7). Every kind of
// result; the rows are named by cell arrays of names (StateNames,
// ParamNames, OutputNames, Names), the same names as the CSV's columns
// (docs/results.md).
//
// An identification (the iterated filter): T [1 x N]; Theta [ntheta x 1],
// the mean over the last pass (what the toolbox reports); ThetaFinal and
// ThetaStd [ntheta x 1] at the end; Trace [ntheta x N], the estimate after
// each sample of the last pass; X [nx x N]; Ymod [ny x N], the model's
// outputs along it; Innovations [ny x N]; P [nz x nz] at the end.
// Output error and maximum likelihood (as nlgreyest's): Method ('oe',
// 'ml'); Theta, ThetaStd, ThetaLower, ThetaUpper (95 %), Fixed (1, 0)
// [ntheta x 1]; Covariance, Correlation [ntheta x ntheta]; Cost, Sigma2,
// CostHistory; X0, X0Std [nx x experiments]; the samples of every
// experiment one after the other: Experiment (1, 2, ...), T [1 x N], Y,
// Ymod, Residuals (Y - Ymod, the output's unit), ResidualsNormalised (what
// the diagnostics test), Used (1, 0) [ny x N]; ML: ProcessNoise and
// MeasurementNoise with their ...Std.
// A smoothing: T [1 x N]; Z, ZStd [nz x N] smoothed, ZFiltered,
// ZFilteredStd the filter's, of [x; theta] named by Names; Ymod,
// Innovations [ny x N].
// A validation: T [1 x N]; Y [ny x N] measured; Ymod [ny x N] simulated;
// Residuals = Y - Ymod; Theta [ntheta x 1] simulated with; X0 [nx x 1].
#pragma once

#include <optional>
#include <string>

#include "estimation_output.hpp"
#include "riccati/v1/jobs.pb.h"

namespace riccati::cli {

// Writes `r` to `path`, its rows named from `names` (the job's model's;
// numbered where empty); returns what went wrong, if anything.
std::optional<std::string> write_result_mat(const v1::JobResult& r, const ModelNames& names, const std::string& path);

}  // namespace riccati::cli
