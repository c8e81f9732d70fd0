#include "engine/estimation/max_likelihood.hpp"

#include <ceres/ceres.h>
#include <ceres/dynamic_numeric_diff_cost_function.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <string>

#include "engine/estimation/least_squares.hpp"
#include "engine/estimation/likelihood_sensitivity.hpp"
#include "engine/estimation/online_runner.hpp"
#include "engine/estimation/uncertainty.hpp"

namespace riccati {
namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();
constexpr double kLn10 = 2.302585092994045684;

// Where each unknown sits in the optimiser's vector v (solver coordinates:
// log theta for a log-scaled parameter, log of the noise levels).
struct Unknowns {
  std::vector<Eigen::Index> theta;            // [ntheta] index in v, or -1 (fixed)
  std::vector<std::vector<Eigen::Index>> x0;  // [experiment][nx] index in v, or -1 (given)
  std::vector<Eigen::Index> q, r;             // [nx], [ny] index in v, or -1 (given)
  Eigen::VectorXd start, lower, upper, typical;
  std::vector<std::string> names;
  std::vector<bool> log_scale;  // per entry of v: its natural value is exp(v)

  Eigen::Index size() const { return start.size(); }

  Eigen::Index add(const std::string& name, double start_value, double lo, double hi, bool log) {
    const Eigen::Index i = size();
    const auto grow = [&](Eigen::VectorXd& v, double value) {
      v.conservativeResize(i + 1);
      v[i] = value;
    };
    grow(start, log ? std::log(start_value) : start_value);
    grow(lower, log ? (lo > 0.0 ? std::log(lo) : -kInfinity) : lo);
    grow(upper, log ? std::log(hi) : hi);
    // The scale of a finite-difference step: the start's size (1 on a log scale).
    grow(typical, log ? 1.0 : std::max(std::abs(start_value), 1e-8));
    names.push_back(name);
    log_scale.push_back(log);
    return i;
  }
};

// The pieces of the model at a point v of the optimiser.
struct Point {
  Eigen::VectorXd theta;
  std::vector<Eigen::VectorXd> x0;
  Eigen::VectorXd q, r;
};

// The two sums of L over the experiments, and what the result shows of the
// run at the estimate.
struct Sums {
  double logdet = 0.0;     // sum ln det S_k
  double quadratic = 0.0;  // sum e_k' S_k^-1 e_k
  double measurements = 0.0;  // the scalar innovations: ny a sample measured
  double total() const { return 0.5 * (logdet + quadratic); }
};

class Likelihood {
 public:
  Likelihood(ModelPtr model, const std::vector<Experiment>& experiments, const MaxLikelihoodSettings& settings,
             const Unknowns& unknowns)
      : model_(std::move(model)),
        experiments_(experiments),
        settings_(settings),
        unknowns_(unknowns),
        runners_(experiments.size()),
        S_llt_(model_->ny()),
        noise_estimated_(settings.estimate_process_noise || settings.estimate_measurement_noise) {}

  Point point(const Eigen::VectorXd& v) const {
    const ParameterSettings& p = settings_.parameters;
    const int nx = model_->nx(), ny = model_->ny();
    Point out;
    out.theta = p.theta0;
    for (Eigen::Index j = 0; j < out.theta.size(); ++j) {
      const Eigen::Index i = unknowns_.theta[static_cast<std::size_t>(j)];
      if (i >= 0) out.theta[j] = from_solver(p, j, v[i]);
    }
    for (std::size_t e = 0; e < experiments_.size(); ++e) {
      Eigen::VectorXd x0 = experiments_[e].x0;
      for (int j = 0; j < nx; ++j) {
        const Eigen::Index i = unknowns_.x0[e][static_cast<std::size_t>(j)];
        if (i >= 0) x0[j] = v[i];
      }
      out.x0.push_back(std::move(x0));
    }
    out.q = settings_.filter.Q.diagonal().head(nx);
    out.r = settings_.filter.R.diagonal();
    for (int j = 0; j < nx; ++j) {
      if (unknowns_.q[static_cast<std::size_t>(j)] >= 0) out.q[j] = std::exp(v[unknowns_.q[static_cast<std::size_t>(j)]]);
    }
    for (int j = 0; j < ny; ++j) {
      if (unknowns_.r[static_cast<std::size_t>(j)] >= 0) out.r[j] = std::exp(v[unknowns_.r[static_cast<std::size_t>(j)]]);
    }
    return out;
  }

  // L's sums at v; with `results`, also each experiment's predictions,
  // normalised innovations and NIS.
  Status evaluate(const Eigen::VectorXd& v, Sums* sums, std::vector<ExperimentResult>* results = nullptr,
                  std::vector<Eigen::VectorXd>* nis = nullptr) {
    const Point at = point(v);
    *sums = Sums{};
    for (std::size_t e = 0; e < experiments_.size(); ++e) {
      RICCATI_RETURN_IF_ERROR(run(e, at, sums, nullptr, results != nullptr ? &(*results)[e] : nullptr,
                                  nis != nullptr ? &(*nis)[e] : nullptr));
    }
    return Status::ok();
  }

  // Experiment e alone at `at`, its least-squares residuals [N (ny + 1)]:
  // per sample S_k^-1/2 e_k, then rho_k = sqrt(ln det S_k - ln det R + 1)
  // (S_k >= R, so the root is real; the 1 keeps it smooth), so that
  // 1/2 sum |residual|^2 is the experiment's L less 1/2 N (ln det R - 1).
  Status residuals(std::size_t e, const Point& at, double* out) {
    Sums sums;
    return run(e, at, &sums, out, nullptr, nullptr);
  }

  // Samples whose every output is used, over every experiment.
  double used_samples() const {
    double n = 0.0;
    for (const Experiment& ex : experiments_) {
      n += ex.mask.size() == 0 ? static_cast<double>(ex.data.size())
                               : static_cast<double>((ex.mask != 0.0).colwise().all().count());
    }
    return n;
  }

  // The predictor of experiment e at `at`: its initial states, and the
  // noise with the diagonals of the point (the filter's and the exact
  // sensitivities' alike).
  LikelihoodPoint predictor_point(std::size_t e, const Point& at) const {
    const int nx = model_->nx();
    LikelihoodPoint out;
    out.theta = at.theta;
    out.x0 = at.x0[e];
    out.Q = settings_.filter.Q.topLeftCorner(nx, nx);
    out.Q.diagonal() = at.q;
    out.R = settings_.filter.R;
    out.R.diagonal() = at.r;
    return out;
  }

  // L at v and, with `with_derivatives`, its exact gradient and Fisher
  // information in the unknowns' coordinates (likelihood_sensitivity.hpp).
  Status derivatives(LikelihoodSensitivity& sensitivity, const Eigen::VectorXd& v, bool with_derivatives,
                     LikelihoodDerivatives* out) {
    const Point at = point(v);
    const ParameterSettings& p = settings_.parameters;
    const Eigen::Index n = unknowns_.size();
    out->reset(with_derivatives ? n : 0);
    LikelihoodDirections& directions = directions_;
    directions.resize(*model_, with_derivatives ? n : 0);
    if (with_derivatives) {
      for (std::size_t j = 0; j < unknowns_.theta.size(); ++j) {
        const Eigen::Index i = unknowns_.theta[j], jj = static_cast<Eigen::Index>(j);
        if (i >= 0) directions.theta(jj, i) = theta_per_phi(p, jj, at.theta[jj]);
      }
      for (std::size_t j = 0; j < unknowns_.q.size(); ++j) {
        if (unknowns_.q[j] >= 0) directions.q(static_cast<Eigen::Index>(j), unknowns_.q[j]) = at.q[static_cast<Eigen::Index>(j)];
      }
      for (std::size_t j = 0; j < unknowns_.r.size(); ++j) {
        if (unknowns_.r[j] >= 0) directions.r(static_cast<Eigen::Index>(j), unknowns_.r[j]) = at.r[static_cast<Eigen::Index>(j)];
      }
    }
    for (std::size_t e = 0; e < experiments_.size(); ++e) {
      if (with_derivatives) {
        directions.x0.setZero();  // this experiment's initial states alone
        for (std::size_t j = 0; j < unknowns_.x0[e].size(); ++j) {
          if (unknowns_.x0[e][j] >= 0) directions.x0(static_cast<Eigen::Index>(j), unknowns_.x0[e][j]) = 1.0;
        }
      }
      ++evaluations_;
      RICCATI_RETURN_IF_ERROR(sensitivity.accumulate(experiments_[e], predictor_point(e, at), directions,
                                                     with_derivatives, out)
                                  .with_context("experiment " + std::to_string(e + 1)));
    }
    return Status::ok();
  }

  int evaluations() const { return evaluations_; }

 private:
  // The predictor for experiment e at `at`: made once, restarted at every
  // evaluation, made again only when the noise levels it holds change.
  Result<OnlineRunner*> runner(std::size_t e, const Point& at) {
    const int nx = model_->nx(), nz = model_->nz();
    InitialEstimate initial;
    initial.mode = InitialState::kGiven;
    initial.x0 = at.x0[e];
    initial.theta0 = at.theta;
    initial.P0 = Eigen::MatrixXd::Zero(nz, nz);
    initial.P0.topLeftCorner(nx, nx) = settings_.P0x;
    if (runners_[e].has_value() && !noise_estimated_) {
      RICCATI_RETURN_IF_ERROR(runners_[e]->restart(std::move(initial)));
      return &*runners_[e];
    }
    const LikelihoodPoint noise = predictor_point(e, at);
    FilterSettings filter = settings_.filter;
    filter.Q = Eigen::MatrixXd::Zero(nz, nz);
    filter.Q.topLeftCorner(nx, nx) = noise.Q;
    filter.R = noise.R;
    runners_[e].reset();
    RICCATI_ASSIGN_OR_RETURN(OnlineRunner made, OnlineRunner::create(model_, filter, std::move(initial)));
    runners_[e].emplace(std::move(made));
    return &*runners_[e];
  }

  Status run(std::size_t e, const Point& at, Sums* sums, double* residuals, ExperimentResult* out,
             Eigen::VectorXd* nis) {
    ++evaluations_;
    const Experiment& ex = experiments_[e];
    const Dataset& d = ex.data;
    const Eigen::Index N = d.size(), ny = model_->ny(), nu = model_->nu();
    RICCATI_ASSIGN_OR_RETURN(OnlineRunner* r, runner(e, at));
    if (out != nullptr) {
      out->y_model.setZero(ny, N);
      out->residuals.setZero(ny, N);
    }
    if (nis != nullptr) nis->setZero(N);
    if (residuals != nullptr) std::fill(residuals, residuals + N * (ny + 1), 0.0);
    const double logdet_R = std::log(at.r.prod());
    const bool masked = ex.mask.size() != 0;
    for (Eigen::Index k = 0; k < N; ++k) {
      const std::span<const double> u(d.u.col(k).data(), static_cast<std::size_t>(nu));
      const bool measured = !masked || (ex.mask.col(k) != 0.0).all();
      const Status st = measured ? r->advance(d.t[k], u, {d.y.col(k).data(), static_cast<std::size_t>(ny)})
                                 : r->advance_without_measurement(d.t[k], u);
      if (!st.is_ok()) {
        return st.with_context("experiment " + std::to_string(e + 1) + ", sample " + std::to_string(k + 1) +
                               " (t = " + std::to_string(d.t[k]) + ")");
      }
      if (!measured) continue;
      const Filter& f = r->filter();
      S_llt_.compute(f.innovation_covariance());
      if (S_llt_.info() != Eigen::Success) {
        return failed_precondition("innovation covariance not positive definite at sample " + std::to_string(k + 1));
      }
      const double logdet = 2.0 * S_llt_.matrixLLT().diagonal().array().log().sum();
      sums->logdet += logdet;
      sums->quadratic += f.nis();
      sums->measurements += static_cast<double>(ny);
      if (residuals != nullptr) {
        double* row = residuals + k * (ny + 1);
        Eigen::Map<Eigen::VectorXd>(row, ny) = S_llt_.matrixL().solve(f.innovation());
        row[ny] = std::sqrt(std::max(logdet - logdet_R, 0.0) + 1.0);
      }
      if (out != nullptr) {
        out->y_model.col(k) = f.predicted_output();
        out->residuals.col(k) = S_llt_.matrixL().solve(f.innovation());
      }
      if (nis != nullptr) (*nis)[k] = f.nis();
    }
    return Status::ok();
  }

  const ModelPtr model_;
  const std::vector<Experiment>& experiments_;
  const MaxLikelihoodSettings& settings_;
  const Unknowns& unknowns_;
  std::vector<std::optional<OnlineRunner>> runners_;
  Eigen::LLT<Eigen::MatrixXd> S_llt_;
  LikelihoodDirections directions_;  // derivatives()'s, sized once
  const bool noise_estimated_;
  int evaluations_ = 0;
};

// Experiment e's residuals for Ceres, over [theta in solver coordinates;
// its x0; log of Q's diagonal; log of R's diagonal], differenced
// centrally by Ceres. The last point's residuals are kept: Ceres evaluates a
// point's cost in the line search, again as the candidate, and again at the
// centre of its Jacobian's differences once the step is accepted.
class ExperimentResiduals {
 public:
  ExperimentResiduals(Likelihood& likelihood, std::size_t e, const ParameterSettings& parameters, int nx, int ny,
                      std::size_t experiments, Eigen::Index residual_count)
      : likelihood_(likelihood),
        e_(e),
        parameters_(parameters),
        nx_(nx),
        ny_(ny),
        experiments_(experiments),
        point_(parameters.theta0.size() + 2 * nx + ny),
        residuals_(residual_count) {}

  bool operator()(double const* const* blocks, double* residuals) const {
    const Eigen::Index ntheta = parameters_.theta0.size();
    Eigen::VectorXd point(point_.size());
    point << Eigen::Map<const Eigen::VectorXd>(blocks[0], ntheta), Eigen::Map<const Eigen::VectorXd>(blocks[1], nx_),
        Eigen::Map<const Eigen::VectorXd>(blocks[2], nx_), Eigen::Map<const Eigen::VectorXd>(blocks[3], ny_);
    if (!evaluated_ || point != point_) {
      Point at;
      at.theta.resize(ntheta);
      for (Eigen::Index j = 0; j < ntheta; ++j) at.theta[j] = from_solver(parameters_, j, blocks[0][j]);
      at.x0.assign(experiments_, Eigen::VectorXd());
      at.x0[e_] = Eigen::Map<const Eigen::VectorXd>(blocks[1], nx_);
      at.q = Eigen::Map<const Eigen::VectorXd>(blocks[2], nx_).array().exp();
      at.r = Eigen::Map<const Eigen::VectorXd>(blocks[3], ny_).array().exp();
      last_ = likelihood_.residuals(e_, at, residuals_.data());
      point_ = point;
      evaluated_ = true;
    }
    Eigen::Map<Eigen::VectorXd>(residuals, residuals_.size()) = residuals_;
    return last_.is_ok();  // a point where the predictor fails: Ceres rejects the step
  }

  const Status& last() const { return last_; }

 private:
  Likelihood& likelihood_;
  const std::size_t e_;
  const ParameterSettings& parameters_;
  const int nx_, ny_;
  const std::size_t experiments_;
  mutable bool evaluated_ = false;
  mutable Eigen::VectorXd point_, residuals_;  // the last point evaluated, and its residuals
  mutable Status last_;
};

// The rest of 1/2 sum ln det S_k when R is estimated: 1/2 N ln det R, as the
// square of rho_0 = sqrt(N (ln det R - ln det R_floor) + 1) over log R's
// diagonal, R_floor being R's lower bounds (so the root is real).
class NoiseLevelResidual final : public ceres::CostFunction {
 public:
  NoiseLevelResidual(double samples, Eigen::VectorXd log_r_floor)
      : samples_(samples), log_r_floor_(std::move(log_r_floor)) {
    set_num_residuals(1);
    mutable_parameter_block_sizes()->push_back(static_cast<int>(log_r_floor_.size()));
  }

  bool Evaluate(double const* const* blocks, double* residuals, double** jacobians) const override {
    const Eigen::Index ny = log_r_floor_.size();
    const Eigen::Map<const Eigen::VectorXd> log_r(blocks[0], ny);
    const double rho = std::sqrt(samples_ * (log_r - log_r_floor_).sum() + 1.0);
    residuals[0] = rho;
    if (jacobians != nullptr && jacobians[0] != nullptr) std::fill(jacobians[0], jacobians[0] + ny, samples_ / (2.0 * rho));
    return true;
  }

 private:
  const double samples_;
  const Eigen::VectorXd log_r_floor_;
};

// L's Hessian in solver coordinates by central second differences, the two
// sums differenced apart.
Status hessian(Likelihood& likelihood, const Unknowns& unknowns, const Eigen::VectorXd& v, Eigen::MatrixXd* H) {
  const Eigen::Index n = v.size();
  H->setZero(n, n);
  Eigen::VectorXd h(n);
  for (Eigen::Index j = 0; j < n; ++j) h[j] = 1.2e-4 * std::max(std::abs(v[j]), unknowns.typical[j]);  // eps^1/4
  Sums center;
  RICCATI_RETURN_IF_ERROR(likelihood.evaluate(v, &center));
  const auto at = [&](Eigen::Index i, double di, Eigen::Index j, double dj, Sums* s) {
    Eigen::VectorXd moved = v;
    moved[i] += di;
    if (j >= 0) moved[j] += dj;
    return likelihood.evaluate(moved, s);
  };
  const auto combine = [](const Sums& a, const Sums& b, const Sums& c, const Sums& d) {
    return 0.5 * ((a.logdet - b.logdet - c.logdet + d.logdet) + (a.quadratic - b.quadratic - c.quadratic + d.quadratic));
  };
  for (Eigen::Index i = 0; i < n; ++i) {
    Sums plus, minus;
    RICCATI_RETURN_IF_ERROR(at(i, h[i], -1, 0.0, &plus));
    RICCATI_RETURN_IF_ERROR(at(i, -h[i], -1, 0.0, &minus));
    (*H)(i, i) = 0.5 * ((plus.logdet - 2.0 * center.logdet + minus.logdet) +
                        (plus.quadratic - 2.0 * center.quadratic + minus.quadratic)) /
                 (h[i] * h[i]);
    for (Eigen::Index j = 0; j < i; ++j) {
      Sums pp, pm, mp, mm;
      RICCATI_RETURN_IF_ERROR(at(i, h[i], j, h[j], &pp));
      RICCATI_RETURN_IF_ERROR(at(i, h[i], j, -h[j], &pm));
      RICCATI_RETURN_IF_ERROR(at(i, -h[i], j, h[j], &mp));
      RICCATI_RETURN_IF_ERROR(at(i, -h[i], j, -h[j], &mm));
      (*H)(i, j) = (*H)(j, i) = combine(pp, pm, mp, mm) / (4.0 * h[i] * h[j]);
    }
  }
  return Status::ok();
}

// L's Hessian from forward differences of its exact gradient: n runs of the
// sensitivities (the gradient at v is known) instead of 2n^2 of the filter.
// Step 1e-6 of each unknown's scale: truncation and rounding (the gradient
// is exact to about 1e-12 of its size) both near 1e-6 of the Hessian, far
// below what a standard error needs.
Status hessian_from_gradient(Likelihood& likelihood, LikelihoodSensitivity& sensitivity, const Unknowns& unknowns,
                             const Eigen::VectorXd& v, const Eigen::VectorXd& gradient, Eigen::MatrixXd* H) {
  const Eigen::Index n = v.size();
  H->setZero(n, n);
  LikelihoodDerivatives moved_point;
  for (Eigen::Index j = 0; j < n; ++j) {
    const double h = 1e-6 * std::max(std::abs(v[j]), unknowns.typical[j]);
    Eigen::VectorXd moved = v;
    moved[j] = v[j] + h;
    RICCATI_RETURN_IF_ERROR(likelihood.derivatives(sensitivity, moved, true, &moved_point));
    H->col(j) = (moved_point.gradient - gradient) / h;
  }
  *H = (0.5 * (*H + H->transpose())).eval();
  return Status::ok();
}

// What a minimisation did, for the result.
struct Minimisation {
  int iterations = 0;
  int derivative_evaluations = 0;
  bool converged = false;
  std::string termination;
  Eigen::VectorXd gradient;  // L's at the end
};

// Minimises L over the unknowns from v within [lower, upper] by Fisher
// scoring (likelihood_sensitivity.hpp) with Levenberg-Marquardt damping:
// the step solves (F + lambda diag F) d = -g on the unknowns not held at a
// bound, projected into the bounds; a step is taken when L decreases, and
// lambda follows how well F predicted the decrease. The criteria are Ceres'
// (relative change of L, of v, the projected gradient), so that the
// settings mean what they mean for output error.
Result<Minimisation> fisher_scoring(Likelihood& likelihood, LikelihoodSensitivity& sensitivity,
                                    const Eigen::VectorXd& lower, const Eigen::VectorXd& upper,
                                    const std::vector<bool>& noise_level,
                                    const OptimizerSettings& settings, const EstimationHooks& hooks,
                                    std::vector<double>* history, Eigen::VectorXd* v) {
  Minimisation out;
  const Eigen::Index n = v->size();
  const auto project = [&](Eigen::VectorXd x) { return x.cwiseMax(lower).cwiseMin(upper).eval(); };
  *v = project(*v);
  LikelihoodDerivatives at, trial;
  RICCATI_RETURN_IF_ERROR(likelihood.derivatives(sensitivity, *v, true, &at).with_context("the likelihood at the start"));
  ++out.derivative_evaluations;
  history->push_back(at.value());
  if (hooks.progress) hooks.progress(EstimationProgress{0, at.value()});
  // Ends the minimisation at v, whose derivatives `at` holds.
  const auto finish = [&](bool converged, std::string termination) {
    out.converged = converged;
    out.termination = std::move(termination);
    out.gradient = at.gradient;
    return out;
  };
  double lambda = 1e-3;
  double noise_radius = kLn10;
  Status last_failure;
  for (int iteration = 1; iteration <= settings.max_iterations; ++iteration) {
    if (hooks.stop.stop_requested()) return cancelled("maximum likelihood cancelled after iteration " + std::to_string(iteration - 1));
    const double projected_gradient = (*v - project(*v - at.gradient)).cwiseAbs().maxCoeff();
    if (projected_gradient <= settings.gradient_tolerance) {
      return finish(true, "the projected gradient is within the gradient tolerance");
    }
    // Unknowns held at a bound that the gradient pushes against stay there.
    std::vector<Eigen::Index> free;
    for (Eigen::Index i = 0; i < n; ++i) {
      const bool held = ((*v)[i] <= lower[i] && at.gradient[i] > 0.0) || ((*v)[i] >= upper[i] && at.gradient[i] < 0.0);
      if (!held) free.push_back(i);
    }
    const Eigen::Index nf = static_cast<Eigen::Index>(free.size());
    Eigen::MatrixXd F(nf, nf);
    Eigen::VectorXd g(nf);
    for (Eigen::Index a = 0; a < nf; ++a) {
      g[a] = at.gradient[free[static_cast<std::size_t>(a)]];
      for (Eigen::Index b = 0; b < nf; ++b) F(a, b) = at.fisher(free[static_cast<std::size_t>(a)], free[static_cast<std::size_t>(b)]);
    }
    const Eigen::VectorXd scale = F.diagonal().cwiseMax(1e-12 * std::max(F.diagonal().maxCoeff(), 1e-300));
    bool stepped = false;
    while (!stepped) {
      if (lambda > 1e16) {
        // No step decreases L any more: it is at its minimum to rounding.
        return finish(last_failure.is_ok(), last_failure.is_ok()
                                                ? "no step decreases the likelihood further"
                                                : "no step could be taken: " + last_failure.message());
      }
      Eigen::MatrixXd damped = F;
      damped.diagonal() += lambda * scale;
      const Eigen::VectorXd step_free = damped.ldlt().solve(-g);
      // A noise level moves at most `noise_radius` in ln a step: far from the
      // optimum (residuals much larger than R) F's curvature in ln R is much
      // smaller than L's, and its step would overshoot by decades. The radius
      // starts at a decade and grows while F predicts L well.
      double shrink = 1.0;
      for (Eigen::Index a = 0; a < nf; ++a) {
        const double longest =
            noise_level[static_cast<std::size_t>(free[static_cast<std::size_t>(a)])] ? noise_radius : kInfinity;
        if (std::abs(step_free[a]) > longest) shrink = std::min(shrink, longest / std::abs(step_free[a]));
      }
      Eigen::VectorXd candidate = *v;
      for (Eigen::Index a = 0; a < nf; ++a) candidate[free[static_cast<std::size_t>(a)]] += shrink * step_free[a];
      candidate = project(candidate);
      const Eigen::VectorXd step = candidate - *v;
      if (step.cwiseAbs().maxCoeff() <= settings.parameter_tolerance * (v->cwiseAbs().maxCoeff() + settings.parameter_tolerance)) {
        return finish(true, "the step is within the parameter tolerance");
      }
      const double predicted = -(at.gradient.dot(step) + 0.5 * step.dot(at.fisher * step));
      const Status evaluated = likelihood.derivatives(sensitivity, candidate, true, &trial);
      ++out.derivative_evaluations;
      if (hooks.stop.stop_requested()) return cancelled("maximum likelihood cancelled after iteration " + std::to_string(iteration - 1));
      const double decrease = at.value() - trial.value();
      const double ratio = predicted > 0.0 ? decrease / predicted : 0.0;
      if (!evaluated.is_ok() || !(decrease > 0.0) || ratio < 1e-3) {
        if (!evaluated.is_ok()) last_failure = evaluated;
        lambda *= 4.0;
        noise_radius = std::max(0.5 * noise_radius, 0.1);
        continue;
      }
      if (shrink < 1.0 && ratio > 0.75) noise_radius = std::min(4.0 * noise_radius, 30.0);
      lambda *= ratio > 0.75 ? 1.0 / 3.0 : (ratio < 0.25 ? 2.0 : 1.0);
      lambda = std::max(lambda, 1e-12);
      const bool small_change = decrease <= settings.function_tolerance * std::abs(at.value());
      *v = candidate;
      std::swap(at, trial);
      last_failure = Status::ok();
      out.iterations = iteration;
      history->push_back(at.value());
      if (hooks.progress) hooks.progress(EstimationProgress{iteration, at.value()});
      if (small_change) {
        return finish(true, "the change of the likelihood is within the function tolerance");
      }
      stepped = true;
    }
  }
  return finish(false, "the iteration limit (" + std::to_string(settings.max_iterations) + ") was reached");
}

}  // namespace

Result<MaxLikelihoodResult> max_likelihood(ModelPtr model, const std::vector<Experiment>& experiments,
                                           const MaxLikelihoodSettings& settings, const EstimationHooks& hooks) {
  if (model == nullptr) return invalid_argument("no model given");
  if (experiments.empty()) return invalid_argument("maximum likelihood needs at least one experiment");
  const ParameterSettings& p = settings.parameters;
  RICCATI_RETURN_IF_ERROR(validate(p, *model));
  const int ntheta = model->ntheta(), nx = model->nx(), ny = model->ny(), nz = model->nz();
  if (settings.filter.kind != FilterKind::kEkf && settings.filter.kind != FilterKind::kUkf) {
    return invalid_argument("maximum likelihood's predictor is the EKF or the UKF");
  }
  RICCATI_RETURN_IF_ERROR(check_covariance(settings.filter.Q, nz, "process noise Q"));
  RICCATI_RETURN_IF_ERROR(check_covariance(settings.filter.R, ny, "measurement noise R"));
  RICCATI_RETURN_IF_ERROR(check_covariance(settings.P0x, nx, "initial covariance of the states P0"));
  if (settings.estimate_process_noise && !(settings.filter.Q.diagonal().head(nx).array() > 0.0).all()) {
    return invalid_argument("estimating Q needs a positive start for each state's process noise");
  }
  if (settings.estimate_measurement_noise && !(settings.filter.R.diagonal().array() > 0.0).all()) {
    return invalid_argument("estimating R needs a positive start for each output's noise variance");
  }
  for (std::size_t e = 0; e < experiments.size(); ++e) RICCATI_RETURN_IF_ERROR(validate(experiments[e], *model, e));

  Unknowns unknowns;
  for (int j = 0; j < ntheta; ++j) {
    if (p.fixed[static_cast<std::size_t>(j)]) {
      unknowns.theta.push_back(-1);
      continue;
    }
    const bool log = p.log_scale[static_cast<std::size_t>(j)];
    unknowns.theta.push_back(unknowns.add(model->param_names()[static_cast<std::size_t>(j)], p.theta0[j], p.lower[j],
                                          p.upper[j], log));
  }
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    unknowns.x0.emplace_back(static_cast<std::size_t>(nx), -1);
    const Experiment& ex = experiments[e];
    for (int j = 0; j < nx; ++j) {
      if (ex.estimate_x0.empty() || !ex.estimate_x0[static_cast<std::size_t>(j)]) continue;
      unknowns.x0[e][static_cast<std::size_t>(j)] =
          unknowns.add(model->state_names()[static_cast<std::size_t>(j)] + "(0)" +
                           (experiments.size() > 1 ? " of experiment " + std::to_string(e + 1) : ""),
                       ex.x0[j], -kInfinity, kInfinity, false);
    }
  }
  unknowns.q.assign(static_cast<std::size_t>(nx), -1);
  unknowns.r.assign(static_cast<std::size_t>(ny), -1);
  if (settings.estimate_process_noise) {
    for (int j = 0; j < nx; ++j) {
      unknowns.q[static_cast<std::size_t>(j)] = unknowns.add("Q(" + model->state_names()[static_cast<std::size_t>(j)] + ")",
                                                             settings.filter.Q(j, j), 0.0, kInfinity, true);
    }
  }
  if (settings.estimate_measurement_noise) {
    for (int j = 0; j < ny; ++j) {
      unknowns.r[static_cast<std::size_t>(j)] = unknowns.add("R(" + model->output_names()[static_cast<std::size_t>(j)] + ")",
                                                             settings.filter.R(j, j), 0.0, kInfinity, true);
    }
  }

  Likelihood likelihood(model, experiments, settings, unknowns);
  MaxLikelihoodResult out;
  EstimationResult& result = out.estimate;
  result.param_names = model->param_names();
  // Exact derivatives where the model and the predictor have them; else
  // central differences of the filter's residuals, saying why.
  std::optional<LikelihoodSensitivity> sensitivity;
  const Status exact = settings.differenced_gradient ? failed_precondition("asked for")
                                                     : LikelihoodSensitivity::available(*model, settings.filter);
  if (exact.is_ok()) {
    RICCATI_ASSIGN_OR_RETURN(LikelihoodSensitivity made, LikelihoodSensitivity::create(model, settings.filter, settings.P0x));
    sensitivity.emplace(std::move(made));
    result.gradient = "exact: forward sensitivities of the EKF's state and covariance (Fisher scoring)";
  } else {
    result.gradient = "central differences of the likelihood's residuals (" + exact.message() + ")";
  }

  // The minimisation: Fisher scoring with the exact derivatives, else Ceres'
  // Levenberg-Marquardt on the residuals with central differences.
  const auto by_differences = [&]() -> Result<Eigen::VectorXd> {
    // Ceres' least squares over the parameters, the initial states and the log
    // noise levels: 1/2 |residuals|^2 is L less a constant (see residuals()).
    LeastSquaresUnknowns blocks(p, experiments);
    // The log noise levels, Q's diagonal and R's, as two blocks: one that is
    // not estimated is constant, and so not differenced.
    Eigen::VectorXd log_q = settings.filter.Q.diagonal().head(nx).cwiseMax(std::numeric_limits<double>::min()).array().log();
    Eigen::VectorXd log_r = settings.filter.R.diagonal().array().log();
    ceres::Problem::Options problem_options;
    problem_options.manifold_ownership = ceres::TAKE_OWNERSHIP;
    problem_options.cost_function_ownership = ceres::TAKE_OWNERSHIP;
    ceres::Problem problem(problem_options);
    std::vector<const Status*> predictor_status;  // each residual block's last evaluation
    for (std::size_t e = 0; e < experiments.size(); ++e) {
      const Eigen::Index residual_count = experiments[e].data.size() * (ny + 1);
      auto* functor = new ExperimentResiduals(likelihood, e, p, nx, ny, experiments.size(), residual_count);
      predictor_status.push_back(&functor->last());
      auto* cost = new ceres::DynamicNumericDiffCostFunction<ExperimentResiduals, ceres::CENTRAL>(functor);
      cost->AddParameterBlock(ntheta);
      cost->AddParameterBlock(nx);
      cost->AddParameterBlock(nx);
      cost->AddParameterBlock(ny);
      cost->SetNumResiduals(static_cast<int>(residual_count));
      problem.AddResidualBlock(cost, nullptr, blocks.phi.data(), blocks.x0[e].data(), log_q.data(), log_r.data());
    }
    blocks.constrain(problem, p, experiments);
    // Estimated noise levels within 13 decades of their start below (R's floor
    // makes rho_0 real), the others constant.
    const Eigen::VectorXd log_r_floor = log_r.array() - 30.0;
    for (const auto& [levels, estimated] : {std::pair{&log_q, settings.estimate_process_noise},
                                            std::pair{&log_r, settings.estimate_measurement_noise}}) {
      if (!estimated) {
        problem.SetParameterBlockConstant(levels->data());
        continue;
      }
      for (Eigen::Index j = 0; j < levels->size(); ++j) {
        problem.SetParameterLowerBound(levels->data(), static_cast<int>(j), (*levels)[j] - 30.0);
      }
    }
    if (settings.estimate_measurement_noise) {
      problem.AddResidualBlock(new NoiseLevelResidual(likelihood.used_samples(), log_r_floor), nullptr, log_r.data());
    }
    // The unknowns as one vector (the likelihood's and the Hessian's coordinates).
    const auto unknowns_now = [&] {
      Eigen::VectorXd v(unknowns.size());
      for (int j = 0; j < ntheta; ++j) {
        if (unknowns.theta[static_cast<std::size_t>(j)] >= 0) v[unknowns.theta[static_cast<std::size_t>(j)]] = blocks.phi[j];
      }
      for (std::size_t e = 0; e < experiments.size(); ++e) {
        for (int j = 0; j < nx; ++j) {
          if (unknowns.x0[e][static_cast<std::size_t>(j)] >= 0) v[unknowns.x0[e][static_cast<std::size_t>(j)]] = blocks.x0[e][j];
        }
      }
      for (int j = 0; j < nx; ++j) {
        if (unknowns.q[static_cast<std::size_t>(j)] >= 0) v[unknowns.q[static_cast<std::size_t>(j)]] = log_q[j];
      }
      for (int j = 0; j < ny; ++j) {
        if (unknowns.r[static_cast<std::size_t>(j)] >= 0) v[unknowns.r[static_cast<std::size_t>(j)]] = log_r[j];
      }
      return v;
    };
    // Progress and the cost history say L itself, not the optimiser's cost:
    // the two differ by a constant (see residuals()), measured once at the start.
    Sums at_start;
    RICCATI_RETURN_IF_ERROR(likelihood.evaluate(unknowns_now(), &at_start).with_context("the likelihood at the start"));
    double solver_cost_at_start = 0.0;
    problem.Evaluate(ceres::Problem::EvaluateOptions(), &solver_cost_at_start, nullptr, nullptr, nullptr);
    IterationWatcher watcher(hooks, &result.cost_history, at_start.total() - solver_cost_at_start);
    // The line search's trials by their cost alone: a gradient is 2n more
    // filter runs. (Bisection, not a quadratic fit: on two-tank that took twice
    // the iterations.)
    const ceres::Solver::Options options = solver_options(settings.optimizer, &watcher, ceres::BISECTION);
    ceres::Solver::Summary summary;
    ceres::Solve(options, &problem, &summary);
    if (hooks.stop.stop_requested()) {
      return cancelled("maximum likelihood cancelled after iteration " + std::to_string(summary.iterations.size()));
    }
    if (summary.termination_type == ceres::FAILURE || !summary.IsSolutionUsable()) {
      std::string why = summary.message;
      for (const Status* last : predictor_status) {
        if (!last->is_ok()) why += "; the predictor failed: " + last->message();
      }
      return failed_precondition("maximum likelihood found no step it could take: " + why);
    }
    // Ceres lists the start as iteration 0; with every unknown held it runs
    // none and lists nothing (not -1: unsigned in the API, 4294967295).
    result.iterations = std::max(0, static_cast<int>(summary.iterations.size()) - 1);
    result.jacobian_evaluations = summary.num_jacobian_evaluations;
    result.converged = summary.termination_type == ceres::CONVERGENCE;
    result.termination = summary.message;

    return unknowns_now();
};
  Eigen::VectorXd v, gradient_at_estimate;
  if (sensitivity.has_value()) {
    // The bounds in the unknowns' coordinates; estimated noise levels within
    // 13 decades (30 in ln) of their start below, as the differenced path's.
    Eigen::VectorXd lower = unknowns.lower, upper = unknowns.upper;
    std::vector<bool> noise_level(static_cast<std::size_t>(unknowns.size()), false);
    for (const std::vector<Eigen::Index>* levels : {&unknowns.q, &unknowns.r}) {
      for (const Eigen::Index i : *levels) {
        if (i < 0) continue;
        lower[i] = unknowns.start[i] - 30.0;
        noise_level[static_cast<std::size_t>(i)] = true;
      }
    }
    v = unknowns.start;
    RICCATI_ASSIGN_OR_RETURN(const Minimisation done,
                             fisher_scoring(likelihood, *sensitivity, lower, upper, noise_level, settings.optimizer, hooks,
                                            &result.cost_history, &v));
    result.iterations = done.iterations;
    result.jacobian_evaluations = done.derivative_evaluations;
    result.converged = done.converged;
    result.termination = done.termination;
    gradient_at_estimate = done.gradient;
  } else {
    RICCATI_ASSIGN_OR_RETURN(v, by_differences());
  }

  // The estimate and what the run shows there.
  Sums sums;
  std::vector<Eigen::VectorXd> nis(experiments.size());
  result.experiments.resize(experiments.size());
  RICCATI_RETURN_IF_ERROR(likelihood.evaluate(v, &sums, &result.experiments, &nis));
  result.cost = sums.total();
  result.sigma2 = 1.0;
  const Point at = likelihood.point(v);
  result.theta = at.theta;
  result.fixed = p.fixed;

  // Covariance: the inverse of L's Hessian, in natural coordinates (log
  // coordinates scaled back: H_natural = D^-1 H D^-1, D = d natural / d v).
  Eigen::MatrixXd H;
  RICCATI_RETURN_IF_ERROR((sensitivity.has_value() ? hessian_from_gradient(likelihood, *sensitivity, unknowns, v, gradient_at_estimate, &H)
                                                   : hessian(likelihood, unknowns, v, &H))
                              .with_context("the likelihood's Hessian"));
  result.evaluations = likelihood.evaluations();
  Eigen::VectorXd natural(unknowns.size()), d(unknowns.size());
  for (Eigen::Index i = 0; i < unknowns.size(); ++i) {
    natural[i] = unknowns.log_scale[static_cast<std::size_t>(i)] ? std::exp(v[i]) : v[i];
    d[i] = unknowns.log_scale[static_cast<std::size_t>(i)] ? natural[i] : 1.0;
  }
  const Eigen::MatrixXd H_natural = d.cwiseInverse().asDiagonal() * H * d.cwiseInverse().asDiagonal();
  const Uncertainty u = uncertainty_from_information(H_natural, 1.0, unknowns.names, natural);
  set_parameter_uncertainty(p, u, unknowns.theta, &result);
  warn_active_bounds(p, &result);
  // ln L = -L - n/2 ln 2 pi: L leaves the constant out.
  constexpr double kLog2Pi = 1.8378770664093454836;
  set_information_criteria(-result.cost - 0.5 * sums.measurements * kLog2Pi, static_cast<int>(unknowns.size()),
                           sums.measurements, &result);
  out.noise.q = at.q;
  out.noise.r = at.r;
  out.noise.q_std = Eigen::VectorXd::Zero(nx);
  out.noise.r_std = Eigen::VectorXd::Zero(ny);
  for (int j = 0; j < nx; ++j) {
    if (unknowns.q[static_cast<std::size_t>(j)] >= 0) out.noise.q_std[j] = u.std[unknowns.q[static_cast<std::size_t>(j)]];
  }
  for (int j = 0; j < ny; ++j) {
    if (unknowns.r[static_cast<std::size_t>(j)] >= 0) out.noise.r_std[j] = u.std[unknowns.r[static_cast<std::size_t>(j)]];
  }
  for (std::size_t e = 0; e < experiments.size(); ++e) {
    ExperimentResult& ex = result.experiments[e];
    const Experiment& in = experiments[e];
    ex.x0 = at.x0[e];
    ex.x0_std = Eigen::VectorXd::Zero(nx);
    ex.x0_estimated.assign(static_cast<std::size_t>(nx), false);
    for (int j = 0; j < nx; ++j) {
      const Eigen::Index c = unknowns.x0[e][static_cast<std::size_t>(j)];
      if (c < 0) continue;
      ex.x0_std[j] = u.std[c];
      ex.x0_estimated[static_cast<std::size_t>(j)] = true;
    }
    ex.t = in.data.t;
    ex.y_measured = in.data.y;
    ex.mask = in.mask.size() != 0 ? in.mask : Eigen::ArrayXXd::Ones(ny, in.data.size());
    ex.residuals = (ex.residuals.array() * ex.mask).matrix();
    RICCATI_ASSIGN_OR_RETURN(ex.fits, fits_over_mask(ex.y_measured, ex.y_model, ex.mask, model->output_names()));
    RICCATI_ASSIGN_OR_RETURN(ex.diagnostics, diagnose(ex, in.data.u, &nis[e]));
  }
  return out;
}

}  // namespace riccati
