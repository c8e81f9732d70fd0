// Multi-pass identification, as the 1999 Eindhoven EKF toolbox runs it:
//
//     ekf(x0, Theta0, U, Y, T, model, R, Q, P, passes, order, s, inverse)
//
// Each pass filters the whole dataset. The first pass starts from
// [x0; theta0] and P0. Every later pass restarts the states and their
// covariance from the first pass's values and keeps theta and its covariance
// from the end of the previous pass (Hensen 1999, ch. 2). A pass is the
// on-line run of the filter over the samples (online_runner.hpp), so a
// session streaming the same samples gives the first pass's estimates.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <stop_token>
#include <vector>

#include "engine/data/dataset.hpp"
#include "engine/estimation/binding.hpp"
#include "engine/estimation/online_runner.hpp"
#include "engine/estimation/uncertainty.hpp"
#include "engine/filters/filter.hpp"
#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

struct IdentificationSettings {
  FilterSettings filter;
  InitialEstimate initial;  // [x0; theta0] and P0 of the first pass
  int passes = 1;
  // Trial identification: filter only samples [first_sample, end_sample)
  // (end_sample < 0 means to the end). The toolbox's "trial".
  Eigen::Index first_sample = 0;
  Eigen::Index end_sample = -1;
  // The parameters' bounds [ntheta] the estimate is held within after every
  // sample (empty: none; the model's own bounds are the usual ones).
  Eigen::VectorXd theta_lower, theta_upper;
  // [ny x N] of the whole dataset: 1 for a sample used, 0 for one left out
  // (a sample with an output left out is a prediction without an update);
  // empty: every sample used.
  Eigen::ArrayXXd mask;
  // Which covariance the estimate's intervals come from (theta_std).
  CovarianceChoice covariance = CovarianceChoice::kAuto;
};

struct PassResult {
  Eigen::MatrixXd theta_trace;     // [ntheta x N] estimate after each sample (the toolbox's Trace)
  Eigen::VectorXd theta_final;     // [ntheta] at the end of the pass
  Eigen::VectorXd theta_mean;      // [ntheta] mean over the pass
  Eigen::VectorXd theta_std;       // [ntheta] sqrt(diag P) at the end of the pass
  Eigen::VectorXd innovation_rms;  // [ny]
  double nis_mean = 0.0;           // mean normalised innovation squared (about ny for a consistent filter)
};

struct IdentificationResult {
  std::vector<std::string> param_names;
  std::vector<PassResult> passes;
  Eigen::VectorXd theta;        // final estimate (end of the last pass)
  Eigen::VectorXd theta_mean;   // mean over the last pass (what the toolbox reports)
  // The standard errors of theta_mean, and their covariance [ntheta x
  // ntheta]: output error's at that estimate (point_uncertainty.hpp), or,
  // where the model cannot be simulated there, the filter's P times the
  // passes. covariance_method says which.
  Eigen::VectorXd theta_std;
  Eigen::MatrixXd theta_covariance;
  std::string covariance_method;
  // [ntheta] one Gauss-Newton step of output error from theta_mean: how far
  // the passes still are from the simulation error's optimum (0 where the
  // filter's P is used).
  Eigen::VectorXd theta_step;
  // [ntheta] 95 % intervals: the optimum's (theta_mean + theta_step -+ 1.96
  // theta_std), widened to hold theta_mean where it lies outside.
  Eigen::VectorXd ci_lower, ci_upper;
  Eigen::VectorXd filter_theta_std;  // sqrt(diag P) of the parameters at the end (the toolbox's std)
  Eigen::MatrixXd covariance;   // [nz x nz] the filter's P at the end
  Eigen::VectorXd t;            // [N] sample times filtered
  Eigen::MatrixXd x_trace;      // [nx x N] state estimates of the last pass
  Eigen::MatrixXd y_model;      // [ny x N] model outputs g(x, theta) along the last pass (the toolbox's Ymod)
  Eigen::MatrixXd innovations;  // [ny x N] innovations of the last pass
  std::vector<std::string> warnings;  // parameters held at a bound in the last pass; of the uncertainty
};

struct IdentificationProgress {
  int pass = 0;              // 1-based
  int passes = 0;
  Eigen::Index sample = 0;   // samples done in the pass (after a failure: those before the one that failed)
  Eigen::Index samples = 0;
  const Eigen::VectorXd* state = nullptr;  // the estimate of [x; theta] now
};

// Called after every sample; keep it cheap (throttle in the callback).
using ProgressCallback = std::function<void(const IdentificationProgress&)>;

// Where a run that was interrupted resumes: the passes it completed and the
// covariance of [x; theta] at the end of the last one. A later pass depends
// on the earlier ones only through theta and its covariance, so the resumed
// run's result is the uninterrupted run's, bit for bit.
struct IdentificationCheckpoint {
  std::vector<PassResult> passes;
  Eigen::MatrixXd covariance;  // [nz x nz] at the end of passes.back()
};

// Called after every pass but the last, with the pass (1-based), its result
// and the covariance at its end: what a checkpoint stores. An error from it
// ends the run.
using PassCallback = std::function<Status(int pass, const PassResult& result, const Eigen::MatrixXd& covariance)>;

// How a run is observed, stopped and resumed; all optional.
struct IdentificationHooks {
  ProgressCallback progress;
  PassCallback pass_done;
  std::stop_token stop;  // checked between samples: a stop request ends the run with kCancelled
  const IdentificationCheckpoint* resume = nullptr;  // start after the passes it holds
};

Status validate(const IdentificationSettings& settings, const Model& model);

// Runs the identification.
Result<IdentificationResult> identify(ModelPtr model, const Dataset& data, const IdentificationSettings& settings,
                                      const IdentificationHooks& hooks = {});

}  // namespace riccati
