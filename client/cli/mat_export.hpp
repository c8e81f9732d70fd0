// `riccati result JOB --export FILE.mat`: a result as MATLAB variables in
// the 1999 toolbox's layout (a row per signal, a column per sample, as its
// T, U, Y), written with matio (level 5, as MATLAB's -v7).
//
// An identification (the iterated filter): T [1 x N]; Theta [ntheta x 1],
// the mean over the last pass (what the toolbox reports); ThetaFinal and
// ThetaStd [ntheta x 1] at the end; Trace [ntheta x N], the estimate after
// each sample of the last pass; X [nx x N]; Ymod [ny x N], the model's
// outputs along it; Innovations [ny x N]; P [nz x nz] at the end; ParamNames
// (a cell array of the parameters' names).
// A validation: T [1 x N]; Y [ny x N] measured; Ymod [ny x N] simulated;
// Theta [ntheta x 1] simulated with; X0 [nx x 1]; OutputNames.
#pragma once

#include <optional>
#include <string>

#include "riccati/v1/jobs.pb.h"

namespace riccati::cli {

// Writes `r` to `path`; returns what went wrong, if anything (a kind of
// result the layout has no place for: output error, likelihood, smoothing).
std::optional<std::string> write_result_mat(const v1::JobResult& r, const std::string& path);

}  // namespace riccati::cli
