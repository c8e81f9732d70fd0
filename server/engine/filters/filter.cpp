#include "engine/filters/filter.hpp"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <cmath>
#include <string>

#include "engine/filters/filter_kinds.hpp"

namespace riccati {

Result<GainInversion> parse_gain_inversion(std::string_view name) {
  if (name == "cholesky" || name == "normal") return GainInversion::kCholesky;
  if (name == "pinv" || name == "pseudo-inverse") return GainInversion::kPseudoInverse;
  return invalid_argument("unknown gain inversion \"" + std::string(name) + "\" (expected cholesky or pinv)");
}

Result<SigmaWeights> parse_sigma_weights(std::string_view name) {
  if (name == "julier") return SigmaWeights::kJulier;
  if (name == "scaled") return SigmaWeights::kScaled;
  return invalid_argument("unknown sigma-point weights \"" + std::string(name) + "\" (expected julier or scaled)");
}

Result<OptimalForm> parse_optimal_form(std::string_view name) {
  if (name == "continuous") return OptimalForm::kContinuous;
  if (name == "split-step" || name == "split") return OptimalForm::kSplitStep;
  return invalid_argument("unknown optimal filter form \"" + std::string(name) +
                          "\" (expected continuous or split-step)");
}

const char* optimal_form_name(OptimalForm form) {
  return form == OptimalForm::kSplitStep ? "split-step" : "continuous";
}

int optimal_equation_count(const Model& model) { return model.ndof() + model.nu() + model.ny(); }

Status check_covariance(const Eigen::MatrixXd& M, Eigen::Index n, const std::string& what) {
  if (M.rows() != n || M.cols() != n) {
    return invalid_argument(what + " must be " + std::to_string(n) + " x " + std::to_string(n) + ", got " +
                            size_text(M));
  }
  if (!M.allFinite()) return invalid_argument(what + " has a NaN or infinite entry");
  // A filter multiplies these by one another (P Phi', C S^-1 C', Q dt
  // summed): an entry whose square overflows gives infinities, or estimates
  // with standard deviations of 1e134 that report no divergence.
  for (Eigen::Index j = 0; j < n; ++j) {
    for (Eigen::Index i = 0; i < n; ++i) {
      if (std::abs(M(i, j)) > kMaxCovarianceEntry) {
        return invalid_argument(what + "[" + std::to_string(i) + ", " + std::to_string(j) + "] = " +
                                message_number(M(i, j)) + " is too large: entries of a covariance or weight are at "
                                "most " + message_number(kMaxCovarianceEntry) +
                                " in magnitude (so that their products stay finite); rescale the model's units");
      }
    }
  }
  const double scale = std::max(1.0, M.cwiseAbs().maxCoeff());
  if ((M - M.transpose()).cwiseAbs().maxCoeff() > 1e-12 * scale) {
    return invalid_argument(what + " is not symmetric");
  }
  for (Eigen::Index i = 0; i < n; ++i) {
    if (M(i, i) < 0.0) {
      return invalid_argument(what + " has a negative variance " + std::to_string(M(i, i)) + " at " +
                              std::to_string(i));
    }
  }
  Eigen::LDLT<Eigen::MatrixXd> ldlt(M);
  if (ldlt.info() != Eigen::Success || (ldlt.vectorD().array() < -1e-10 * scale).any()) {
    return invalid_argument(what + " is not positive semi-definite");
  }
  return Status::ok();
}

Status validate_noise_covariances(const FilterSettings& s, const Model& model) {
  if (s.optimal.V.size() != 0 || s.optimal.W.size() != 0) {
    return invalid_argument("the optimal filter's weights V and W do not apply to a filter with noise covariances Q and R");
  }
  RICCATI_RETURN_IF_ERROR(check_covariance(s.Q, model.nz(), "process noise Q"));
  return check_covariance(s.R, model.ny(), "measurement noise R");
}

Status validate(const FilterSettings& s, const Model& model) {
  RICCATI_RETURN_IF_ERROR(validate(s.integrator));
  return filter_kind_info(s.kind).validate(s, model);
}

Result<Eigen::MatrixXd> covariance_from_confidence(const Eigen::MatrixXd& R, const std::string& what) {
  const Eigen::Index n = R.rows();
  if (R.cols() != n || !R.allFinite()) return invalid_argument(what + " must be a finite square matrix");
  Eigen::LLT<Eigen::MatrixXd> llt(R);
  if (llt.info() != Eigen::Success) return invalid_argument(what + " must be positive definite");
  return Eigen::MatrixXd(llt.solve(Eigen::MatrixXd::Identity(n, n)));
}

const Eigen::VectorXd Filter::kNothing;

Filter::Filter(ModelPtr model, FilterSettings settings)
    : model_(std::move(model)), settings_(std::move(settings)), hold_(settings_.hold, model_->nu()) {
  const Eigen::Index nz = model_->nz(), ny = model_->ny();
  z_ = Eigen::VectorXd::Zero(nz);
  P_ = Eigen::MatrixXd::Zero(nz, nz);
  y_pred_ = Eigen::VectorXd::Zero(ny);
  innovation_ = Eigen::VectorXd::Zero(ny);
  S_ = Eigen::MatrixXd::Zero(ny, ny);
  if (settings_.smoothing) {
    prediction_.z = Eigen::VectorXd::Zero(nz);
    prediction_.P = Eigen::MatrixXd::Zero(nz, nz);
    prediction_.C = Eigen::MatrixXd::Zero(nz, nz);
  }
}

Status Filter::reset(double t, const Eigen::VectorXd& z, const Eigen::MatrixXd& P) {
  if (!std::isfinite(t)) return invalid_argument("initial time is not finite");
  if (z.size() != model_->nz()) {
    return invalid_argument("initial state has " + std::to_string(z.size()) + " entries, model " + model_->name() +
                            " has nx + ntheta = " + std::to_string(model_->nz()));
  }
  if (!z.allFinite()) return invalid_argument("initial state has a NaN or infinite entry");
  RICCATI_RETURN_IF_ERROR(check_covariance(P, model_->nz(), "initial covariance P0"));
  t_ = t;
  z_ = z;
  P_ = P;
  restarted();
  return Status::ok();
}

Status Filter::retune(const FilterSettings& settings) {
  if (settings.kind != settings_.kind) return invalid_argument("a retuning cannot change the filter's kind");
  RICCATI_RETURN_IF_ERROR(validate(settings, *model_));
  settings_.Q = settings.Q;
  settings_.R = settings.R;
  settings_.optimal.V = settings.optimal.V;
  settings_.optimal.W = settings.optimal.W;
  noise_changed();
  return Status::ok();
}

Status Filter::restore(double t, const Eigen::VectorXd& z, const Eigen::MatrixXd& P, const Eigen::VectorXd& carried) {
  const Eigen::Index nz = model_->nz();
  if (z.size() != nz || P.rows() != nz || P.cols() != nz) {
    return invalid_argument("saved filter state has " + std::to_string(z.size()) + " states and a " +
                            size_text(P) + " covariance, model " +
                            model_->name() + " has nz = " + std::to_string(nz));
  }
  t_ = t;
  z_ = z;
  P_ = P;
  restarted();
  if (!restore_carried(carried)) {
    return invalid_argument("saved filter state carries " + std::to_string(carried.size()) +
                            " values this filter does not expect");
  }
  return Status::ok();
}

void Filter::clamp_parameters(const Eigen::VectorXd& lower, const Eigen::VectorXd& upper, Eigen::VectorXi* hits) {
  const Eigen::Index nx = model_->nx();
  for (Eigen::Index i = 0; i < lower.size(); ++i) {
    double& theta = z_[nx + i];
    if (theta < lower[i]) {
      theta = lower[i];
      ++(*hits)[i];
    } else if (theta > upper[i]) {
      theta = upper[i];
      ++(*hits)[i];
    }
  }
}

Status Filter::step(double t1, const double* u0, const double* u1, const double* y1) {
  RICCATI_RETURN_IF_ERROR(predict(t1, u0, u1));
  return update(y1, u1);
}

std::string Filter::element_name(Eigen::Index i) const {
  const Eigen::Index nx = model_->nx();
  const auto& names = i < nx ? model_->state_names() : model_->param_names();
  const Eigen::Index k = i < nx ? i : i - nx;
  const char* kind = i < nx ? "state " : "parameter ";
  return k < static_cast<Eigen::Index>(names.size()) ? kind + names[static_cast<std::size_t>(k)]
                                                      : "element " + std::to_string(i);
}

Status Filter::check_estimate(const char* where) const {
  // The message is built only on failure: this runs at every sample. It
  // names the first state or parameter that went wrong, as the user named it.
  auto diverged = [&](const std::string& what) {
    return failed_precondition("filter diverged: " + what + " after the " + where + " at t = " + std::to_string(t_));
  };
  if (!z_.allFinite()) {
    Eigen::Index i = 0;
    while (std::isfinite(z_[i])) ++i;
    return diverged("the estimate of " + element_name(i) + " is " + std::to_string(z_[i]));
  }
  if (!P_.allFinite()) {
    Eigen::Index i = 0;
    while (P_.row(i).allFinite()) ++i;
    return diverged("the covariance of " + element_name(i) + " is not finite");
  }
  const double scale = std::max(1.0, P_.diagonal().cwiseAbs().maxCoeff());
  for (Eigen::Index i = 0; i < P_.rows(); ++i) {
    if (P_(i, i) < -1e-9 * scale) {
      return diverged("the covariance lost positive semi-definiteness (the variance of " + element_name(i) + " is " +
                      std::to_string(P_(i, i)) + ")");
    }
  }
  return Status::ok();
}

Result<std::unique_ptr<Filter>> make_filter(ModelPtr model, const FilterSettings& settings) {
  if (model == nullptr) return invalid_argument("no model given");
  RICCATI_RETURN_IF_ERROR(validate(settings, *model));
  RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Integrator> integrator, make_integrator(settings.integrator));
  return filter_kind_info(settings.kind).make(std::move(model), settings, std::move(integrator));
}

}  // namespace riccati
