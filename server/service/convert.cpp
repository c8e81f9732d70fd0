#include "service/convert.hpp"

#include <Eigen/Cholesky>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>

namespace riccati::service {

grpc::Status to_grpc(const Status& status) {
  if (status.is_ok()) return grpc::Status::OK;
  return {static_cast<grpc::StatusCode>(status.code()), status.message()};
}

v1::Error to_error(const Status& status) {
  v1::Error e;
  e.set_code(static_cast<int>(status.code()));
  e.set_message(status.message());
  return e;
}

std::int64_t now_ms() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

std::string new_id(std::string_view prefix) {
  thread_local std::mt19937_64 rng{std::random_device{}()};
  char digits[17];
  std::snprintf(digits, sizeof digits, "%016llx", static_cast<unsigned long long>(rng()));
  return std::string(prefix) + "-" + digits;
}

void set_timestamp(std::int64_t unix_ms, google::protobuf::Timestamp* out) {
  out->set_seconds(unix_ms / 1000);
  out->set_nanos(static_cast<int>((unix_ms % 1000) * 1000000));
}

v1::Matrix to_matrix(const Eigen::MatrixXd& m) {
  v1::Matrix out;
  out.set_rows(static_cast<uint32_t>(m.rows()));
  out.set_cols(static_cast<uint32_t>(m.cols()));
  out.mutable_values()->Add(m.data(), m.data() + m.size());
  return out;
}

Result<Eigen::MatrixXd> from_matrix(const v1::Matrix& m, const std::string& field) {
  const std::int64_t expected = static_cast<std::int64_t>(m.rows()) * m.cols();
  if (expected != m.values_size()) {
    return invalid_argument(field + ": a " + std::to_string(m.rows()) + " x " + std::to_string(m.cols()) +
                            " matrix needs " + std::to_string(expected) + " values, got " +
                            std::to_string(m.values_size()));
  }
  Eigen::MatrixXd out = Eigen::Map<const Eigen::MatrixXd>(m.values().data(), m.rows(), m.cols());
  if (!out.allFinite()) return invalid_argument(field + " has a NaN or infinite value");
  return out;
}

Result<Eigen::VectorXd> from_values(const google::protobuf::RepeatedField<double>& v, Eigen::Index expected,
                                    const std::string& field) {
  if (v.size() != expected) {
    return invalid_argument(field + " needs " + std::to_string(expected) + " values, got " +
                            std::to_string(v.size()));
  }
  Eigen::VectorXd out = Eigen::Map<const Eigen::VectorXd>(v.data(), v.size());
  for (Eigen::Index i = 0; i < out.size(); ++i) {
    if (!std::isfinite(out[i])) return invalid_argument(field + "[" + std::to_string(i) + "] is not finite");
  }
  return out;
}

Result<Eigen::MatrixXd> from_covariance(const v1::Covariance& c, Eigen::Index n, bool required,
                                        const std::string& field) {
  switch (c.form_case()) {
    case v1::Covariance::kDiagonal: {
      RICCATI_ASSIGN_OR_RETURN(const Eigen::VectorXd d, from_values(c.diagonal().values(), n, field + ".diagonal"));
      return Eigen::MatrixXd(d.asDiagonal());
    }
    case v1::Covariance::kFull: {
      RICCATI_ASSIGN_OR_RETURN(Eigen::MatrixXd m, from_matrix(c.full(), field + ".full"));
      if (m.rows() != n || m.cols() != n) {
        return invalid_argument(field + ".full must be " + std::to_string(n) + " x " + std::to_string(n));
      }
      return m;
    }
    case v1::Covariance::kScalar: {
      if (!std::isfinite(c.scalar())) return invalid_argument(field + ".scalar is not finite");
      return Eigen::MatrixXd(Eigen::MatrixXd::Identity(n, n) * c.scalar());
    }
    case v1::Covariance::FORM_NOT_SET:
      break;
  }
  if (required) return invalid_argument(field + " is required (" + std::to_string(n) + " values on the diagonal)");
  return Eigen::MatrixXd(Eigen::MatrixXd::Zero(n, n));
}

Result<IntegratorSettings> from_proto(const v1::IntegratorSettings& s) {
  IntegratorSettings out;
  switch (s.kind()) {
    case v1::INTEGRATOR_KIND_UNSPECIFIED:
    case v1::INTEGRATOR_KIND_RK4: out.kind = IntegratorKind::kRk4; break;
    case v1::INTEGRATOR_KIND_RK3: out.kind = IntegratorKind::kRk3; break;
    case v1::INTEGRATOR_KIND_CVODE_BDF: out.kind = IntegratorKind::kCvodeBdf; break;
    case v1::INTEGRATOR_KIND_CVODE_ADAMS: out.kind = IntegratorKind::kCvodeAdams; break;
    case v1::INTEGRATOR_KIND_ARKODE_ERK: out.kind = IntegratorKind::kArkodeErk; break;
    default: return invalid_argument("integrator.kind " + std::to_string(s.kind()) + " is unknown");
  }
  if (s.substeps() != 0) out.substeps = static_cast<int>(std::min<uint32_t>(s.substeps(), 1000001));
  if (s.rtol() != 0.0) out.rtol = s.rtol();
  if (s.atol() != 0.0) out.atol = s.atol();
  if (s.max_steps() != 0) out.max_steps = static_cast<long>(std::min<uint64_t>(s.max_steps(), 1000000000));
  RICCATI_RETURN_IF_ERROR(validate(out));
  return out;
}

HoldOrder from_proto(v1::HoldOrder hold) {
  return hold == v1::HOLD_ORDER_FIRST ? HoldOrder::kFirst : HoldOrder::kZero;
}

namespace {

// The optimal filter's weights; it has no Q and no R.
Status optimal_from_proto(const v1::FilterSettings& s, const Model& model, FilterSettings* out) {
  if (s.has_q() || s.has_r()) {
    return invalid_argument("filter.q and filter.r do not apply to the optimal filter: give filter.optimal.v and w");
  }
  if (!model.has_mechanical_form()) {
    return invalid_argument("model " + model.name() +
                            " has no mechanical form (M a + h = H u): the optimal filter needs one");
  }
  const v1::OptimalSettings& o = s.optimal();
  RICCATI_ASSIGN_OR_RETURN(out->optimal.V, from_covariance(o.v(), optimal_equation_count(model), true,
                                                           "filter.optimal.v"));
  RICCATI_ASSIGN_OR_RETURN(out->optimal.W, from_covariance(o.w(), model.nz(), true, "filter.optimal.w"));
  switch (o.form()) {
    case v1::OPTIMAL_FORM_UNSPECIFIED:
    case v1::OPTIMAL_FORM_CONTINUOUS: out->optimal.form = OptimalForm::kContinuous; break;
    case v1::OPTIMAL_FORM_SPLIT_STEP: out->optimal.form = OptimalForm::kSplitStep; break;
    default: return invalid_argument("filter.optimal.form " + std::to_string(o.form()) + " is unknown");
  }
  out->optimal.interpolate_outputs = !o.hold_outputs();
  return Status::ok();
}

}  // namespace

Result<FilterSettings> from_proto(const v1::FilterSettings& s, const Model& model) {
  FilterSettings out;
  switch (s.kind()) {
    case v1::FILTER_KIND_UNSPECIFIED:
    case v1::FILTER_KIND_EKF: out.kind = FilterKind::kEkf; break;
    case v1::FILTER_KIND_UKF: out.kind = FilterKind::kUkf; break;
    case v1::FILTER_KIND_OPTIMAL: out.kind = FilterKind::kOptimal; break;
    default: return invalid_argument("filter.kind " + std::to_string(s.kind()) + " is unknown");
  }
  if (s.hold() != v1::HOLD_ORDER_UNSPECIFIED && s.hold() != v1::HOLD_ORDER_ZERO && s.hold() != v1::HOLD_ORDER_FIRST) {
    return invalid_argument("filter.hold " + std::to_string(s.hold()) + " is unknown");
  }
  out.hold = from_proto(s.hold());
  RICCATI_ASSIGN_OR_RETURN(out.integrator, from_proto(s.integrator()));
  if (out.kind == FilterKind::kOptimal) {
    RICCATI_RETURN_IF_ERROR(optimal_from_proto(s, model, &out));
    Status valid = validate(out, model);
    if (!valid.is_ok()) return valid.with_context("filter");
    return out;
  }
  if (s.has_optimal()) return invalid_argument("filter.optimal applies to the optimal filter only");
  RICCATI_ASSIGN_OR_RETURN(out.Q, from_covariance(s.q(), model.nz(), false, "filter.q"));
  RICCATI_ASSIGN_OR_RETURN(out.R, from_covariance(s.r(), model.ny(), true, "filter.r"));
  switch (s.inversion()) {
    case v1::GAIN_INVERSION_UNSPECIFIED:
    case v1::GAIN_INVERSION_CHOLESKY: out.inversion = GainInversion::kCholesky; break;
    case v1::GAIN_INVERSION_PSEUDO_INVERSE: out.inversion = GainInversion::kPseudoInverse; break;
    default: return invalid_argument("filter.inversion " + std::to_string(s.inversion()) + " is unknown");
  }
  out.joseph = !s.short_covariance_update();
  switch (s.ukf().weights()) {
    case v1::SIGMA_WEIGHTS_UNSPECIFIED:
    case v1::SIGMA_WEIGHTS_JULIER: out.ukf.weights = SigmaWeights::kJulier; break;
    case v1::SIGMA_WEIGHTS_SCALED: out.ukf.weights = SigmaWeights::kScaled; break;
    default: return invalid_argument("filter.ukf.weights " + std::to_string(s.ukf().weights()) + " is unknown");
  }
  if (s.ukf().has_alpha()) out.ukf.alpha = s.ukf().alpha();
  if (s.ukf().has_beta()) out.ukf.beta = s.ukf().beta();
  if (s.ukf().has_kappa()) out.ukf.kappa = s.ukf().kappa();
  Status valid = validate(out, model);
  if (!valid.is_ok()) return valid.with_context("filter");
  return out;
}

Result<Eigen::MatrixXd> initial_covariance(const v1::Covariance& p0, const v1::FilterSettings& filter,
                                           const Model& model) {
  if (!filter.optimal().has_r0()) return from_covariance(p0, model.nz(), true, "p0");
  if (p0.form_case() != v1::Covariance::FORM_NOT_SET) {
    return invalid_argument("give either p0 or filter.optimal.r0 (its inverse), not both");
  }
  RICCATI_ASSIGN_OR_RETURN(const Eigen::MatrixXd R0,
                           from_covariance(filter.optimal().r0(), model.nz(), true, "filter.optimal.r0"));
  Eigen::LLT<Eigen::MatrixXd> llt(R0);
  if (llt.info() != Eigen::Success) return invalid_argument("filter.optimal.r0 must be positive definite");
  return Eigen::MatrixXd(llt.solve(Eigen::MatrixXd::Identity(model.nz(), model.nz())));
}

void initial_state_from_proto(const v1::InitialState& s, InitialState* mode, Eigen::VectorXd* x0) {
  *mode = s.first_measurement() ? InitialState::kFirstMeasurement : InitialState::kGiven;
  *x0 = Eigen::Map<const Eigen::VectorXd>(s.x0().data(), s.x0_size());
}

Result<IdentificationSettings> from_proto(const v1::IdentificationSpec& spec, const Model& model) {
  IdentificationSettings out;
  RICCATI_ASSIGN_OR_RETURN(out.filter, from_proto(spec.filter(), model));
  initial_state_from_proto(spec.initial_state(), &out.initial_state, &out.x0);
  if (spec.theta0_size() == 0) {
    out.theta0 = model.theta_default();
  } else {
    RICCATI_ASSIGN_OR_RETURN(out.theta0, from_values(spec.theta0(), model.ntheta(), "theta0"));
  }
  RICCATI_ASSIGN_OR_RETURN(out.P0, initial_covariance(spec.p0(), spec.filter(), model));
  out.passes = spec.passes() == 0 ? 1 : static_cast<int>(std::min<uint32_t>(spec.passes(), 1u << 30));
  out.first_sample = static_cast<Eigen::Index>(spec.first_sample());
  out.end_sample = spec.end_sample() == 0 ? -1 : static_cast<Eigen::Index>(spec.end_sample());
  RICCATI_RETURN_IF_ERROR(validate(out, model));
  return out;
}

Result<ValidationSettings> from_proto(const v1::ValidationSpec& spec, const Model& /*model*/) {
  ValidationSettings out;
  RICCATI_ASSIGN_OR_RETURN(out.simulation.integrator, from_proto(spec.integrator()));
  out.simulation.hold = from_proto(spec.hold());
  initial_state_from_proto(spec.initial_state(), &out.initial_state, &out.x0);
  return out;
}

v1::ModelInfo to_proto(const Model& model) {
  v1::ModelInfo info;
  info.set_name(model.name());
  info.set_version(model.version());
  info.set_description(model.description());
  for (const auto& n : model.state_names()) info.add_state_names(n);
  for (const auto& n : model.param_names()) info.add_param_names(n);
  for (const auto& n : model.input_names()) info.add_input_names(n);
  for (const auto& n : model.output_names()) info.add_output_names(n);
  copy_values(model.theta_default(), info.mutable_theta_default());
  copy_values(model.theta_lower(), info.mutable_theta_lower());
  copy_values(model.theta_upper(), info.mutable_theta_upper());
  info.set_exact_f_jacobian(model.has_f_jacobian());
  info.set_exact_g_jacobian(model.has_g_jacobian());
  info.set_ndof(static_cast<uint32_t>(model.ndof()));
  return info;
}

v1::DatasetInfo to_proto(const DatasetRecord& r) {
  v1::DatasetInfo info;
  info.set_id(r.id);
  info.set_name(r.name);
  info.set_format(r.format == "mat" ? v1::DATASET_FORMAT_MAT : v1::DATASET_FORMAT_CSV);
  for (const auto& n : r.input_names) info.add_input_names(n);
  for (const auto& n : r.output_names) info.add_output_names(n);
  info.set_samples(static_cast<uint64_t>(r.samples));
  info.set_t_start(r.t_start);
  info.set_t_end(r.t_end);
  info.set_size_bytes(static_cast<uint64_t>(r.size_bytes));
  set_timestamp(r.created_ms, info.mutable_created());
  return info;
}

v1::IdentificationResult to_proto(const IdentificationResult& r) {
  v1::IdentificationResult out;
  for (const auto& n : r.param_names) out.add_param_names(n);
  for (const PassResult& p : r.passes) {
    v1::PassResult* pass = out.add_passes();
    *pass->mutable_theta_trace() = to_matrix(p.theta_trace);
    copy_values(p.theta_final, pass->mutable_theta_final());
    copy_values(p.theta_mean, pass->mutable_theta_mean());
    copy_values(p.theta_std, pass->mutable_theta_std());
    copy_values(p.innovation_rms, pass->mutable_innovation_rms());
    pass->set_nis_mean(p.nis_mean);
  }
  copy_values(r.theta, out.mutable_theta());
  copy_values(r.theta_mean, out.mutable_theta_mean());
  copy_values(r.theta_std, out.mutable_theta_std());
  *out.mutable_covariance() = to_matrix(r.covariance);
  copy_values(r.t, out.mutable_t());
  *out.mutable_x_trace() = to_matrix(r.x_trace);
  *out.mutable_y_model() = to_matrix(r.y_model);
  *out.mutable_innovations() = to_matrix(r.innovations);
  return out;
}

Result<IdentificationResult> from_proto(const v1::IdentificationResult& r) {
  IdentificationResult out;
  out.param_names.assign(r.param_names().begin(), r.param_names().end());
  const auto n = static_cast<Eigen::Index>(out.param_names.size());
  for (int i = 0; i < r.passes_size(); ++i) {
    const v1::PassResult& p = r.passes(i);
    const std::string where = "passes[" + std::to_string(i) + "]";
    PassResult pass;
    RICCATI_ASSIGN_OR_RETURN(pass.theta_trace, from_matrix(p.theta_trace(), where + ".theta_trace"));
    RICCATI_ASSIGN_OR_RETURN(pass.theta_final, from_values(p.theta_final(), n, where + ".theta_final"));
    RICCATI_ASSIGN_OR_RETURN(pass.theta_mean, from_values(p.theta_mean(), n, where + ".theta_mean"));
    RICCATI_ASSIGN_OR_RETURN(pass.theta_std, from_values(p.theta_std(), n, where + ".theta_std"));
    RICCATI_ASSIGN_OR_RETURN(pass.innovation_rms,
                             from_values(p.innovation_rms(), p.innovation_rms_size(), where + ".innovation_rms"));
    pass.nis_mean = p.nis_mean();
    out.passes.push_back(std::move(pass));
  }
  RICCATI_ASSIGN_OR_RETURN(out.theta, from_values(r.theta(), n, "theta"));
  RICCATI_ASSIGN_OR_RETURN(out.theta_mean, from_values(r.theta_mean(), n, "theta_mean"));
  RICCATI_ASSIGN_OR_RETURN(out.theta_std, from_values(r.theta_std(), n, "theta_std"));
  RICCATI_ASSIGN_OR_RETURN(out.covariance, from_matrix(r.covariance(), "covariance"));
  RICCATI_ASSIGN_OR_RETURN(out.t, from_values(r.t(), r.t_size(), "t"));
  RICCATI_ASSIGN_OR_RETURN(out.x_trace, from_matrix(r.x_trace(), "x_trace"));
  RICCATI_ASSIGN_OR_RETURN(out.y_model, from_matrix(r.y_model(), "y_model"));
  RICCATI_ASSIGN_OR_RETURN(out.innovations, from_matrix(r.innovations(), "innovations"));
  return out;
}

v1::ValidationResult to_proto(const ValidationResult& r, const Eigen::VectorXd& theta) {
  v1::ValidationResult out;
  copy_values(theta, out.mutable_theta());
  copy_values(r.t, out.mutable_t());
  *out.mutable_y_measured() = to_matrix(r.y_measured);
  *out.mutable_y_simulated() = to_matrix(r.y_simulated);
  for (const OutputFit& f : r.fits) {
    v1::OutputFit* fit = out.add_fits();
    fit->set_name(f.name);
    fit->set_rmse(f.rmse);
    fit->set_fit_percent(f.fit_percent);
    fit->set_vaf_percent(f.vaf_percent);
    fit->set_rrse(f.rrse);
  }
  return out;
}

v1::FilterKind to_proto(FilterKind kind) {
  switch (kind) {
    case FilterKind::kEkf: return v1::FILTER_KIND_EKF;
    case FilterKind::kUkf: return v1::FILTER_KIND_UKF;
    case FilterKind::kOptimal: return v1::FILTER_KIND_OPTIMAL;
  }
  return v1::FILTER_KIND_UNSPECIFIED;
}

v1::JobState to_proto(JobState state) {
  switch (state) {
    case JobState::kQueued: return v1::JOB_STATE_QUEUED;
    case JobState::kRunning: return v1::JOB_STATE_RUNNING;
    case JobState::kSucceeded: return v1::JOB_STATE_SUCCEEDED;
    case JobState::kFailed: return v1::JOB_STATE_FAILED;
    case JobState::kCancelled: return v1::JOB_STATE_CANCELLED;
  }
  return v1::JOB_STATE_UNSPECIFIED;
}

}  // namespace riccati::service
