#include "engine/estimation/online_runner.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

namespace riccati {
namespace {


// x0 as the mode needs it: nx values, or none with the first measurement.
Status check_x0(const Model& model, InitialState mode, const Eigen::VectorXd& x0) {
  const int nx = model.nx();
  if (x0.size() != 0 && x0.size() != nx) {
    return invalid_argument("x0 has " + std::to_string(x0.size()) + " entries, model " + model.name() + " has " +
                            std::to_string(nx) + " states (" + join_names(model.state_names()) + ")");
  }
  if (mode == InitialState::kGiven && x0.size() != nx) {
    return invalid_argument("x0 is required (" + std::to_string(nx) + " values: " + join_names(model.state_names()) +
                            ") unless the initial state is the first measurement");
  }
  if (!x0.allFinite()) return invalid_argument("x0 has a NaN or infinite entry");
  return Status::ok();
}

}  // namespace

Status validate(const InitialEstimate& initial, const Model& model) {
  RICCATI_RETURN_IF_ERROR(check_x0(model, initial.mode, initial.x0));
  if (initial.theta0.size() != model.ntheta()) {
    return invalid_argument("theta0 has " + std::to_string(initial.theta0.size()) + " entries, model " +
                            model.name() + " has " + std::to_string(model.ntheta()) + " parameters (" +
                            join_names(model.param_names()) + ")");
  }
  if (!initial.theta0.allFinite()) return invalid_argument("theta0 has a NaN or infinite entry");
  if (initial.P0.rows() != model.nz() || initial.P0.cols() != model.nz()) {
    return invalid_argument("P0 must be " + std::to_string(model.nz()) + " x " + std::to_string(model.nz()) +
                            " (states and parameters)");
  }
  return check_covariance(initial.P0, model.nz(), "initial covariance P0");
}

Result<Eigen::VectorXd> initial_state(const Model& model, InitialState mode, const Eigen::VectorXd& x0,
                                      std::span<const double> y_first) {
  RICCATI_RETURN_IF_ERROR(check_x0(model, mode, x0));
  const int nx = model.nx();
  Eigen::VectorXd x = x0.size() == nx ? x0 : Eigen::VectorXd::Zero(nx);
  if (mode == InitialState::kFirstMeasurement) {
    int matched = 0;
    for (int i = 0; i < nx; ++i) {
      const int out = model.output_index(model.state_names()[i]);
      if (out >= 0 && static_cast<std::size_t>(out) < y_first.size()) {
        x[i] = y_first[static_cast<std::size_t>(out)];
        ++matched;
      }
    }
    if (matched == 0) {
      return invalid_argument("x0 = first measurement needs outputs named as states; model " + model.name() +
                              " has states (" + join_names(model.state_names()) + ") and outputs (" +
                              join_names(model.output_names()) + ")");
    }
  }
  if (!x.allFinite()) return invalid_argument("x0 has a NaN or infinite entry");
  return x;
}

Result<OnlineRunner> OnlineRunner::create(ModelPtr model, const FilterSettings& settings, InitialEstimate initial) {
  if (model == nullptr) return invalid_argument("no model given");
  RICCATI_RETURN_IF_ERROR(validate(initial, *model));
  RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Filter> filter, make_filter(std::move(model), settings));
  return OnlineRunner(std::move(filter), std::move(initial));
}

OnlineRunner::OnlineRunner(std::unique_ptr<Filter> filter, InitialEstimate initial)
    : filter_(std::move(filter)),
      initial_(std::move(initial)),
      u_last_(Eigen::VectorXd::Zero(filter_->model().nu())),
      hits_(Eigen::VectorXi::Zero(filter_->model().ntheta())) {}

Status OnlineRunner::set_parameter_bounds(Eigen::VectorXd lower, Eigen::VectorXd upper) {
  const Model& model = filter_->model();
  if (lower.size() == 0 && upper.size() == 0) {
    lower_.resize(0);
    upper_.resize(0);
    return Status::ok();
  }
  if (lower.size() != model.ntheta() || upper.size() != model.ntheta() || (lower.array() > upper.array()).any()) {
    return invalid_argument("parameter bounds need " + std::to_string(model.ntheta()) + " intervals (model " +
                            model.name() + ")");
  }
  lower_ = std::move(lower);
  upper_ = std::move(upper);
  return Status::ok();
}

Status OnlineRunner::restart(InitialEstimate initial) {
  RICCATI_RETURN_IF_ERROR(validate(initial, filter_->model()));
  initial_ = std::move(initial);
  started_ = false;
  divergence_ = Status::ok();
  hits_.setZero();
  return Status::ok();
}

Status OnlineRunner::check(double t, std::span<const double> u, std::span<const double> y) const {
  const Model& model = filter_->model();
  if (u.size() != static_cast<std::size_t>(model.nu()) || y.size() != static_cast<std::size_t>(model.ny())) {
    return invalid_argument("measurement needs " + std::to_string(model.nu()) + " inputs and " +
                            std::to_string(model.ny()) + " outputs (model " + model.name() + "), got " +
                            std::to_string(u.size()) + " and " + std::to_string(y.size()));
  }
  if (!std::isfinite(t)) return invalid_argument("measurement time is not finite");
  for (std::size_t i = 0; i < u.size(); ++i) {
    if (!std::isfinite(u[i])) {
      return invalid_argument("input " + model.input_names()[i] + " is not finite at t = " + std::to_string(t));
    }
  }
  for (std::size_t i = 0; i < y.size(); ++i) {
    if (!std::isfinite(y[i])) {
      return invalid_argument("output " + model.output_names()[i] + " is not finite at t = " + std::to_string(t));
    }
  }
  if (started_ && !(t > filter_->time())) {
    return invalid_argument("time goes backwards (or repeats): t = " + std::to_string(t) +
                            " after t = " + std::to_string(filter_->time()));
  }
  if (started_ && max_time_step_ > 0.0 && t - filter_->time() > max_time_step_) {
    char text[200];
    std::snprintf(text, sizeof text, "time jumps by %.6g s (t = %.6g after t = %.6g), more than the %.6g s a step may be",
                  t - filter_->time(), t, filter_->time(), max_time_step_);
    return invalid_argument(text);
  }
  return Status::ok();
}

Status OnlineRunner::start(double t, const double* u, const double* y) {
  const Model& model = filter_->model();
  RICCATI_ASSIGN_OR_RETURN(const Eigen::VectorXd x0,
                           initial_state(model, initial_.mode, initial_.x0,
                                         std::span<const double>(y, static_cast<std::size_t>(model.ny()))));
  Eigen::VectorXd z(model.nz());
  z << x0, initial_.theta0;
  RICCATI_RETURN_IF_ERROR(filter_->reset(t, z, initial_.P0));
  started_ = true;
  return filter_->update(y, u);
}

Status OnlineRunner::advance(double t, std::span<const double> u, std::span<const double> y) {
  if (diverged()) return divergence_;
  RICCATI_RETURN_IF_ERROR(check(t, u, y));
  // Past the checks, a failure is the filter's: it diverged (or the model
  // failed), and its estimate can no longer be trusted.
  const Status stepped = started_ ? filter_->step(t, u_last_.data(), u.data(), y.data()) : start(t, u.data(), y.data());
  if (!stepped.is_ok()) {
    // An interrupted prediction (cancelled, a deadline, a step budget) left
    // the filter where it was: the measurement is not taken, nothing diverged.
    if (started_ && is_interruption(stepped)) return stepped;
    divergence_ = stepped;
    return divergence_;
  }
  if (lower_.size() != 0) filter_->clamp_parameters(lower_, upper_, &hits_);
  std::copy(u.begin(), u.end(), u_last_.data());
  return Status::ok();
}

Status OnlineRunner::advance_without_measurement(double t, std::span<const double> u) {
  if (diverged()) return divergence_;
  const Model& model = filter_->model();
  if (u.size() != static_cast<std::size_t>(model.nu())) {
    return invalid_argument("measurement needs " + std::to_string(model.nu()) + " inputs (model " + model.name() +
                            "), got " + std::to_string(u.size()));
  }
  if (!std::isfinite(t) || (started_ && !(t > filter_->time()))) {
    return invalid_argument("time " + std::to_string(t) + " is not after the run's " + std::to_string(filter_->time()));
  }
  Status stepped;
  if (started_) {
    stepped = filter_->predict(t, u_last_.data(), u.data());
    if (!stepped.is_ok() && is_interruption(stepped)) return stepped;  // as in advance()
  } else {
    if (initial_.mode != InitialState::kGiven) {
      return invalid_argument("a run that starts without a measurement needs x0 given");
    }
    Eigen::VectorXd z(model.nz());
    z << initial_.x0, initial_.theta0;
    stepped = filter_->reset(t, z, initial_.P0);
    started_ = stepped.is_ok();
  }
  if (!stepped.is_ok()) {
    divergence_ = stepped;
    return divergence_;
  }
  std::copy(u.begin(), u.end(), u_last_.data());
  return Status::ok();
}

OnlineRunner::Snapshot OnlineRunner::snapshot() const {
  Snapshot s;
  s.started = started_;
  if (started_) {
    s.t = filter_->time();
    s.z = filter_->state();
    s.P = filter_->covariance();
    s.carried = filter_->carried_state();
    s.u_last = u_last_;
  }
  s.divergence = divergence_;
  return s;
}

Status OnlineRunner::restore(const Snapshot& s) {
  if (s.started) {
    if (s.u_last.size() != u_last_.size()) {
      return invalid_argument("saved run has " + std::to_string(s.u_last.size()) + " inputs, model " +
                              filter_->model().name() + " has " + std::to_string(u_last_.size()));
    }
    RICCATI_RETURN_IF_ERROR(filter_->restore(s.t, s.z, s.P, s.carried));
    u_last_ = s.u_last;
  }
  started_ = s.started;
  divergence_ = s.divergence;
  return Status::ok();
}

}  // namespace riccati
