#include "service/jobs/job_convert.hpp"

#include <algorithm>

#include "service/convert.hpp"
#include "service/run_settings.hpp"

namespace riccati::service {

Result<IdentificationSettings> from_proto(const v1::IdentificationSpec& spec, const Model& model) {
  IdentificationSettings out;
  RICCATI_ASSIGN_OR_RETURN(out.filter, from_proto(spec.filter(), model));
  RICCATI_ASSIGN_OR_RETURN(out.initial, initial_estimate_from_proto(spec.initial_state(), spec.theta0(), spec.p0(),
                                                                    spec.filter(), model));
  out.passes = spec.passes() == 0 ? 1 : static_cast<int>(std::min<uint32_t>(spec.passes(), 1u << 30));
  out.first_sample = static_cast<Eigen::Index>(spec.first_sample());
  out.end_sample = spec.end_sample() == 0 ? -1 : static_cast<Eigen::Index>(spec.end_sample());
  RICCATI_RETURN_IF_ERROR(validate(out, model));
  return out;
}

Result<SmootherSettings> from_proto(const v1::SmoothingSpec& spec, const Model& model) {
  SmootherSettings out;
  RICCATI_ASSIGN_OR_RETURN(out.filter, from_proto(spec.filter(), model));
  RICCATI_ASSIGN_OR_RETURN(out.initial, initial_estimate_from_proto(spec.initial_state(), spec.theta0(), spec.p0(),
                                                                    spec.filter(), model));
  out.first_sample = static_cast<Eigen::Index>(spec.first_sample());
  out.end_sample = spec.end_sample() == 0 ? -1 : static_cast<Eigen::Index>(spec.end_sample());
  RICCATI_RETURN_IF_ERROR(validate(out, model));
  return out;
}

v1::SmoothingResult to_proto(const SmootherResult& r, bool full_covariance) {
  v1::SmoothingResult out;
  for (const auto& n : r.names) out.add_names(n);
  copy_values(r.t, out.mutable_t());
  *out.mutable_z_filtered() = to_matrix(r.z_filtered);
  *out.mutable_std_filtered() = to_matrix(r.std_filtered);
  *out.mutable_z_smoothed() = to_matrix(r.z_smoothed);
  *out.mutable_std_smoothed() = to_matrix(r.std_smoothed);
  *out.mutable_y_model() = to_matrix(r.y_model);
  *out.mutable_innovations() = to_matrix(r.innovations);
  if (full_covariance) *out.mutable_covariances() = to_matrix(r.P_smoothed);
  return out;
}

v1::Diagnostics to_proto(const ResidualDiagnostics& d) {
  v1::Diagnostics out;
  out.set_samples(static_cast<uint64_t>(d.samples));
  out.set_lags(static_cast<uint32_t>(d.lags));
  out.set_band(d.band);
  *out.mutable_autocorrelation() = to_matrix(d.autocorrelation);
  copy_values(d.ljung_box, out.mutable_ljung_box());
  out.set_ljung_box_limit(d.ljung_box_limit);
  *out.mutable_cross_correlation() = to_matrix(d.cross_correlation);
  copy_values(d.cross_statistic, out.mutable_cross_statistic());
  copy_values(d.cross_limit, out.mutable_cross_limit());
  out.set_nis_mean(d.nis_mean);
  out.set_nis_lower(d.nis_lower);
  out.set_nis_upper(d.nis_upper);
  out.set_white(d.white());
  out.set_uncorrelated_with_inputs(d.uncorrelated_with_inputs());
  out.set_nis_consistent(d.nis_consistent());
  out.set_summary(d.summary());
  out.set_ljung_box_dof(static_cast<uint32_t>(d.lags));
  copy_values(d.ljung_box_p, out.mutable_ljung_box_p());
  for (int dof : d.cross_dof) out.add_cross_dof(static_cast<uint32_t>(dof));
  copy_values(d.cross_p, out.mutable_cross_p());
  out.set_nis_dof(static_cast<uint64_t>(d.nis_dof));
  out.set_nis_p(d.nis_p);
  return out;
}

namespace {

template <typename Container>
void copy_flags(const Container& flags, google::protobuf::RepeatedField<bool>* out) {
  for (bool f : flags) out->Add(f);
}

}  // namespace

v1::EstimationResult to_proto(const EstimationResult& r, IdentificationMethod method,
                              const std::vector<std::string>& dataset_ids) {
  v1::EstimationResult out;
  out.set_method(static_cast<v1::IdentificationMethod>(
      enum_to_proto(*v1::IdentificationMethod_descriptor(), identification_method_name(method))));
  for (const auto& n : r.param_names) out.add_param_names(n);
  copy_values(r.theta, out.mutable_theta());
  copy_values(r.theta_std, out.mutable_theta_std());
  copy_values(r.ci_lower, out.mutable_ci_lower());
  copy_values(r.ci_upper, out.mutable_ci_upper());
  copy_flags(r.fixed, out.mutable_fixed());
  *out.mutable_covariance() = to_matrix(r.covariance);
  *out.mutable_correlation() = to_matrix(r.correlation);
  for (const auto& w : r.warnings) out.add_warnings(w);
  out.set_cost(r.cost);
  out.set_sigma2(r.sigma2);
  out.set_covariance_method(r.covariance_method);
  for (double c : r.cost_history) out.add_cost_history(c);
  out.set_iterations(static_cast<uint32_t>(r.iterations));
  out.set_evaluations(static_cast<uint32_t>(r.evaluations));
  out.set_jacobian_evaluations(static_cast<uint32_t>(r.jacobian_evaluations));
  out.set_converged(r.converged);
  out.set_termination(r.termination);
  out.set_gradient(r.gradient);
  out.set_log_likelihood(r.criteria.log_likelihood);
  out.set_estimated_quantities(static_cast<uint32_t>(r.criteria.estimated_quantities));
  out.set_samples(static_cast<uint64_t>(r.criteria.samples));
  out.set_aic(r.criteria.aic);
  out.set_aicc(r.criteria.aicc);
  out.set_bic(r.criteria.bic);
  for (std::size_t e = 0; e < r.experiments.size(); ++e) {
    const ExperimentResult& x = r.experiments[e];
    v1::ExperimentFit* fit = out.add_experiments();
    if (e < dataset_ids.size()) fit->set_dataset_id(dataset_ids[e]);
    copy_values(x.x0, fit->mutable_x0());
    copy_values(x.x0_std, fit->mutable_x0_std());
    copy_flags(x.x0_estimated, fit->mutable_x0_estimated());
    copy_values(x.t, fit->mutable_t());
    *fit->mutable_y_measured() = to_matrix(x.y_measured);
    *fit->mutable_y_model() = to_matrix(x.y_model);
    *fit->mutable_residuals() = to_matrix(x.residuals);
    *fit->mutable_mask() = to_matrix(x.mask.matrix());
    for (const OutputFit& f : x.fits) *fit->add_fits() = to_proto(f);
    *fit->mutable_diagnostics() = to_proto(x.diagnostics);
  }
  return out;
}

v1::OutputFit to_proto(const OutputFit& f) {
  v1::OutputFit fit;
  fit.set_name(f.name);
  fit.set_rmse(f.rmse);
  fit.set_fit_percent(f.fit_percent);
  fit.set_vaf_percent(f.vaf_percent);
  fit.set_rrse(f.rrse);
  return fit;
}

Result<ValidationSettings> from_proto(const v1::ValidationSpec& spec) {
  ValidationSettings out;
  RICCATI_ASSIGN_OR_RETURN(out.simulation.integrator, from_proto(spec.integrator()));
  RICCATI_ASSIGN_OR_RETURN(out.simulation.hold, from_proto(spec.hold()));
  initial_state_from_proto(spec.initial_state(), &out.initial_state, &out.x0);
  return out;
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
  for (const auto& w : r.warnings) out.add_warnings(w);
  copy_values(r.filter_theta_std, out.mutable_filter_theta_std());
  copy_values(r.ci_lower, out.mutable_ci_lower());
  copy_values(r.ci_upper, out.mutable_ci_upper());
  *out.mutable_theta_covariance() = to_matrix(r.theta_covariance);
  out.set_covariance_method(r.covariance_method);
  copy_values(r.theta_step, out.mutable_theta_step());
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
  out.warnings.assign(r.warnings().begin(), r.warnings().end());
  // The uncertainty's fields, absent from results stored before them.
  const auto optional_values = [&](const auto& values, Eigen::VectorXd* to, const char* field) -> Status {
    if (values.empty()) return Status::ok();
    RICCATI_ASSIGN_OR_RETURN(*to, from_values(values, n, field));
    return Status::ok();
  };
  RICCATI_RETURN_IF_ERROR(optional_values(r.filter_theta_std(), &out.filter_theta_std, "filter_theta_std"));
  RICCATI_RETURN_IF_ERROR(optional_values(r.ci_lower(), &out.ci_lower, "ci_lower"));
  RICCATI_RETURN_IF_ERROR(optional_values(r.ci_upper(), &out.ci_upper, "ci_upper"));
  RICCATI_RETURN_IF_ERROR(optional_values(r.theta_step(), &out.theta_step, "theta_step"));
  RICCATI_ASSIGN_OR_RETURN(out.theta_covariance, from_matrix(r.theta_covariance(), "theta_covariance"));
  out.covariance_method = r.covariance_method();
  return out;
}

v1::ValidationResult to_proto(const ValidationResult& r, const Eigen::VectorXd& theta) {
  v1::ValidationResult out;
  copy_values(theta, out.mutable_theta());
  copy_values(r.t, out.mutable_t());
  copy_values(r.x0, out.mutable_x0());
  *out.mutable_y_measured() = to_matrix(r.y_measured);
  *out.mutable_y_simulated() = to_matrix(r.y_simulated);
  for (const OutputFit& f : r.fits) *out.add_fits() = to_proto(f);
  out.set_horizon(static_cast<uint32_t>(r.horizon));
  return out;
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


v1::Job to_proto(const JobRecord& job) {
  v1::Job out;
  out.set_id(job.id);
  // A running job asked to cancel is CANCELLING until it stops (between two
  // samples here, at its next lease renewal on another instance).
  out.set_state(job.state == JobState::kRunning && job.cancel_requested ? v1::JOB_STATE_CANCELLING
                                                                         : to_proto(job.state));
  switch (job.kind) {
    case JobKind::kIdentification: out.mutable_identification()->ParseFromString(job.spec); break;
    case JobKind::kValidation: out.mutable_validation()->ParseFromString(job.spec); break;
    case JobKind::kSmoothing: out.mutable_smoothing()->ParseFromString(job.spec); break;
    case JobKind::kUnknown: break;  // a newer riccatid's: its spec is not ours to read
  }
  v1::JobProgress* p = out.mutable_progress();
  p->set_pass_number(static_cast<uint32_t>(job.pass));
  p->set_passes(static_cast<uint32_t>(job.passes));
  p->set_sample(static_cast<uint64_t>(job.sample));
  p->set_samples(static_cast<uint64_t>(job.samples));
  for (double v : job.theta) p->add_theta(v);
  p->set_iteration(static_cast<uint32_t>(job.iteration));
  p->set_cost(job.cost);
  if (job.error_code != 0) {
    out.mutable_error()->set_code(static_cast<v1::Code>(job.error_code));
    out.mutable_error()->set_message(job.error_message);
  }
  set_timestamp(job.created_ms, out.mutable_created());
  if (job.started_ms != 0) set_timestamp(job.started_ms, out.mutable_started());
  if (job.finished_ms != 0) set_timestamp(job.finished_ms, out.mutable_finished());
  out.set_attempts(static_cast<uint32_t>(job.attempts));
  return out;
}

}  // namespace riccati::service
