#include "engine/estimation/estimate.hpp"

#include "engine/estimation/uncertainty.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace riccati {
namespace {


}  // namespace

std::span<const IdentificationMethodInfo> identification_methods() {
  static constexpr IdentificationMethodInfo kMethods[] = {
      {IdentificationMethod::kFilter, "filter",
       "the iterated filter of the 1999 toolbox: passes of the EKF, UKF or optimal filter, the parameters as states",
       true, false, false},
      {IdentificationMethod::kOutputError, "oe",
       "output error: the simulated outputs' weighted squared errors minimised (exact sensitivities)", false, true,
       false},
      {IdentificationMethod::kMaxLikelihood, "ml",
       "maximum likelihood: the negative log-likelihood of the CD-EKF's or CD-UKF's innovations minimised", false,
       true, true},
  };
  return kMethods;
}

const IdentificationMethodInfo& identification_method_info(IdentificationMethod method) {
  for (const IdentificationMethodInfo& info : identification_methods()) {
    if (info.method == method) return info;
  }
  return identification_methods().front();  // unreachable: every enumerator has its row (a test checks)
}

const char* identification_method_name(IdentificationMethod method) {
  return identification_method_info(method).name.data();
}

Result<IdentificationMethod> parse_identification_method(std::string_view name) {
  std::string names;
  for (const IdentificationMethodInfo& info : identification_methods()) {
    if (name == info.name) return info.method;
    names += (names.empty() ? "" : ", ") + std::string(info.name);
  }
  return invalid_argument("unknown identification method \"" + std::string(name) + "\" (expected " + names + ")");
}

ParameterSettings default_parameters(const Model& model, Eigen::VectorXd theta0) {
  ParameterSettings p;
  p.theta0 = std::move(theta0);
  p.lower = model.theta_lower();
  p.upper = model.theta_upper();
  p.fixed.assign(static_cast<std::size_t>(model.ntheta()), false);
  p.log_scale.assign(static_cast<std::size_t>(model.ntheta()), false);
  return p;
}

Status validate(const ParameterSettings& p, const Model& model) {
  const Eigen::Index n = model.ntheta();
  const auto count = [](std::size_t size) { return static_cast<Eigen::Index>(size); };
  if (p.theta0.size() != n || p.lower.size() != n || p.upper.size() != n || count(p.fixed.size()) != n ||
      count(p.log_scale.size()) != n) {
    return invalid_argument("the parameter settings need " + std::to_string(n) + " values each (model " +
                            model.name() + ")");
  }
  for (Eigen::Index i = 0; i < n; ++i) {
    const std::string& name = model.param_names()[static_cast<std::size_t>(i)];
    const double lo = p.lower[i], hi = p.upper[i], v = p.theta0[i];
    if (!std::isfinite(v)) return invalid_argument("theta0 of " + name + " is not finite");
    if (std::isnan(lo) || std::isnan(hi) || lo > hi) {
      return invalid_argument("the bounds of " + name + " are not an interval: [" + message_number(lo) + ", " + message_number(hi) +
                              "]");
    }
    if (v < lo || v > hi) {
      return invalid_argument("theta0 of " + name + " = " + message_number(v) + " is outside its bounds [" + message_number(lo) +
                              ", " + message_number(hi) + "]");
    }
    if (p.log_scale[static_cast<std::size_t>(i)] && !(lo > 0.0)) {
      return invalid_argument(name + " is estimated on a log scale, so it needs a positive lower bound (it has " +
                              message_number(lo) + ")");
    }
  }
  return Status::ok();
}

double to_solver(const ParameterSettings& p, Eigen::Index i, double theta) {
  return p.log_scale[static_cast<std::size_t>(i)] ? std::log(theta) : theta;
}

double from_solver(const ParameterSettings& p, Eigen::Index i, double phi) {
  return p.log_scale[static_cast<std::size_t>(i)] ? std::exp(phi) : phi;
}

double theta_per_phi(const ParameterSettings& p, Eigen::Index i, double theta) {
  return p.log_scale[static_cast<std::size_t>(i)] ? theta : 1.0;
}

Status validate(const Experiment& e, const Model& model, std::size_t index) {
  const std::string which = "experiment " + std::to_string(index + 1) +
                            (e.data.name.empty() ? std::string() : " (" + e.data.name + ")");
  RICCATI_RETURN_IF_ERROR(validate_dataset(e.data).with_context(which));
  if (e.data.num_inputs() != model.nu() || e.data.num_outputs() != model.ny()) {
    return invalid_argument(which + ": the data are not bound to model " + model.name());
  }
  if (e.x0.size() != model.nx() || !e.x0.allFinite()) {
    return invalid_argument(which + ": x0 needs " + std::to_string(model.nx()) + " finite values");
  }
  if (!e.estimate_x0.empty() && static_cast<int>(e.estimate_x0.size()) != model.nx()) {
    return invalid_argument(which + ": which initial states to estimate needs " + std::to_string(model.nx()) +
                            " flags");
  }
  if (e.mask.size() != 0) {
    if (e.mask.rows() != model.ny() || e.mask.cols() != e.data.size()) {
      return invalid_argument(which + ": the sample mask must be " + std::to_string(model.ny()) + " x " +
                              std::to_string(e.data.size()));
    }
    if (((e.mask != 0.0) && (e.mask != 1.0)).any()) return invalid_argument(which + ": the mask holds 0 and 1 only");
    if ((e.mask.rowwise().sum() == 0.0).any()) {
      return invalid_argument(which + ": an output has every sample excluded");
    }
  }
  return Status::ok();
}

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

void set_information_criteria(double log_likelihood, int estimated_quantities, double samples,
                              EstimationResult* result) {
  InformationCriteria& c = result->criteria;
  const double k = estimated_quantities;
  c.log_likelihood = log_likelihood;
  c.estimated_quantities = estimated_quantities;
  c.samples = samples;
  c.aic = 2.0 * k - 2.0 * log_likelihood;
  c.aicc = samples - k - 1.0 > 0.0 ? c.aic + 2.0 * k * (k + 1.0) / (samples - k - 1.0)
                                   : std::numeric_limits<double>::infinity();
  c.bic = k * std::log(samples) - 2.0 * log_likelihood;
}

double chi_square_survival(double x, unsigned dof) {
  if (dof == 0) return std::numeric_limits<double>::quiet_NaN();
  if (!(x > 0.0)) return 1.0;
  if (std::isinf(x)) return 0.0;
  // Abramowitz and Stegun 26.4.4 and 26.4.5: for even dof, e^{-x/2} sum_{r <
  // dof/2} (x/2)^r / r!; for odd, the normal's two tails at sqrt(x) and 2
  // phi(sqrt x) sum_{r=1}^{(dof-1)/2} x^{r - 1/2} / (1 3 5 ... (2r - 1)).
  const double half = 0.5 * x;
  double sum = 0.0, term = 0.0;
  if (dof % 2 == 0) {
    term = std::exp(-half);
    for (unsigned r = 0; r < dof / 2; ++r) {
      sum += term;
      term *= half / static_cast<double>(r + 1);
    }
    return std::min(1.0, sum);
  }
  const double root = std::sqrt(x);
  term = std::sqrt(2.0 / std::numbers::pi) * std::exp(-half) * root;  // r = 1
  for (unsigned r = 1; r <= (dof - 1) / 2; ++r) {
    sum += term;
    term *= x / static_cast<double>(2 * r + 1);
  }
  return std::min(1.0, std::erfc(root / std::sqrt(2.0)) + sum);
}

void warn_active_bounds(const ParameterSettings& p, EstimationResult* r) {
  const std::vector<std::string>& names = r->param_names;
  for (Eigen::Index i = 0; i < r->theta.size(); ++i) {
    if (p.fixed[static_cast<std::size_t>(i)]) continue;
    const double v = r->theta[i], tolerance = 1e-9 * std::max(1.0, std::abs(v));
    const char* which = std::abs(v - p.lower[i]) <= tolerance ? "lower" : std::abs(v - p.upper[i]) <= tolerance ? "upper" : nullptr;
    if (which != nullptr) {
      r->warnings.push_back(names[static_cast<std::size_t>(i)] + " ended on its " + which + " bound " + message_number(v) +
                            ": the best fit may lie beyond it");
    }
  }
}

void set_parameter_uncertainty(const ParameterSettings& p, const Uncertainty& u, const std::vector<Eigen::Index>& columns,
                               EstimationResult* result) {
  const Eigen::Index ntheta = result->theta.size();
  result->warnings.insert(result->warnings.end(), u.warnings.begin(), u.warnings.end());
  result->theta_std = Eigen::VectorXd::Zero(ntheta);
  result->covariance = Eigen::MatrixXd::Zero(ntheta, ntheta);
  result->correlation = Eigen::MatrixXd::Identity(ntheta, ntheta);
  result->ci_lower = result->theta;
  result->ci_upper = result->theta;
  for (Eigen::Index a = 0; a < ntheta; ++a) {
    const Eigen::Index ca = columns[static_cast<std::size_t>(a)];
    if (ca < 0) continue;
    result->theta_std[a] = u.std[ca];
    for (Eigen::Index b = 0; b < ntheta; ++b) {
      const Eigen::Index cb = columns[static_cast<std::size_t>(b)];
      if (cb < 0) continue;
      result->covariance(a, b) = u.covariance(ca, cb);
      result->correlation(a, b) = u.correlation(ca, cb);
    }
    confidence_interval(result->theta[a], result->theta_std[a], p.log_scale[static_cast<std::size_t>(a)],
                        &result->ci_lower[a], &result->ci_upper[a]);
  }
}

Result<ResidualDiagnostics> diagnose(const ExperimentResult& e, const Eigen::MatrixXd& inputs, const Eigen::VectorXd* nis) {
  std::vector<Eigen::Index> used;
  for (Eigen::Index k = 0; k < e.residuals.cols(); ++k) {
    if (e.mask.size() == 0 || (e.mask.col(k) != 0.0).all()) used.push_back(k);
  }
  const auto n = static_cast<Eigen::Index>(used.size());
  Eigen::MatrixXd r(e.residuals.rows(), n), u(inputs.rows(), n);
  Eigen::VectorXd s(nis != nullptr ? n : 0);
  for (Eigen::Index c = 0; c < n; ++c) {
    r.col(c) = e.residuals.col(used[static_cast<std::size_t>(c)]);
    u.col(c) = inputs.col(used[static_cast<std::size_t>(c)]);
    if (nis != nullptr) s[c] = (*nis)[used[static_cast<std::size_t>(c)]];
  }
  return diagnose_residuals(r, u, nis != nullptr ? &s : nullptr);
}

}  // namespace riccati
