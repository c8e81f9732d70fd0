#include "service/jobs/job_execution.hpp"

#include <spdlog/spdlog.h>

#include "engine/estimation/identification.hpp"
#include "engine/estimation/validation.hpp"
#include "service/convert.hpp"
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

Result<std::string> execute_identification(const JobRecord& job, const JobExecution& run) {
  v1::IdentificationSpec spec;
  if (!spec.ParseFromString(job.spec)) return internal_error("job " + job.id + ": stored spec is unreadable");
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, run.models.get(spec.model()));
  RICCATI_ASSIGN_OR_RETURN(const IdentificationSettings settings, from_proto(spec, *model));
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, run.store.load_dataset(job.tenant, spec.dataset_id()));

  IdentificationHooks hooks;
  if (run.progress) {
    hooks.progress = [&](const IdentificationProgress& p) {
      const std::span<const double> z(p.state->data(), static_cast<std::size_t>(p.state->size()));
      run.progress(JobProgress{p.pass, p.passes, p.sample, p.samples, z.subspan(static_cast<std::size_t>(model->nx()))});
    };
  }
  hooks.stop = run.stop;
  // After each pass, what resumes the job if the daemon dies (kill -9,
  // power loss) before the next one ends.
  hooks.pass_done = [&](int pass, const PassResult& result, const Eigen::MatrixXd& covariance) {
    return run.store.put_job_pass(job.tenant, job.id, pass, encode_pass(result, covariance));
  };
  RICCATI_ASSIGN_OR_RETURN(const std::vector<std::string> records, run.store.list_job_passes(job.tenant, job.id));
  IdentificationCheckpoint resume;
  if (!records.empty()) {
    Status decoded = decode_passes(records, &resume);
    if (decoded.is_ok()) {
      hooks.resume = &resume;
      spdlog::info("job resumes id={} after_pass={}", job.id, resume.passes.size());
    } else {
      spdlog::warn("job checkpoint unusable, running from the start id={} error=\"{}\"", job.id, decoded.message());
    }
  }
  RICCATI_ASSIGN_OR_RETURN(const IdentificationResult r, identify(model, data, settings, hooks));
  v1::JobResult result;
  result.set_job_id(job.id);
  *result.mutable_identification() = to_proto(r);
  return result.SerializeAsString();
}

Result<std::string> execute_validation(const JobRecord& job, const JobExecution& run) {
  v1::ValidationSpec spec;
  if (!spec.ParseFromString(job.spec)) return internal_error("job " + job.id + ": stored spec is unreadable");
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, run.models.get(spec.model()));
  RICCATI_ASSIGN_OR_RETURN(ValidationSettings settings, from_proto(spec));
  if (spec.has_identification_job_id()) {
    RICCATI_ASSIGN_OR_RETURN(const std::string encoded, run.store.get_result(job.tenant, spec.identification_job_id()));
    v1::JobResult source;
    if (!source.ParseFromString(encoded) || !source.has_identification()) {
      return failed_precondition("job " + spec.identification_job_id() + " has no identification result");
    }
    RICCATI_ASSIGN_OR_RETURN(settings.theta,
                             from_values(source.identification().theta_mean(), model->ntheta(), "theta"));
  } else if (spec.has_theta()) {
    RICCATI_ASSIGN_OR_RETURN(settings.theta, from_values(spec.theta().values(), model->ntheta(), "theta"));
  } else {
    settings.theta = model->theta_default();
  }
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, run.store.load_dataset(job.tenant, spec.dataset_id()));
  if (run.stop.stop_requested()) return cancelled("validation cancelled");
  RICCATI_ASSIGN_OR_RETURN(const ValidationResult r, validate_model(*model, data, settings));
  v1::JobResult result;
  result.set_job_id(job.id);
  *result.mutable_validation() = to_proto(r, settings.theta);
  return result.SerializeAsString();
}

}  // namespace

Result<std::string> execute_job(const JobRecord& job, const JobExecution& run) {
  switch (job.kind) {
    case JobKind::kIdentification: return execute_identification(job, run);
    case JobKind::kValidation: return execute_validation(job, run);
    case JobKind::kUnknown: break;  // never claimed (Store::claim_job)
  }
  return internal_error("job " + job.id + " is of a kind this riccatid does not know");
}

}  // namespace riccati::service
