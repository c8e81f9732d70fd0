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

// riccatid compares (CompareJobs): this prints its answer.
int compare(Client& c, const std::vector<std::string>& ids) {
  v1::CompareJobsRequest request;
  for (const std::string& id : ids) request.add_job_ids(id);
  v1::CompareJobsResponse r;
  {
    auto ctx = c.context();
    const grpc::Status s = c.jobs->CompareJobs(ctx.get(), request, &r);
    if (!s.ok()) return c.fail("comparing the jobs", s);
  }
  if (c.json) {
    nlohmann::json out = {{"jobs", nlohmann::json::array()}, {"likelihood_ratio_tests", nlohmann::json::array()}};
    for (const v1::ComparedJob& j : r.jobs()) {
      nlohmann::json fits = nlohmann::json::object();
      for (const v1::OutputFit& f : j.fits()) fits[f.name()] = f.fit_percent();
      out["jobs"].push_back({{"job", j.job_id()}, {"model", j.model()}, {"method", method_name(j.method())},
                             {"k", j.estimated_quantities()}, {"n", j.samples()}, {"log_likelihood", j.log_likelihood()},
                             {"aic", j.aic()}, {"aicc", j.aicc()}, {"bic", j.bic()}, {"fit_percent", fits},
                             {"lowest_aic", j.lowest_aic()}, {"lowest_bic", j.lowest_bic()}});
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
  for (const std::string& o : r.outputs()) std::printf(" %10s", ("fit % " + o).c_str());
  std::printf("\n");
  for (const v1::ComparedJob& j : r.jobs()) {
    std::printf("%-22s %-16s %-6s %4u %8llu %16.10g %15.10g%s %16.10g %15.10g%s", j.job_id().c_str(), j.model().c_str(),
                method_name(j.method()).c_str(), j.estimated_quantities(), static_cast<unsigned long long>(j.samples()),
                j.log_likelihood(), j.aic(), j.lowest_aic() ? "*" : " ", j.aicc(), j.bic(), j.lowest_bic() ? "*" : " ");
    for (const v1::OutputFit& f : j.fits()) std::printf(" %10.3f", f.fit_percent());
    std::printf("\n");
  }
  std::printf("(* the lowest: the best of these fits by that criterion; fit %%: the first record's, oe's simulated, "
              "ml's one step ahead)\n");
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
