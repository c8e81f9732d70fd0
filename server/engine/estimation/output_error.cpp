#include "engine/estimation/output_error.hpp"

#include <ceres/ceres.h>
#include <glog/logging.h>

#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <string>

#include "engine/estimation/sensitivity.hpp"
#include "engine/estimation/uncertainty.hpp"

namespace riccati {
namespace {

// Counts shared by every experiment's cost: what the result reports.
struct Counters {
  int evaluations = 0;
  int jacobian_evaluations = 0;
  Status last_failure;  // the last simulation that failed, for the message if nothing works
};

// One experiment's residuals W^1/2 m (y_model - y) over [theta in solver
// coordinates; x0], and their Jacobian from the sensitivities.
class ExperimentCost final : public ceres::CostFunction {
 public:
  ExperimentCost(const Experiment& experiment, SensitivitySimulator simulator, const ParameterSettings& parameters,
                 Eigen::VectorXd weights, Counters* counters)
      : experiment_(experiment),
        simulator_(std::move(simulator)),
        parameters_(parameters),
        weights_(std::move(weights)),
        counters_(counters),
        theta_(parameters.theta0.size()) {
    const Model& model = simulator_.model();
    set_num_residuals(static_cast<int>(experiment.data.size() * model.ny()));
    mutable_parameter_block_sizes()->push_back(model.ntheta());
    mutable_parameter_block_sizes()->push_back(model.nx());
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const Model& model = simulator_.model();
    const Eigen::Index ntheta = model.ntheta(), nx = model.nx(), ny = model.ny(), N = experiment_.data.size();
    for (Eigen::Index i = 0; i < ntheta; ++i) theta_[i] = from_solver(parameters_, i, parameters[0][i]);
    const Eigen::Map<const Eigen::VectorXd> x0(parameters[1], nx);
    const bool theta_jacobian = jacobians != nullptr && jacobians[0] != nullptr;
    const bool x0_jacobian = jacobians != nullptr && jacobians[1] != nullptr;
    const Status simulated =
        simulator_.simulate(experiment_.data.t, experiment_.data.u, x0, theta_, theta_jacobian || x0_jacobian, &record_);
    ++counters_->evaluations;
    if (theta_jacobian || x0_jacobian) ++counters_->jacobian_evaluations;
    if (!simulated.is_ok()) {
      counters_->last_failure = simulated;
      return false;  // Ceres rejects the step and shrinks the trust region
    }
    const bool masked = experiment_.mask.size() != 0;
    for (Eigen::Index k = 0; k < N; ++k) {
      for (Eigen::Index i = 0; i < ny; ++i) {
        const Eigen::Index row = k * ny + i;
        const double w = weights_[i] * (masked ? experiment_.mask(i, k) : 1.0);
        residuals[row] = w * (record_.y(i, k) - experiment_.data.y(i, k));
        if (theta_jacobian) {
          double* jrow = jacobians[0] + row * ntheta;
          for (Eigen::Index j = 0; j < ntheta; ++j) {
            jrow[j] = w * record_.dy_dtheta(row, j) * theta_per_phi(parameters_, j, theta_[j]);
          }
        }
        if (x0_jacobian) {
          double* jrow = jacobians[1] + row * nx;
          for (Eigen::Index j = 0; j < nx; ++j) jrow[j] = w * record_.dy_dx0(row, j);
        }
      }
    }
    return true;
  }

  // The simulation with sensitivities at (theta, x0): the final analysis.
  Result<const SimulatedRecord*> analyse(const Eigen::VectorXd& theta, const Eigen::VectorXd& x0) const {
    RICCATI_RETURN_IF_ERROR(simulator_.simulate(experiment_.data.t, experiment_.data.u, x0, theta, true, &record_));
    return &record_;
  }

 private:
  const Experiment& experiment_;
  mutable SensitivitySimulator simulator_;
  const ParameterSettings& parameters_;
  const Eigen::VectorXd weights_;
  Counters* const counters_;
  mutable Eigen::VectorXd theta_;
  mutable SimulatedRecord record_;
};

// Progress, the cost after each iteration, and cancellation.
class Watcher final : public ceres::IterationCallback {
 public:
  Watcher(const EstimationHooks& hooks, std::vector<double>* history) : hooks_(hooks), history_(history) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& summary) override {
    history_->push_back(summary.cost);
    if (hooks_.progress) hooks_.progress(EstimationProgress{summary.iteration, summary.cost});
    return hooks_.stop.stop_requested() ? ceres::SOLVER_ABORT : ceres::SOLVER_CONTINUE;
  }

 private:
  const EstimationHooks& hooks_;
  std::vector<double>* history_;
};

std::string number(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.6g", v);
  return buffer;
}

std::string join(const Eigen::VectorXd& v) {
  std::string out;
  for (Eigen::Index i = 0; i < v.size(); ++i) out += (i > 0 ? ", " : "") + number(v[i]);
  return out;
}

// The fit of each output over the samples used.
Result<std::vector<OutputFit>> fits_over_mask(const Eigen::MatrixXd& y, const Eigen::MatrixXd& y_model,
                                              const Eigen::ArrayXXd& mask, const std::vector<std::string>& names) {
  std::vector<OutputFit> fits;
  for (Eigen::Index i = 0; i < y.rows(); ++i) {
    const Eigen::Index used = static_cast<Eigen::Index>(mask.row(i).sum());
    Eigen::MatrixXd a(1, used), b(1, used);
    for (Eigen::Index k = 0, c = 0; k < y.cols(); ++k) {
      if (mask(i, k) == 0.0) continue;
      a(0, c) = y(i, k);
      b(0, c++) = y_model(i, k);
    }
    RICCATI_ASSIGN_OR_RETURN(std::vector<OutputFit> one, compare_outputs(a, b, {names[static_cast<std::size_t>(i)]}));
    fits.push_back(one.front());
  }
  return fits;
}

// Warnings for parameters that ended on a bound: the optimum of the
// criterion may lie beyond it.
void warn_active_bounds(const ParameterSettings& p, const std::vector<std::string>& names, EstimationResult* r) {
  for (Eigen::Index i = 0; i < r->theta.size(); ++i) {
    if (p.fixed[static_cast<std::size_t>(i)]) continue;
    const double v = r->theta[i], tolerance = 1e-9 * std::max(1.0, std::abs(v));
    const char* which = std::abs(v - p.lower[i]) <= tolerance ? "lower" : std::abs(v - p.upper[i]) <= tolerance ? "upper" : nullptr;
    if (which != nullptr) {
      r->warnings.push_back(names[static_cast<std::size_t>(i)] + " ended on its " + which + " bound " + number(v) +
                            ": the best fit may lie beyond it");
    }
  }
}

// Ceres reports through glog; riccati reports what the optimiser did in the
// result (termination, failures) and logs through spdlog, so glog is kept
// quiet (it would write to stderr before any InitGoogleLogging).
void quiet_ceres_logging() {
  static std::once_flag once;
  std::call_once(once, [] { FLAGS_minloglevel = google::GLOG_FATAL; });
}

}  // namespace

Result<EstimationResult> output_error(ModelPtr model, const std::vector<Experiment>& experiments,
                                      const OutputErrorSettings& settings, const EstimationHooks& hooks) {
  if (model == nullptr) return invalid_argument("no model given");
  if (experiments.empty()) return invalid_argument("output error needs at least one experiment");
  quiet_ceres_logging();
  const ParameterSettings& p = settings.parameters;
  RICCATI_RETURN_IF_ERROR(validate(p, *model));
  RICCATI_RETURN_IF_ERROR(validate(settings.simulation.integrator));
  const int ntheta = model->ntheta(), nx = model->nx(), ny = model->ny();
  Eigen::VectorXd weights = Eigen::VectorXd::Ones(ny);
  const bool noise_known = settings.output_sigma.size() != 0;
  if (noise_known) {
    if (settings.output_sigma.size() != ny || !(settings.output_sigma.array() > 0.0).all() ||
        !settings.output_sigma.allFinite()) {
      return invalid_argument("the outputs' noise standard deviations need " + std::to_string(ny) +
                              " positive values");
    }
    weights = settings.output_sigma.cwiseInverse();
  }
  for (std::size_t e = 0; e < experiments.size(); ++e) RICCATI_RETURN_IF_ERROR(validate(experiments[e], *model, e));

  // The unknowns: theta in solver coordinates, and each experiment's x0.
  Eigen::VectorXd phi(ntheta);
  for (Eigen::Index i = 0; i < ntheta; ++i) phi[i] = to_solver(p, i, p.theta0[i]);
  std::vector<Eigen::VectorXd> x0s;
  for (const Experiment& e : experiments) x0s.push_back(e.x0);

  Counters counters;
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::TAKE_OWNERSHIP;
  problem_options.cost_function_ownership = ceres::TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  std::vector<const ExperimentCost*> costs;
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    const Experiment& ex = experiments[e];
    const bool any_x0 = std::find(ex.estimate_x0.begin(), ex.estimate_x0.end(), true) != ex.estimate_x0.end();
    RICCATI_ASSIGN_OR_RETURN(SensitivitySimulator simulator,
                             SensitivitySimulator::create(model, settings.simulation, any_x0));
    auto* cost = new ExperimentCost(ex, std::move(simulator), p, weights, &counters);
    costs.push_back(cost);
    problem.AddResidualBlock(cost, nullptr, phi.data(), x0s[e].data());
    if (!any_x0) {
      problem.SetParameterBlockConstant(x0s[e].data());
    } else {
      std::vector<int> fixed;
      for (int i = 0; i < nx; ++i) {
        if (!ex.estimate_x0[static_cast<std::size_t>(i)]) fixed.push_back(i);
      }
      if (!fixed.empty()) problem.SetManifold(x0s[e].data(), new ceres::SubsetManifold(nx, fixed));
    }
  }
  std::vector<int> fixed_theta;
  for (int i = 0; i < ntheta; ++i) {
    if (p.fixed[static_cast<std::size_t>(i)]) fixed_theta.push_back(i);
  }
  if (static_cast<int>(fixed_theta.size()) == ntheta) {
    problem.SetParameterBlockConstant(phi.data());
  } else {
    if (!fixed_theta.empty()) problem.SetManifold(phi.data(), new ceres::SubsetManifold(ntheta, fixed_theta));
    for (int i = 0; i < ntheta; ++i) {
      if (std::isfinite(p.lower[i]) && !p.fixed[static_cast<std::size_t>(i)]) {
        problem.SetParameterLowerBound(phi.data(), i, to_solver(p, i, p.lower[i]));
      }
      if (std::isfinite(p.upper[i]) && !p.fixed[static_cast<std::size_t>(i)]) {
        problem.SetParameterUpperBound(phi.data(), i, to_solver(p, i, p.upper[i]));
      }
    }
  }

  EstimationResult result;
  result.param_names = model->param_names();
  result.gradient = "exact: forward sensitivities of the simulation";
  Watcher watcher(hooks, &result.cost_history);
  ceres::Solver::Options options;
  options.minimizer_type = ceres::TRUST_REGION;
  options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = settings.optimizer.max_iterations;
  options.function_tolerance = settings.optimizer.function_tolerance;
  options.gradient_tolerance = settings.optimizer.gradient_tolerance;
  options.parameter_tolerance = settings.optimizer.parameter_tolerance;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  options.minimizer_progress_to_stdout = false;
  options.callbacks.push_back(&watcher);
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  if (hooks.stop.stop_requested()) {
    return cancelled("output error cancelled after iteration " + std::to_string(summary.iterations.size()));
  }
  if (summary.termination_type == ceres::FAILURE || !summary.IsSolutionUsable()) {
    std::string why = summary.message;
    if (!counters.last_failure.is_ok()) why += "; the simulation failed: " + counters.last_failure.message();
    return failed_precondition("output error found no step it could take from theta = [" + join(p.theta0) +
                               "]: " + why);
  }
  result.iterations = static_cast<int>(summary.iterations.size()) - 1;
  result.evaluations = counters.evaluations;
  result.jacobian_evaluations = counters.jacobian_evaluations;
  result.converged = summary.termination_type == ceres::CONVERGENCE;
  result.termination = summary.message;
  result.cost = summary.final_cost;
  result.theta.resize(ntheta);
  for (Eigen::Index i = 0; i < ntheta; ++i) result.theta[i] = from_solver(p, i, phi[i]);
  result.fixed = p.fixed;

  // The information J'J at the estimate over the free unknowns, in natural
  // coordinates: free theta first, then each experiment's estimated x0.
  std::vector<std::string> names;
  Eigen::VectorXd values(0);
  std::vector<Eigen::Index> theta_columns(static_cast<std::size_t>(ntheta), -1);
  for (int i = 0; i < ntheta; ++i) {
    if (p.fixed[static_cast<std::size_t>(i)]) continue;
    theta_columns[static_cast<std::size_t>(i)] = static_cast<Eigen::Index>(names.size());
    names.push_back(model->param_names()[static_cast<std::size_t>(i)]);
  }
  std::vector<std::vector<Eigen::Index>> x0_columns(experiments.size());
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    x0_columns[e].assign(static_cast<std::size_t>(nx), -1);
    for (int i = 0; i < nx; ++i) {
      if (experiments[e].estimate_x0.empty() || !experiments[e].estimate_x0[static_cast<std::size_t>(i)]) continue;
      x0_columns[e][static_cast<std::size_t>(i)] = static_cast<Eigen::Index>(names.size());
      names.push_back(model->state_names()[static_cast<std::size_t>(i)] + "(0)" +
                      (experiments.size() > 1 ? " of experiment " + std::to_string(e + 1) : ""));
    }
  }
  const Eigen::Index unknowns = static_cast<Eigen::Index>(names.size());
  values.resize(unknowns);
  Eigen::MatrixXd information = Eigen::MatrixXd::Zero(unknowns, unknowns);
  double used_residuals = 0.0;
  Eigen::MatrixXd J;
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    const Experiment& ex = experiments[e];
    RICCATI_ASSIGN_OR_RETURN(const SimulatedRecord* r, costs[e]->analyse(result.theta, x0s[e]));
    const Eigen::Index N = ex.data.size();
    ExperimentResult out;
    out.x0 = x0s[e];
    out.x0_std = Eigen::VectorXd::Zero(nx);
    out.x0_estimated = ex.estimate_x0.empty() ? std::vector<bool>(static_cast<std::size_t>(nx), false) : ex.estimate_x0;
    out.t = ex.data.t;
    out.y_measured = ex.data.y;
    out.y_model = r->y;
    out.mask = ex.mask.size() != 0 ? ex.mask : Eigen::ArrayXXd::Ones(ny, N);
    used_residuals += out.mask.sum();
    J.setZero(N * ny, unknowns);
    for (Eigen::Index k = 0; k < N; ++k) {
      for (Eigen::Index i = 0; i < ny; ++i) {
        const Eigen::Index row = k * ny + i;
        const double w = weights[i] * out.mask(i, k);
        for (int j = 0; j < ntheta; ++j) {
          const Eigen::Index c = theta_columns[static_cast<std::size_t>(j)];
          if (c >= 0) J(row, c) = w * r->dy_dtheta(row, j);
        }
        for (int j = 0; j < nx; ++j) {
          const Eigen::Index c = x0_columns[e][static_cast<std::size_t>(j)];
          if (c >= 0) J(row, c) = w * r->dy_dx0(row, j);
        }
      }
    }
    information.noalias() += J.transpose() * J;
    for (int j = 0; j < nx; ++j) {
      const Eigen::Index c = x0_columns[e][static_cast<std::size_t>(j)];
      if (c >= 0) values[c] = out.x0[j];
    }
    result.experiments.push_back(std::move(out));
  }
  for (int j = 0; j < ntheta; ++j) {
    const Eigen::Index c = theta_columns[static_cast<std::size_t>(j)];
    if (c >= 0) values[c] = result.theta[j];
  }
  const double dof = used_residuals - static_cast<double>(unknowns);
  result.sigma2 = noise_known ? 1.0 : (dof > 0.0 ? 2.0 * result.cost / dof : std::numeric_limits<double>::infinity());
  const Uncertainty u = uncertainty_from_information(information, result.sigma2, names, values);
  result.warnings = u.warnings;
  warn_active_bounds(p, model->param_names(), &result);
  result.theta_std = Eigen::VectorXd::Zero(ntheta);
  result.covariance = Eigen::MatrixXd::Zero(ntheta, ntheta);
  result.correlation = Eigen::MatrixXd::Identity(ntheta, ntheta);
  result.ci_lower = result.theta;
  result.ci_upper = result.theta;
  for (int a = 0; a < ntheta; ++a) {
    const Eigen::Index ca = theta_columns[static_cast<std::size_t>(a)];
    if (ca < 0) continue;
    result.theta_std[a] = u.std[ca];
    for (int b = 0; b < ntheta; ++b) {
      const Eigen::Index cb = theta_columns[static_cast<std::size_t>(b)];
      if (cb < 0) continue;
      result.covariance(a, b) = u.covariance(ca, cb);
      result.correlation(a, b) = u.correlation(ca, cb);
    }
    confidence_interval(result.theta[a], result.theta_std[a], p.log_scale[static_cast<std::size_t>(a)],
                        &result.ci_lower[a], &result.ci_upper[a]);
  }
  // An exact fit (noise-free data, cost 0) has no residual scale: its
  // residuals are 0 either way.
  const double sigma_scale = result.sigma2 > 0.0 && std::isfinite(result.sigma2) ? std::sqrt(result.sigma2) : 1.0;
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    ExperimentResult& out = result.experiments[e];
    for (int j = 0; j < nx; ++j) {
      const Eigen::Index c = x0_columns[e][static_cast<std::size_t>(j)];
      if (c >= 0) out.x0_std[j] = u.std[c];
    }
    // (y - y_model) / sigma: the given sigma, or sqrt(s2) when unknown.
    out.residuals = ((out.y_measured - out.y_model).array().colwise() * weights.array()).matrix() / sigma_scale;
    out.residuals = (out.residuals.array() * out.mask).matrix();
    RICCATI_ASSIGN_OR_RETURN(out.fits, fits_over_mask(out.y_measured, out.y_model, out.mask, model->output_names()));
    RICCATI_ASSIGN_OR_RETURN(out.diagnostics, diagnose(out, experiments[e].data.u));
  }
  return result;
}

}  // namespace riccati
