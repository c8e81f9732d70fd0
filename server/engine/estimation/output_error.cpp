#include "engine/estimation/output_error.hpp"

#include <ceres/ceres.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <string>

#include "engine/estimation/least_squares.hpp"
#include "engine/estimation/point_uncertainty.hpp"
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
    const Simulation& simulation = simulate(x0, theta_jacobian || x0_jacobian);
    if (!simulation.status.is_ok()) {
      counters_->last_failure = simulation.status;
      return false;  // Ceres rejects the step and shrinks the trust region
    }
    const SimulatedRecord& record = simulation.record;
    const bool masked = experiment_.mask.size() != 0;
    for (Eigen::Index k = 0; k < N; ++k) {
      for (Eigen::Index i = 0; i < ny; ++i) {
        const Eigen::Index row = k * ny + i;
        const double w = weights_[i] * (masked ? experiment_.mask(i, k) : 1.0);
        residuals[row] = w * (record.y(i, k) - experiment_.data.y(i, k));
        if (theta_jacobian) {
          double* jrow = jacobians[0] + row * ntheta;
          for (Eigen::Index j = 0; j < ntheta; ++j) {
            jrow[j] = w * record.dy_dtheta(row, j) * theta_per_phi(parameters_, j, theta_[j]);
          }
        }
        if (x0_jacobian) {
          double* jrow = jacobians[1] + row * nx;
          for (Eigen::Index j = 0; j < nx; ++j) jrow[j] = w * record.dy_dx0(row, j);
        }
      }
    }
    return true;
  }

  // The simulation with sensitivities at (theta, x0): the final analysis.
  Result<const SimulatedRecord*> analyse(const Eigen::VectorXd& theta, const Eigen::VectorXd& x0) const {
    theta_ = theta;
    const Simulation& simulation = simulate(x0, true);
    RICCATI_RETURN_IF_ERROR(simulation.status);
    return &simulation.record;
  }

 private:
  // A simulation of the record, and the point it was made at.
  struct Simulation {
    bool made = false, sensitivities = false;
    Eigen::VectorXd theta, x0;
    Status status;
    SimulatedRecord record;
  };

  // The simulation at (theta_, x0), with sensitivities if asked, made only
  // when neither of the last two is it. Ceres evaluates a point more than
  // once: in the line search with its gradient, then its cost as the
  // candidate, then its Jacobian once accepted; a step projected onto the
  // bounds lands on the same point again and again (failing the same way
  // each time). The analysis after the fit is at the last accepted point,
  // one before the candidate that ended the fit.
  const Simulation& simulate(const Eigen::Ref<const Eigen::VectorXd>& x0, bool sensitivities) const {
    for (std::size_t i = 0; i < simulations_.size(); ++i) {
      const Simulation& s = simulations_[i];
      if (s.made && (s.sensitivities || !sensitivities) && s.theta == theta_ && s.x0 == x0) {
        if (i > 0) std::swap(simulations_[0], simulations_[i]);
        return simulations_[0];
      }
    }
    std::swap(simulations_[0], simulations_[1]);  // the older one is overwritten
    Simulation& s = simulations_[0];
    ++counters_->evaluations;
    if (sensitivities) ++counters_->jacobian_evaluations;
    s.status = simulator_.simulate(experiment_.data.t, experiment_.data.u, x0, theta_, sensitivities, &s.record);
    s.made = true;
    s.sensitivities = sensitivities;
    s.theta = theta_;
    s.x0 = x0;
    return s;
  }

  const Experiment& experiment_;
  mutable SensitivitySimulator simulator_;
  const ParameterSettings& parameters_;
  const Eigen::VectorXd weights_;
  Counters* const counters_;
  mutable Eigen::VectorXd theta_;
  mutable std::array<Simulation, 2> simulations_;  // the latest first
};


std::string join(const Eigen::VectorXd& v) {
  std::string out;
  for (Eigen::Index i = 0; i < v.size(); ++i) out += (i > 0 ? ", " : "") + message_number(v[i]);
  return out;
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

  LeastSquaresUnknowns unknowns(p, experiments);
  Counters counters;
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::TAKE_OWNERSHIP;
  problem_options.cost_function_ownership = ceres::TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  std::vector<const ExperimentCost*> costs;
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    RICCATI_ASSIGN_OR_RETURN(SensitivitySimulator simulator,
                             SensitivitySimulator::create(model, settings.simulation, estimates_x0(experiments[e])));
    auto* cost = new ExperimentCost(experiments[e], std::move(simulator), p, weights, &counters);
    costs.push_back(cost);
    problem.AddResidualBlock(cost, nullptr, unknowns.phi.data(), unknowns.x0[e].data());
  }
  unknowns.constrain(problem, p, experiments);

  EstimationResult result;
  result.param_names = model->param_names();
  result.gradient = "exact: forward sensitivities of the simulation";
  IterationWatcher watcher(hooks, &result.cost_history);
  // The line search's trials with their gradients: a trial that is accepted
  // (most are) then has its Jacobian ready, one sensitivity simulation where
  // the cost alone and then the Jacobian would take a simulation more.
  const ceres::Solver::Options options = solver_options(settings.optimizer, &watcher, ceres::CUBIC);
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
  // Ceres lists the start as iteration 0; with every unknown held it runs
  // none and lists nothing (not -1: unsigned in the API, 4294967295).
  result.iterations = std::max(0, static_cast<int>(summary.iterations.size()) - 1);
  result.evaluations = counters.evaluations;
  result.jacobian_evaluations = counters.jacobian_evaluations;
  result.converged = summary.termination_type == ceres::CONVERGENCE;
  result.termination = summary.message;
  result.cost = summary.final_cost;
  result.theta = unknowns.theta(p);
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
  const Eigen::Index free_count = static_cast<Eigen::Index>(names.size());
  values.resize(free_count);
  LeastSquaresCovariance information(free_count);
  double used_residuals = 0.0;
  Eigen::MatrixXd J;
  Eigen::VectorXd residuals;
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    const Experiment& ex = experiments[e];
    RICCATI_ASSIGN_OR_RETURN(const SimulatedRecord* r, costs[e]->analyse(result.theta, unknowns.x0[e]));
    const Eigen::Index N = ex.data.size();
    ExperimentResult out;
    out.x0 = unknowns.x0[e];
    out.x0_std = Eigen::VectorXd::Zero(nx);
    out.x0_estimated = ex.estimate_x0.empty() ? std::vector<bool>(static_cast<std::size_t>(nx), false) : ex.estimate_x0;
    out.t = ex.data.t;
    out.y_measured = ex.data.y;
    out.y_model = r->y;
    out.mask = ex.mask.size() != 0 ? ex.mask : Eigen::ArrayXXd::Ones(ny, N);
    used_residuals += out.mask.sum();
    J.setZero(N * ny, free_count);
    residuals.resize(N * ny);
    for (Eigen::Index k = 0; k < N; ++k) {
      for (Eigen::Index i = 0; i < ny; ++i) {
        const Eigen::Index row = k * ny + i;
        const double w = weights[i] * out.mask(i, k);
        residuals[row] = w * (r->y(i, k) - ex.data.y(i, k));
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
    information.add(J, residuals, ny);
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
  // ln L of Gaussian residuals, output i with std sigma_i = 1 / weights[i]:
  // -cost - sum ln sigma_i - n/2 ln 2 pi over the residuals used; with sigma
  // unknown (weights 1), at its maximum-likelihood estimate 2 cost / n, one
  // quantity more estimated.
  double log_weights = 0.0;
  for (const ExperimentResult& out : result.experiments) {
    log_weights += (out.mask.rowwise().sum().matrix().array() * weights.array().log()).sum();
  }
  constexpr double kLog2Pi = 1.8378770664093454836;  // ln(2 pi)
  if (noise_known) {
    set_information_criteria(-result.cost + log_weights - 0.5 * used_residuals * kLog2Pi,
                             static_cast<int>(free_count), used_residuals, &result);
  } else {
    const double sigma2_ml = 2.0 * result.cost / used_residuals;
    set_information_criteria(-0.5 * used_residuals * (kLog2Pi + std::log(sigma2_ml) + 1.0),
                             static_cast<int>(free_count) + 1, used_residuals, &result);
  }
  const double dof = used_residuals - static_cast<double>(free_count);
  result.sigma2 = noise_known ? 1.0 : (dof > 0.0 ? 2.0 * result.cost / dof : std::numeric_limits<double>::infinity());
  // An exact fit (noise-free data, cost 0) has no residual scale: its
  // residuals are 0 either way.
  const double sigma_scale = result.sigma2 > 0.0 && std::isfinite(result.sigma2) ? std::sqrt(result.sigma2) : 1.0;
  std::vector<bool> coloured(static_cast<std::size_t>(ny), false);  // an output whose residuals failed the whiteness test
  double signal = 0.0;
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    const ExperimentResult& out = result.experiments[e];
    signal += ((out.y_measured.array().colwise() * weights.array()).square() * out.mask).sum();
  }
  const bool exact = rounding_residuals(2.0 * result.cost, signal);
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    ExperimentResult& out = result.experiments[e];
    // (y - y_model) / sigma: the given sigma, or sqrt(s2) when unknown.
    out.residuals = ((out.y_measured - out.y_model).array().colwise() * weights.array()).matrix() / sigma_scale;
    out.residuals = (out.residuals.array() * out.mask).matrix();
    RICCATI_ASSIGN_OR_RETURN(out.fits, fits_over_mask(out.y_measured, out.y_model, out.mask, model->output_names()));
    RICCATI_ASSIGN_OR_RETURN(out.diagnostics, diagnose(out, experiments[e].data.u));
    if (exact) continue;
    for (const Eigen::Index i : out.diagnostics.non_white_outputs()) coloured[static_cast<std::size_t>(i)] = true;
  }
  const bool white = std::none_of(coloured.begin(), coloured.end(), [](bool c) { return c; });
  const Uncertainty u = information.uncertainty(settings.covariance, white, result.sigma2,
                                                dof > 0.0 ? used_residuals / dof : 1.0, names, values,
                                                &result.covariance_method);
  set_parameter_uncertainty(p, u, theta_columns, &result);
  if (!white) result.warnings.push_back(coloured_residuals_warning(*model, coloured, settings.covariance));
  warn_active_bounds(p, &result);
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    ExperimentResult& out = result.experiments[e];
    for (int j = 0; j < nx; ++j) {
      const Eigen::Index c = x0_columns[e][static_cast<std::size_t>(j)];
      if (c >= 0) out.x0_std[j] = u.std[c];
    }
  }
  return result;
}

}  // namespace riccati
