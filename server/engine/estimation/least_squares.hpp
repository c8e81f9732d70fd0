// What output error and maximum likelihood share of their Ceres problems
// (private to estimation/): the unknowns as parameter blocks (theta in
// solver coordinates with its bounds and fixed entries; each experiment's
// initial states, constant where given), the solver's settings, and the
// iteration callback that records the cost, reports progress and stops on
// request.
#pragma once

#include <ceres/ceres.h>

#include <vector>

#include "engine/estimation/estimate.hpp"

namespace riccati {

// The parameters and initial states as Ceres sees them. Each residual block
// takes `phi` and one experiment's `x0[e]` (as its first two blocks);
// constrain() is called once they are all added.
struct LeastSquaresUnknowns {
  Eigen::VectorXd phi;              // [ntheta] theta in solver coordinates
  std::vector<Eigen::VectorXd> x0;  // [experiment] [nx]

  LeastSquaresUnknowns(const ParameterSettings& parameters, const std::vector<Experiment>& experiments);
  // Fixed parameters, bounds, and the initial states that are not estimated.
  void constrain(ceres::Problem& problem, const ParameterSettings& parameters,
                 const std::vector<Experiment>& experiments);
  Eigen::VectorXd theta(const ParameterSettings& parameters) const;
};

bool estimates_x0(const Experiment& experiment);

// Records the cost after each iteration, reports it, stops on request.
class IterationWatcher final : public ceres::IterationCallback {
 public:
  // `offset`: what is added to the optimiser's cost to give the criterion
  // that is reported (0 for output error; maximum likelihood's constant).
  IterationWatcher(const EstimationHooks& hooks, std::vector<double>* history, double offset = 0.0)
      : hooks_(hooks), history_(history), offset_(offset) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& summary) override;

 private:
  const EstimationHooks& hooks_;
  std::vector<double>* history_;
  const double offset_;
};

// Levenberg-Marquardt with a dense QR (few unknowns, many residuals), one
// thread, silent; `watcher` attached. On a problem with bounds Ceres runs a
// projected line search along each step; `line_search` says how it fits its
// trials: CUBIC evaluates each with its gradient (worth it when the gradient
// comes with the residuals), BISECTION the cost alone (when a gradient costs
// many more evaluations, as central differences do).
ceres::Solver::Options solver_options(const OptimizerSettings& settings, IterationWatcher* watcher,
                                      ceres::LineSearchInterpolationType line_search);

// Ceres reports through glog; riccati reports what the optimiser did in its
// results and logs through spdlog, so glog is kept quiet (it would write to
// stderr before any InitGoogleLogging).
void quiet_ceres_logging();

}  // namespace riccati
