#include "service/jobs/job_execution.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <limits>
#include <memory>
#include <optional>

#include "engine/estimation/binding.hpp"
#include "engine/estimation/identification.hpp"
#include "engine/estimation/smoother.hpp"
#include "engine/estimation/validation.hpp"
#include "engine/filters/filter_kinds.hpp"
#include "engine/models/jacobian_check.hpp"
#include "riccati/enum_names.hpp"
#include "service/convert.hpp"
#include "service/jobs/identification_job.hpp"
#include "service/jobs/job_convert.hpp"

namespace riccati::service {

namespace {

// A checkpoint record: one pass and the covariance at its end, as an
// IdentificationResult with a single pass.
std::string encode_pass(const PassResult& pass, const Eigen::MatrixXd& covariance) {
  IdentificationResult one;
  one.passes.push_back(pass);
  one.theta = pass.theta_final;
  one.theta_mean = pass.theta_mean;
  one.theta_std = pass.theta_std;
  one.covariance = covariance;
  v1::IdentificationResult encoded = to_proto(one);
  encoded.clear_param_names();
  return encoded.SerializeAsString();
}

Status decode_passes(const std::vector<std::string>& records, IdentificationCheckpoint* out) {
  for (std::size_t i = 0; i < records.size(); ++i) {
    v1::IdentificationResult encoded;
    if (!encoded.ParseFromString(records[i]) || encoded.passes_size() != 1) {
      return internal_error("pass record " + std::to_string(i + 1) + " is unreadable");
    }
    // from_proto checks sizes against param_names; records leave them out.
    for (int k = 0; k < encoded.theta_size(); ++k) encoded.add_param_names("theta" + std::to_string(k));
    RICCATI_ASSIGN_OR_RETURN(IdentificationResult one, from_proto(encoded));
    out->passes.push_back(std::move(one.passes.front()));
    out->covariance = std::move(one.covariance);
  }
  return Status::ok();
}

// The iterated filter's hooks for a job: progress, stop, and a checkpoint
// after every pass (what resumes the job if the daemon dies before the next
// one ends), resuming from the checkpoints stored.
struct PassHooks {
  IdentificationHooks hooks;
  IdentificationCheckpoint resume;
};

Result<std::unique_ptr<PassHooks>> pass_hooks(const JobRecord& job, const JobExecution& run, const Model& model) {
  auto out = std::make_unique<PassHooks>();
  IdentificationHooks& hooks = out->hooks;
  if (run.progress) {
    const auto nx = static_cast<std::size_t>(model.nx());
    hooks.progress = [&run, nx](const IdentificationProgress& p) {
      const std::span<const double> z(p.state->data(), static_cast<std::size_t>(p.state->size()));
      JobProgress progress;
      progress.pass = p.pass;
      progress.passes = p.passes;
      progress.sample = p.sample;
      progress.samples = p.samples;
      progress.theta = z.subspan(nx);
      run.progress(progress);
    };
  }
  hooks.stop = run.stop;
  hooks.pass_done = [&run, &job](int pass, const PassResult& result, const Eigen::MatrixXd& covariance) {
    return run.store.put_job_pass(job.tenant, job.id, pass, encode_pass(result, covariance));
  };
  RICCATI_ASSIGN_OR_RETURN(const std::vector<std::string> records, run.store.list_job_passes(job.tenant, job.id));
  if (!records.empty()) {
    Status decoded = decode_passes(records, &out->resume);
    if (decoded.is_ok()) {
      hooks.resume = &out->resume;
      spdlog::info("job resumes id={} after_pass={}", job.id, out->resume.passes.size());
    } else {
      spdlog::warn("job checkpoint unusable, running from the start id={} error=\"{}\"", job.id, decoded.message());
    }
  }
  return out;
}

Result<Dataset> load_bound(const JobExecution& run, const std::string& tenant, const std::string& id, const Model& model) {
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, run.store.load_dataset(tenant, id));
  return bind_dataset(model, data);
}

// The first `samples` samples of a dataset (a trial range, or the start a
// validation fits its initial states on).
Dataset slice(const Dataset& d, Eigen::Index first, Eigen::Index end) {
  Dataset out = d;
  out.t = d.t.segment(first, end - first);
  out.u = d.u.middleCols(first, end - first);
  out.y = d.y.middleCols(first, end - first);
  return out;
}

// The iterated filter holds its estimate within bounds only when they are
// asked for; otherwise an estimate outside the model's bounds is said.
void warn_outside_bounds(const ParameterSettings& p, IdentificationResult* r) {
  for (Eigen::Index i = 0; i < r->theta_mean.size(); ++i) {
    const double v = r->theta_mean[i];
    if (v >= p.lower[i] && v <= p.upper[i]) continue;
    char text[256];
    std::snprintf(text, sizeof text, "%s = %.6g is outside its bounds [%.6g, %.6g]: give bounds to hold the filter's "
                                     "estimate within them",
                  r->param_names[static_cast<std::size_t>(i)].c_str(), v, p.lower[i], p.upper[i]);
    r->warnings.push_back(text);
  }
}

// The model's Jacobians at the job's own start (the first sample's time and
// inputs, x0, theta0): a warning per Jacobian that disagrees with finite
// differences, which the result carries and the log says.
std::vector<std::string> check_jacobians_at_start(const JobRecord& job, const IdentificationJob& plan,
                                                  const Dataset& first, const Model& model) {
  const Result<Experiment> start = make_experiment(plan.experiments.front(), first, model);
  if (!start.is_ok() || first.size() == 0) return {};  // the run itself says what is wrong
  JacobianPoint p{first.t[0], first.u.col(0), start->x0, plan.parameters.theta0};
  const Result<JacobianCheck> check = check_jacobians(model, {p});
  if (!check.is_ok()) return {};
  std::vector<std::string> warnings;
  for (const std::string& d : check->disagreements) {
    spdlog::warn("job model Jacobian disagrees with finite differences id={} model={} detail=\"{}\"", job.id,
                 model.name(), d);
    warnings.push_back("the model's Jacobian disagrees with finite differences at the start: " + d);
  }
  return warnings;
}

Result<std::string> execute_identification(const JobRecord& job, const JobExecution& run) {
  v1::IdentificationSpec spec;
  if (!spec.ParseFromString(job.spec)) return internal_error("job " + job.id + ": stored spec is unreadable");
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, run.models.get(job.tenant, spec.model()));
  RICCATI_ASSIGN_OR_RETURN(IdentificationJob plan, identification_from_proto(spec, *model));
  RICCATI_ASSIGN_OR_RETURN(const Dataset first, load_bound(run, job.tenant, plan.experiments.front().dataset_id, *model));
  const std::vector<std::string> jacobian_warnings = check_jacobians_at_start(job, plan, first, *model);
  v1::JobResult result;
  result.set_job_id(job.id);

  // The iterated filter: the method, or the passes that find OE's or ML's start.
  const IdentificationMethodInfo& method = identification_method_info(plan.method);
  std::optional<IdentificationResult> passes;
  if (method.iterated_filter || plan.init_passes > 0) {
    RICCATI_ASSIGN_OR_RETURN(plan.filter.mask, make_mask(plan.experiments.front().mask, first, *model));
    RICCATI_ASSIGN_OR_RETURN(const std::unique_ptr<PassHooks> hooks, pass_hooks(job, run, *model));
    RICCATI_ASSIGN_OR_RETURN(passes, identify(model, first, plan.filter, hooks->hooks));
    if (method.iterated_filter) {
      warn_outside_bounds(plan.parameters, &*passes);
      passes->warnings.insert(passes->warnings.begin(), jacobian_warnings.begin(), jacobian_warnings.end());
      *result.mutable_identification() = to_proto(*passes);
      return result.SerializeAsString();
    }
    // The optimiser starts where the passes ended (their mean over the last
    // pass, as the toolbox reports), within the bounds; fixed ones stay.
    ParameterSettings& p = plan.parameters;
    for (Eigen::Index i = 0; i < p.theta0.size(); ++i) {
      if (!p.fixed[static_cast<std::size_t>(i)]) p.theta0[i] = std::clamp(passes->theta_mean[i], p.lower[i], p.upper[i]);
    }
  }

  std::vector<Experiment> experiments;
  std::vector<std::string> dataset_ids;
  for (std::size_t e = 0; e < plan.experiments.size(); ++e) {
    Dataset data = first;
    if (e > 0) {
      RICCATI_ASSIGN_OR_RETURN(data, load_bound(run, job.tenant, plan.experiments[e].dataset_id, *model));
    }
    if (e == 0 && (plan.filter.first_sample > 0 || plan.filter.end_sample >= 0)) {
      data = slice(data, plan.filter.first_sample, plan.filter.end_sample < 0 ? data.size() : plan.filter.end_sample);
    }
    RICCATI_ASSIGN_OR_RETURN(Experiment x, make_experiment(plan.experiments[e], data, *model));
    experiments.push_back(std::move(x));
    dataset_ids.push_back(plan.experiments[e].dataset_id);
  }
  EstimationHooks hooks;
  hooks.stop = run.stop;
  if (run.progress) {
    hooks.progress = [&](const EstimationProgress& p) {
      JobProgress progress;
      progress.iteration = p.iteration;
      progress.cost = p.cost;
      progress.optimizer = true;
      run.progress(progress);
    };
  }
  v1::EstimationResult* out = result.mutable_estimation();
  switch (plan.method) {
    case IdentificationMethod::kOutputError: {
      plan.output_error.parameters = plan.parameters;
      RICCATI_ASSIGN_OR_RETURN(const EstimationResult r, output_error(model, experiments, plan.output_error, hooks));
      *out = to_proto(r, plan.method, dataset_ids);
      break;
    }
    case IdentificationMethod::kMaxLikelihood: {
      plan.max_likelihood.parameters = plan.parameters;
      RICCATI_ASSIGN_OR_RETURN(const MaxLikelihoodResult r,
                               max_likelihood(model, experiments, plan.max_likelihood, hooks));
      *out = to_proto(r.estimate, plan.method, dataset_ids);
      copy_values(r.noise.q, out->mutable_process_noise());
      copy_values(r.noise.q_std, out->mutable_process_noise_std());
      copy_values(r.noise.r, out->mutable_measurement_noise());
      copy_values(r.noise.r_std, out->mutable_measurement_noise_std());
      break;
    }
    case IdentificationMethod::kFilter:  // returned with its passes above
      return internal_error("job " + job.id + ": the filter method reached the optimiser");
  }
  if (passes) *out->mutable_init_passes() = to_proto(*passes);
  for (const std::string& w : jacobian_warnings) out->add_warnings(w);
  return result.SerializeAsString();
}

Result<std::string> execute_smoothing(const JobRecord& job, const JobExecution& run) {
  v1::SmoothingSpec spec;
  if (!spec.ParseFromString(job.spec)) return internal_error("job " + job.id + ": stored spec is unreadable");
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, run.models.get(job.tenant, spec.model()));
  RICCATI_ASSIGN_OR_RETURN(const SmootherSettings settings, from_proto(spec, *model));
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, load_bound(run, job.tenant, spec.dataset_id(), *model));
  SmootherHooks hooks;
  hooks.stop = run.stop;
  if (run.progress) {
    hooks.progress = [&](const SmootherProgress& p) {
      // Forward is pass 1, backward pass 2, counted up: the backward pass
      // smooths N - 1 down to 1, sample N being smoothed as it was filtered.
      JobProgress progress;
      progress.pass = p.pass == SmootherProgress::Pass::kForward ? 1 : 2;
      progress.passes = 2;
      progress.sample = p.pass == SmootherProgress::Pass::kForward ? p.sample : p.samples - p.sample + 1;
      progress.samples = p.samples;
      run.progress(progress);
    };
  }
  RICCATI_ASSIGN_OR_RETURN(const SmootherResult r, smooth(model, data, settings, hooks));
  v1::JobResult result;
  result.set_job_id(job.id);
  *result.mutable_smoothing() = to_proto(r, spec.full_covariance());
  return result.SerializeAsString();
}

struct ValidationX0 {
  Eigen::VectorXd x0;
  std::string description;
};

// A validation's initial states fitted on its record's first samples: output
// error over the states named in initial_state.estimate, the parameters held.
Result<ValidationX0> fit_initial_states(const ModelPtr& model, const Dataset& data, const v1::ValidationSpec& spec,
                                        const ValidationSettings& settings) {
  const auto samples = static_cast<Eigen::Index>(std::min<uint64_t>(spec.estimate_x0_samples(), data.size()));
  RICCATI_ASSIGN_OR_RETURN(const std::vector<bool> estimated, estimated_states(spec.initial_state(), *model, "initial_state"));
  Experiment e;
  e.data = slice(data, 0, samples);
  RICCATI_ASSIGN_OR_RETURN(e.x0, initial_state(*model, settings.initial_state, settings.x0,
                                               {data.y.col(0).data(), static_cast<std::size_t>(data.y.rows())}));
  e.estimate_x0 = estimated;
  OutputErrorSettings oe;
  oe.simulation = settings.simulation;
  oe.parameters = default_parameters(*model, settings.theta);
  oe.parameters.lower.setConstant(-std::numeric_limits<double>::infinity());
  oe.parameters.upper.setConstant(std::numeric_limits<double>::infinity());
  oe.parameters.fixed.assign(oe.parameters.fixed.size(), true);
  RICCATI_ASSIGN_OR_RETURN(const EstimationResult r, output_error(model, {e}, oe));
  std::string names;
  for (std::size_t i = 0; i < estimated.size(); ++i) {
    if (estimated[i]) names += (names.empty() ? "" : ", ") + model->state_names()[i];
  }
  return ValidationX0{r.experiments.front().x0, "fitted by output error on the first " + std::to_string(samples) +
                                                    " samples (" + names + "), the parameters held"};
}

// The parameters a validation simulates with, and what it says of them.
Result<Eigen::VectorXd> validation_parameters(const JobRecord& job, const JobExecution& run, const v1::ValidationSpec& spec,
                                              const Model& model, std::string* from) {
  if (spec.has_theta()) {
    *from = "given";
    return from_values(spec.theta().values(), model.ntheta(), "theta");
  }
  if (!spec.has_identification_job_id()) {
    *from = "the model's defaults";
    return model.theta_default();
  }
  const std::string& source_id = spec.identification_job_id();
  RICCATI_ASSIGN_OR_RETURN(const std::string encoded, run.store.get_result(job.tenant, source_id));
  v1::JobResult source;
  if (!source.ParseFromString(encoded) || (!source.has_identification() && !source.has_estimation())) {
    return failed_precondition("job " + source_id + " has no identification result");
  }
  if (source.has_estimation()) {
    *from = "job " + source_id + ": its " +
            api::enum_value_name(*v1::IdentificationMethod_descriptor()->FindValueByNumber(source.estimation().method())) +
            " estimate";
    return from_values(source.estimation().theta(), model.ntheta(), "theta");
  }
  if (spec.estimate() == v1::ESTIMATE_CHOICE_FINAL) {
    *from = "job " + source_id + ": the estimate at the end of the last pass";
    return from_values(source.identification().theta(), model.ntheta(), "theta");
  }
  *from = "job " + source_id + ": the mean over the last pass";
  return from_values(source.identification().theta_mean(), model.ntheta(), "theta");
}

// A k-step prediction's filter: the identification job's own (its kind, Q,
// R and the states' P0, as it ran), with ML's estimated noise where it
// estimated them.
Result<PredictionSettings> prediction_settings(const JobRecord& job, const JobExecution& run,
                                               const v1::ValidationSpec& spec, const ModelPtr& model,
                                               std::string* predictor) {
  const std::string& source_id = spec.identification_job_id();
  RICCATI_ASSIGN_OR_RETURN(const JobRecord source, run.store.get_job(job.tenant, source_id));
  v1::IdentificationSpec source_spec;
  if (!source_spec.ParseFromString(source.spec)) return internal_error("job " + source_id + ": stored spec is unreadable");
  RICCATI_ASSIGN_OR_RETURN(const IdentificationJob identification, identification_from_proto(source_spec, *model));
  const int nx = model->nx();
  PredictionSettings p;
  p.horizon = static_cast<int>(std::min<uint32_t>(spec.horizon(), 1u << 30));
  p.filter = identification.method == IdentificationMethod::kMaxLikelihood ? identification.max_likelihood.filter
                                                                           : identification.filter.filter;
  if (p.filter.kind != FilterKind::kEkf && p.filter.kind != FilterKind::kUkf) p.filter.kind = FilterKind::kEkf;
  p.P0x = identification.filter.initial.P0.topLeftCorner(nx, nx);
  const char* q_from = "as the job ran";
  const char* r_from = "as the job ran";
  if (identification.method == IdentificationMethod::kMaxLikelihood) {
    RICCATI_ASSIGN_OR_RETURN(const std::string encoded, run.store.get_result(job.tenant, source_id));
    v1::JobResult estimated;
    if (estimated.ParseFromString(encoded) && estimated.has_estimation()) {
      const v1::EstimationResult& e = estimated.estimation();
      if (e.process_noise_size() == nx) {
        Eigen::MatrixXd Q = p.filter.Q.rows() >= nx ? Eigen::MatrixXd(p.filter.Q.topLeftCorner(nx, nx))
                                                    : Eigen::MatrixXd::Zero(nx, nx);
        for (int i = 0; i < nx; ++i) Q(i, i) = e.process_noise(i);
        p.filter.Q = Q;
        q_from = "estimated";
      }
      if (e.measurement_noise_size() == model->ny()) {
        for (int i = 0; i < model->ny(); ++i) p.filter.R(i, i) = e.measurement_noise(i);
        r_from = "estimated";
      }
    }
  }
  *predictor = std::string(filter_kind_name(p.filter.kind)) + " of job " + source_id + " (Q " + q_from + ", R " +
               r_from + ", the states' P0), " + std::to_string(p.horizon) + (p.horizon == 1 ? " sample" : " samples") +
               " ahead";
  return p;
}

Result<std::string> execute_validation(const JobRecord& job, const JobExecution& run) {
  v1::ValidationSpec spec;
  if (!spec.ParseFromString(job.spec)) return internal_error("job " + job.id + ": stored spec is unreadable");
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, run.models.get(job.tenant, spec.model()));
  RICCATI_ASSIGN_OR_RETURN(ValidationSettings settings, from_proto(spec));
  std::string parameters_from;
  RICCATI_ASSIGN_OR_RETURN(settings.theta, validation_parameters(job, run, spec, *model, &parameters_from));
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, load_bound(run, job.tenant, spec.dataset_id(), *model));
  if (run.stop.stop_requested()) return cancelled("validation cancelled");
  std::string x0_from = settings.initial_state == InitialState::kFirstMeasurement ? "the first measurement" : "given";
  if (spec.estimate_x0_samples() > 0) {
    // The initial states fitted by output error on the record's start, the
    // parameters held, then the whole record simulated from them.
    RICCATI_ASSIGN_OR_RETURN(const ValidationX0 fitted, fit_initial_states(model, data, spec, settings));
    settings.initial_state = InitialState::kGiven;
    settings.x0 = fitted.x0;
    x0_from = fitted.description;
  }
  // The simulation, or (horizon) the predictions K samples ahead.
  std::string predictor;
  Result<ValidationResult> r = invalid_argument("no validation");
  if (spec.horizon() == 0) {
    r = validate_model(*model, data, settings);
  } else {
    RICCATI_ASSIGN_OR_RETURN(const PredictionSettings prediction, prediction_settings(job, run, spec, model, &predictor));
    r = predict_model(model, data, settings, prediction);
  }
  if (!r.is_ok()) return r.status();
  v1::JobResult result;
  result.set_job_id(job.id);
  v1::ValidationResult* out = result.mutable_validation();
  *out = to_proto(r.value(), settings.theta);
  out->set_parameters_from(parameters_from);
  out->set_x0_from(x0_from);
  out->set_predictor(predictor);
  return result.SerializeAsString();
}

}  // namespace

Result<std::string> execute_job(const JobRecord& job, const JobExecution& run) {
  switch (job.kind) {
    case JobKind::kIdentification: return execute_identification(job, run);
    case JobKind::kValidation: return execute_validation(job, run);
    case JobKind::kSmoothing: return execute_smoothing(job, run);
    case JobKind::kUnknown: break;  // never claimed (Store::claim_job)
  }
  return internal_error("job " + job.id + " is of a kind this riccatid does not know");
}

}  // namespace riccati::service
