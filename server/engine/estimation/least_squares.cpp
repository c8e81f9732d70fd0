#include "engine/estimation/least_squares.hpp"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <mutex>

namespace riccati {

bool estimates_x0(const Experiment& e) {
  return std::find(e.estimate_x0.begin(), e.estimate_x0.end(), true) != e.estimate_x0.end();
}

LeastSquaresUnknowns::LeastSquaresUnknowns(const ParameterSettings& p, const std::vector<Experiment>& experiments)
    : phi(p.theta0.size()) {
  for (Eigen::Index i = 0; i < phi.size(); ++i) phi[i] = to_solver(p, i, p.theta0[i]);
  for (const Experiment& e : experiments) x0.push_back(e.x0);
}

void LeastSquaresUnknowns::constrain(ceres::Problem& problem, const ParameterSettings& p,
                                     const std::vector<Experiment>& experiments) {
  const int ntheta = static_cast<int>(phi.size());
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    const Experiment& ex = experiments[e];
    const int nx = static_cast<int>(x0[e].size());
    if (!estimates_x0(ex)) {
      problem.SetParameterBlockConstant(x0[e].data());
      continue;
    }
    std::vector<int> given;
    for (int i = 0; i < nx; ++i) {
      if (!ex.estimate_x0[static_cast<std::size_t>(i)]) given.push_back(i);
    }
    if (!given.empty()) problem.SetManifold(x0[e].data(), new ceres::SubsetManifold(nx, given));
  }
  std::vector<int> fixed;
  for (int i = 0; i < ntheta; ++i) {
    if (p.fixed[static_cast<std::size_t>(i)]) fixed.push_back(i);
  }
  if (static_cast<int>(fixed.size()) == ntheta) {
    problem.SetParameterBlockConstant(phi.data());
    return;
  }
  if (!fixed.empty()) problem.SetManifold(phi.data(), new ceres::SubsetManifold(ntheta, fixed));
  for (int i = 0; i < ntheta; ++i) {
    if (p.fixed[static_cast<std::size_t>(i)]) continue;
    if (std::isfinite(p.lower[i])) problem.SetParameterLowerBound(phi.data(), i, to_solver(p, i, p.lower[i]));
    if (std::isfinite(p.upper[i])) problem.SetParameterUpperBound(phi.data(), i, to_solver(p, i, p.upper[i]));
  }
}

Eigen::VectorXd LeastSquaresUnknowns::theta(const ParameterSettings& p) const {
  Eigen::VectorXd out(phi.size());
  for (Eigen::Index i = 0; i < phi.size(); ++i) out[i] = from_solver(p, i, phi[i]);
  return out;
}

ceres::CallbackReturnType IterationWatcher::operator()(const ceres::IterationSummary& summary) {
  history_->push_back(summary.cost + offset_);
  if (hooks_.progress) hooks_.progress(EstimationProgress{summary.iteration, summary.cost + offset_});
  return hooks_.stop.stop_requested() ? ceres::SOLVER_ABORT : ceres::SOLVER_CONTINUE;
}

ceres::Solver::Options solver_options(const OptimizerSettings& settings, IterationWatcher* watcher,
                                      ceres::LineSearchInterpolationType line_search) {
  ceres::Solver::Options options;
  options.minimizer_type = ceres::TRUST_REGION;
  options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  options.linear_solver_type = ceres::DENSE_QR;
  options.line_search_interpolation_type = line_search;
  options.max_num_iterations = settings.max_iterations;
  options.function_tolerance = settings.function_tolerance;
  options.gradient_tolerance = settings.gradient_tolerance;
  options.parameter_tolerance = settings.parameter_tolerance;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  options.minimizer_progress_to_stdout = false;
  options.callbacks.push_back(watcher);
  return options;
}

void quiet_ceres_logging() {
  static std::once_flag once;
  std::call_once(once, [] { FLAGS_minloglevel = google::GLOG_FATAL; });
}

}  // namespace riccati
