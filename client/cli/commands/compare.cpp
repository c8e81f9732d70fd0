// `riccati compare JOB JOB...`: output-error and maximum-likelihood fits side
// by side, by their likelihood and information criteria (docs/identification.md),
// and a likelihood-ratio test for each pair where one model is nested in the
// other: riccatid's CompareJobs, printed.
#include <cstdio>

#include <nlohmann/json.hpp>

#include "commands/commands.hpp"
#include "estimation_output.hpp"
#include "output.hpp"

namespace riccati::cli {

namespace {

// Each job validated on the common record (SubmitValidation, one job after
// another, watched to its end): the validations' ids, in the jobs' order.
int validate_each(Client& c, const CompareOptions& o, const v1::CompareJobsResponse& first,
                  std::vector<std::string>* validations) {
  std::string dataset;
  const std::string model = first.jobs_size() > 0 ? first.jobs(0).model() : "";
  if (const int rc = dataset_for(c, o.data, {}, {}, &dataset, model); rc != kExitOk) return rc;
  for (const v1::ComparedJob& j : first.jobs()) {
    v1::ValidationSpec spec;
    spec.set_model(j.model());
    spec.set_dataset_id(dataset);
    spec.set_identification_job_id(j.job_id());
    if (o.horizon.has_value()) spec.set_horizon(*o.horizon);
    v1::Job job;
    {
      auto ctx = c.context();
      const grpc::Status s = c.jobs->SubmitValidation(ctx.get(), spec, &job);
      if (!s.ok()) return c.fail("validating job " + j.job_id() + " on " + dataset, s);
    }
    v1::Job last;
    if (const int rc = watch_until_done(c, job.id(), &last, OnInterrupt::kCancelJob); rc != kExitOk) return rc;
    if (last.state() != v1::JOB_STATE_SUCCEEDED) {
      std::fprintf(stderr, "riccati: the validation of job %s on %s did not succeed: %s\n", j.job_id().c_str(),
                   dataset.c_str(), last.error().message().c_str());
      return kExitFailed;
    }
    validations->push_back(job.id());
  }
  return kExitOk;
}

}  // namespace

// riccatid compares (CompareJobs): this prints its answer. With --data, the
// jobs are compared once to check them, validated on the record, and
// compared again with their validations.
int compare(Client& c, const CompareOptions& o) {
  v1::CompareJobsRequest request;
  for (const std::string& id : o.ids) request.add_job_ids(id);
  v1::CompareJobsResponse r;
  const auto ask = [&]() -> int {
    auto ctx = c.context();
    const grpc::Status s = c.jobs->CompareJobs(ctx.get(), request, &r);
    return s.ok() ? kExitOk : c.fail("comparing the jobs", s);
  };
  if (const int rc = ask(); rc != kExitOk) return rc;
  if (!o.data.empty()) {
    std::vector<std::string> validations;
    if (const int rc = validate_each(c, o, r, &validations); rc != kExitOk) return rc;
    for (const std::string& v : validations) request.add_validation_job_ids(v);
    if (const int rc = ask(); rc != kExitOk) return rc;
  }
  const bool validated = !r.validation_dataset_id().empty();
  const std::string on_record =
      r.validation_horizon() == 0 ? "simulated" : std::to_string(r.validation_horizon()) + "-step";
  if (c.json) {
    nlohmann::json out = {{"jobs", nlohmann::json::array()}, {"likelihood_ratio_tests", nlohmann::json::array()}};
    for (const v1::ComparedJob& j : r.jobs()) {
      nlohmann::json fits = nlohmann::json::object();
      for (const v1::OutputFit& f : j.fits()) fits[f.name()] = f.fit_percent();
      nlohmann::json row = {{"job", j.job_id()}, {"model", j.model()}, {"method", method_name(j.method())},
                            {"k", j.estimated_quantities()}, {"n", j.samples()}, {"log_likelihood", j.log_likelihood()},
                            {"aic", j.aic()}, {"aicc", j.aicc()}, {"bic", j.bic()}, {"fit_percent", fits},
                            {"lowest_aic", j.lowest_aic()}, {"lowest_bic", j.lowest_bic()}};
      if (validated) {
        nlohmann::json on = nlohmann::json::object();
        for (const v1::OutputFit& f : j.validation_fits()) on[f.name()] = f.fit_percent();
        row["validation"] = {{"job", j.validation_job_id()}, {"fit_percent", on}};
      }
      out["jobs"].push_back(row);
    }
    if (validated) {
      out["validation"] = {{"dataset", r.validation_dataset_id()}, {"horizon", r.validation_horizon()}};
    }
    for (const v1::LikelihoodRatioTest& t : r.tests()) {
      out["likelihood_ratio_tests"].push_back({{"smaller", t.smaller()}, {"larger", t.larger()},
                                               {"statistic", t.statistic()}, {"dof", t.dof()}, {"p", t.p()},
                                               {"significant", t.significant()}});
    }
    std::printf("%s\n", to_json(out).c_str());
    return kExitOk;
  }
  std::printf("%-22s %-16s %-6s %4s %8s %16s %16s %16s %16s", "job", "model", "method", "k", "n", "log-likelihood",
              "AIC", "AICc", "BIC");
  for (const std::string& out : r.outputs()) std::printf(" %10s", ("fit % " + out).c_str());
  for (const std::string& out : r.outputs()) {
    if (validated) std::printf(" %14s", ("valid. % " + out).c_str());
  }
  std::printf("\n");
  for (const v1::ComparedJob& j : r.jobs()) {
    std::printf("%-22s %-16s %-6s %4u %8llu %16.10g %15.10g%s %16.10g %15.10g%s", j.job_id().c_str(), j.model().c_str(),
                method_name(j.method()).c_str(), j.estimated_quantities(), static_cast<unsigned long long>(j.samples()),
                j.log_likelihood(), j.aic(), j.lowest_aic() ? "*" : " ", j.aicc(), j.bic(), j.lowest_bic() ? "*" : " ");
    for (const v1::OutputFit& f : j.fits()) std::printf(" %10.3f", f.fit_percent());
    for (const v1::OutputFit& f : j.validation_fits()) std::printf(" %14.3f", f.fit_percent());
    std::printf("\n");
  }
  std::printf("(* the lowest: the best of these fits by that criterion; fit %%: the first record's, oe's simulated, "
              "ml's one step ahead)\n");
  if (validated) {
    std::printf("(valid. %%: each model %s on the common record %s, at its estimate)\n", on_record.c_str(),
                r.validation_dataset_id().c_str());
  }
  if (r.tests_size() > 0) {
    std::printf("\nlikelihood-ratio tests (the smaller model nested in the larger: same model, records and method)\n");
  }
  for (const v1::LikelihoodRatioTest& t : r.tests()) {
    std::printf("  %s within %s: 2 (ln L_large - ln L_small) = %.6g on %u dof, p = %.3g: %s\n", t.smaller().c_str(),
                t.larger().c_str(), t.statistic(), t.dof(), t.p(),
                t.significant() ? "the larger model fits significantly better (5 %)"
                                : "no significant gain: the smaller model suffices (5 %)");
  }
  return kExitOk;
}

}  // namespace riccati::cli
