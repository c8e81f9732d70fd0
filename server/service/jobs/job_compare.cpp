#include "service/jobs/job_compare.hpp"

#include <algorithm>
#include <set>
#include <vector>

#include "engine/estimation/estimate.hpp"
#include "service/ids.hpp"

namespace riccati::service {
namespace {

struct Fitted {
  v1::ComparedJob summary;
  std::vector<std::string> datasets;  // of its experiments, in order
  std::vector<std::string> outputs;   // the names its fits are by
  std::set<std::string> free;         // the parameters it estimated
};

// `small` is `large` with some of its free parameters held: the same model
// on the same records by the same method, a strict subset of its parameters
// free, fewer quantities estimated.
bool nested_in(const Fitted& small, const Fitted& large) {
  const v1::ComparedJob &s = small.summary, &l = large.summary;
  if (s.model() != l.model() || small.datasets != large.datasets || s.method() != l.method()) return false;
  if (s.samples() != l.samples() || s.estimated_quantities() >= l.estimated_quantities()) return false;
  return small.free.size() < large.free.size() &&
         std::includes(large.free.begin(), large.free.end(), small.free.begin(), small.free.end());
}

std::string listed(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

// The validations on a common record (CompareJobsRequest.validation_job_ids),
// each set beside the job it validates: finished validations of these jobs,
// one a job, one dataset and one horizon among them.
Status add_validations(JobManager& jobs, const std::string& tenant, const v1::CompareJobsRequest& request,
                       std::vector<Fitted>* fits, v1::CompareJobsResponse* out) {
  if (request.validation_job_ids_size() > request.job_ids_size()) {
    return invalid_argument("validation_job_ids: at most one validation a compared job (" +
                            std::to_string(request.job_ids_size()) + "), got " +
                            std::to_string(request.validation_job_ids_size()));
  }
  for (int v = 0; v < request.validation_job_ids_size(); ++v) {
    const std::string& id = request.validation_job_ids(v);
    RICCATI_RETURN_IF_ERROR(check_client_string("validation_job_ids", id, kMaxNameBytes));
    RICCATI_ASSIGN_OR_RETURN(const JobRecord job, jobs.get(tenant, id));
    v1::ValidationSpec spec;
    if (job.kind != JobKind::kValidation || !spec.ParseFromString(job.spec)) {
      return invalid_argument("validation_job_ids: job " + id + " is not a validation");
    }
    if (spec.identification_job_id().empty()) {
      return invalid_argument("validation_job_ids: validation " + id +
                              " simulates given parameters, not a compared job's estimate");
    }
    const auto validated = std::find_if(fits->begin(), fits->end(), [&](const Fitted& f) {
      return f.summary.job_id() == spec.identification_job_id();
    });
    if (validated == fits->end()) {
      return invalid_argument("validation_job_ids: validation " + id + " is of job " + spec.identification_job_id() +
                              ", which is not among the jobs compared");
    }
    if (!validated->summary.validation_job_id().empty()) {
      return invalid_argument("validation_job_ids: job " + spec.identification_job_id() + " has two validations (" +
                              validated->summary.validation_job_id() + " and " + id + ")");
    }
    RICCATI_ASSIGN_OR_RETURN(const JobManager::StoredResult stored, jobs.result(tenant, id));
    v1::JobResult result;
    if (!result.ParseFromString(stored.encoded) || !result.has_validation()) {
      return internal_error("stored result of validation " + id + " is unreadable");
    }
    const v1::ValidationResult& r = result.validation();
    if (v == 0) {
      out->set_validation_dataset_id(spec.dataset_id());
      out->set_validation_horizon(r.horizon());
    } else if (spec.dataset_id() != out->validation_dataset_id() || r.horizon() != out->validation_horizon()) {
      return invalid_argument("validation_job_ids: validations " + request.validation_job_ids(0) + " and " + id +
                              " are not on one common record (datasets " + out->validation_dataset_id() + " and " +
                              spec.dataset_id() + ", horizons " + std::to_string(out->validation_horizon()) + " and " +
                              std::to_string(r.horizon()) + ")");
    }
    std::vector<std::string> outputs;
    for (const v1::OutputFit& fit : r.fits()) outputs.push_back(fit.name());
    if (outputs != validated->outputs) {
      return invalid_argument("validation " + id + " fits outputs " + listed(outputs) + ", its job " +
                              validated->summary.job_id() + " " + listed(validated->outputs));
    }
    validated->summary.set_validation_job_id(id);
    *validated->summary.mutable_validation_fits() = r.fits();
  }
  return Status::ok();
}

}  // namespace

Result<v1::CompareJobsResponse> compare_jobs(JobManager& jobs, const std::string& tenant,
                                             const v1::CompareJobsRequest& request) {
  if (request.job_ids_size() == 0) return invalid_argument("job_ids: name the jobs to compare");
  if (request.job_ids_size() > kMaxComparedJobs) {
    return invalid_argument("job_ids: compare takes at most " + std::to_string(kMaxComparedJobs) + " jobs, got " +
                            std::to_string(request.job_ids_size()));
  }
  std::vector<Fitted> fits;
  for (const std::string& id : request.job_ids()) {
    RICCATI_RETURN_IF_ERROR(check_client_string("job_ids", id, kMaxNameBytes));
    RICCATI_ASSIGN_OR_RETURN(const JobRecord job, jobs.get(tenant, id));
    Fitted f;
    {
      // Read under the budget, and let go of all but the summary at once.
      RICCATI_ASSIGN_OR_RETURN(const JobManager::StoredResult stored, jobs.result(tenant, id));
      v1::JobResult result;
      if (!result.ParseFromString(stored.encoded)) return internal_error("stored result of job " + id + " is unreadable");
      if (!result.has_estimation()) {
        return invalid_argument("job " + id +
                                " is not an output-error or maximum-likelihood identification: it has no likelihood to "
                                "compare (compare takes jobs of method oe or ml)");
      }
      const v1::EstimationResult& r = result.estimation();
      if (r.samples() == 0) {
        return invalid_argument("job " + id + " ended before riccatid reported likelihoods: run it again to compare it");
      }
      v1::ComparedJob& s = f.summary;
      s.set_job_id(id);
      v1::IdentificationSpec spec;
      s.set_model(spec.ParseFromString(job.spec) ? spec.model() : job.model);
      s.set_method(r.method());
      s.set_estimated_quantities(r.estimated_quantities());
      s.set_samples(r.samples());
      s.set_log_likelihood(r.log_likelihood());
      s.set_aic(r.aic());
      s.set_aicc(r.aicc());
      s.set_bic(r.bic());
      for (const v1::ExperimentFit& x : r.experiments()) f.datasets.push_back(x.dataset_id());
      if (r.experiments_size() > 0) {
        for (const v1::OutputFit& fit : r.experiments(0).fits()) {
          *s.add_fits() = fit;
          f.outputs.push_back(fit.name());
        }
      }
      for (int i = 0; i < r.param_names_size(); ++i) {
        if (!(i < r.fixed_size() && r.fixed(i))) f.free.insert(r.param_names(i));
      }
    }
    fits.push_back(std::move(f));
  }
  for (std::size_t j = 1; j < fits.size(); ++j) {
    if (fits[j].outputs != fits[0].outputs) {
      return invalid_argument("jobs " + fits[0].summary.job_id() + " and " + fits[j].summary.job_id() +
                              " fit different outputs (" + listed(fits[0].outputs) + "; " + listed(fits[j].outputs) +
                              "): their likelihoods do not compare");
    }
  }
  v1::CompareJobsResponse out;
  RICCATI_RETURN_IF_ERROR(add_validations(jobs, tenant, request, &fits, &out));
  // Lower is better among fits to the same data: the first lowest marked.
  std::size_t lowest_aic = 0, lowest_bic = 0;
  for (std::size_t j = 1; j < fits.size(); ++j) {
    if (fits[j].summary.aic() < fits[lowest_aic].summary.aic()) lowest_aic = j;
    if (fits[j].summary.bic() < fits[lowest_bic].summary.bic()) lowest_bic = j;
  }
  fits[lowest_aic].summary.set_lowest_aic(true);
  fits[lowest_bic].summary.set_lowest_bic(true);
  for (const Fitted& f : fits) *out.add_jobs() = f.summary;
  for (const std::string& o : fits[0].outputs) out.add_outputs(o);
  for (const Fitted& small : fits) {
    for (const Fitted& large : fits) {
      if (!nested_in(small, large)) continue;
      v1::LikelihoodRatioTest* t = out.add_tests();
      t->set_smaller(small.summary.job_id());
      t->set_larger(large.summary.job_id());
      t->set_statistic(2.0 * (large.summary.log_likelihood() - small.summary.log_likelihood()));
      t->set_dof(large.summary.estimated_quantities() - small.summary.estimated_quantities());
      t->set_p(chi_square_survival(t->statistic(), t->dof()));
      t->set_significant(t->p() < 0.05);
    }
  }
  return out;
}

}  // namespace riccati::service
