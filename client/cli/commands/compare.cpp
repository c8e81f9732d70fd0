// `riccati compare JOB JOB...`: output-error and maximum-likelihood fits side
// by side, by their likelihood and information criteria (docs/identification.md),
// and a likelihood-ratio test for each pair where one model is nested in the
// other.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <set>

#include <nlohmann/json.hpp>

#include "commands/commands.hpp"
#include "estimation_output.hpp"
#include "output.hpp"

namespace riccati::cli {

double chi_square_survival(double x, unsigned dof) {
  if (dof == 0) return std::nan("");
  if (!(x > 0.0)) return 1.0;
  if (std::isinf(x)) return 0.0;
  // Closed forms for whole degrees of freedom (Abramowitz and Stegun 26.4.4
  // and 26.4.5): even, e^{-x/2} sum_{r < dof/2} (x/2)^r / r!; odd, the
  // normal's two tails at sqrt(x) and a like sum.
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
  // 2 phi(sqrt x) sum_{r=1}^{(dof-1)/2} x^{r - 1/2} / (1 3 5 ... (2r - 1))
  term = std::sqrt(2.0 / std::numbers::pi) * std::exp(-half) * root;  // r = 1: 2 phi(sqrt x) sqrt(x)
  for (unsigned r = 1; r <= (dof - 1) / 2; ++r) {
    sum += term;
    term *= x / static_cast<double>(2 * r + 1);
  }
  return std::min(1.0, std::erfc(root / std::sqrt(2.0)) + sum);
}

namespace {

std::string listed(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

struct Fitted {
  std::string id;
  v1::Job job;
  v1::EstimationResult result;
  std::vector<std::string> datasets;  // of its experiments, in order
  std::vector<std::string> outputs;   // the names its fits are by
  std::set<std::string> free;         // the parameters it estimated
};

// The model with the parameters `b` estimates fixed in `a`: b is a's
// special case when both fit the same model to the same records by the same
// method and b estimates a strict subset of a's parameters.
bool nested_in(const Fitted& small, const Fitted& large) {
  if (small.job.identification().model() != large.job.identification().model()) return false;
  if (small.datasets != large.datasets || small.result.method() != large.result.method()) return false;
  if (small.result.samples() != large.result.samples()) return false;
  if (small.result.estimated_quantities() >= large.result.estimated_quantities()) return false;
  return std::includes(large.free.begin(), large.free.end(), small.free.begin(), small.free.end()) &&
         small.free.size() < large.free.size();
}

}  // namespace

int compare(Client& c, const std::vector<std::string>& ids) {
  std::vector<Fitted> fits;
  for (const std::string& id : ids) {
    Fitted f;
    f.id = id;
    {
      auto ctx = c.context();
      v1::GetJobRequest request;
      request.set_id(id);
      const grpc::Status s = c.jobs->GetJob(ctx.get(), request, &f.job);
      if (!s.ok()) return c.fail("job " + id, s);
    }
    v1::JobResult r;
    {
      auto ctx = c.context();
      v1::GetResultRequest request;
      request.set_job_id(id);
      const grpc::Status s = c.jobs->GetResult(ctx.get(), request, &r);
      if (!s.ok()) return c.fail("result of job " + id, s);
    }
    if (!r.has_estimation()) {
      std::fprintf(stderr,
                   "riccati: job %s is not an output-error or maximum-likelihood identification: it has no "
                   "likelihood to compare (compare takes jobs of --method oe or ml)\n",
                   id.c_str());
      return kExitUsage;
    }
    f.result = r.estimation();
    if (f.result.samples() == 0) {
      std::fprintf(stderr, "riccati: job %s ended before riccatid reported likelihoods: run it again to compare it\n",
                   id.c_str());
      return kExitUsage;
    }
    for (const auto& x : f.result.experiments()) {
      f.datasets.push_back(x.dataset_id());
      if (f.outputs.empty()) {
        for (const auto& fit : x.fits()) f.outputs.push_back(fit.name());
      }
    }
    for (int i = 0; i < f.result.param_names_size(); ++i) {
      if (!(i < f.result.fixed_size() && f.result.fixed(i))) f.free.insert(f.result.param_names(i));
    }
    fits.push_back(std::move(f));
  }
  for (std::size_t j = 1; j < fits.size(); ++j) {
    if (fits[j].outputs != fits[0].outputs) {
      std::fprintf(stderr,
                   "riccati: jobs %s and %s fit different outputs (%s; %s): their likelihoods do not compare\n",
                   fits[0].id.c_str(), fits[j].id.c_str(), listed(fits[0].outputs).c_str(),
                   listed(fits[j].outputs).c_str());
      return kExitUsage;
    }
  }
  // Each nested pair's likelihood-ratio test, computed once for both forms.
  struct RatioTest {
    const Fitted* small;
    const Fitted* large;
    double statistic, p;
    unsigned dof;
  };
  std::vector<RatioTest> tests;
  for (const Fitted& small : fits) {
    for (const Fitted& large : fits) {
      if (!nested_in(small, large)) continue;
      const double lr = 2.0 * (large.result.log_likelihood() - small.result.log_likelihood());
      const unsigned dof = large.result.estimated_quantities() - small.result.estimated_quantities();
      tests.push_back({&small, &large, lr, chi_square_survival(lr, dof), dof});
    }
  }
  if (c.json) {
    nlohmann::json out = {{"jobs", nlohmann::json::array()}, {"likelihood_ratio_tests", nlohmann::json::array()}};
    for (const Fitted& f : fits) {
      const v1::EstimationResult& r = f.result;
      out["jobs"].push_back({{"job", f.id}, {"model", f.job.identification().model()}, {"method", method_name(r.method())},
                             {"k", r.estimated_quantities()}, {"n", r.samples()}, {"log_likelihood", r.log_likelihood()},
                             {"aic", r.aic()}, {"aicc", r.aicc()}, {"bic", r.bic()}});
    }
    for (const RatioTest& t : tests) {
      out["likelihood_ratio_tests"].push_back({{"smaller", t.small->id}, {"larger", t.large->id},
                                               {"statistic", t.statistic}, {"dof", t.dof}, {"p", t.p}});
    }
    std::printf("%s\n", to_json(out).c_str());
    return kExitOk;
  }

  // Lower is better, among fits to the same data: the best of each marked.
  const auto best = [&](double (v1::EstimationResult::*criterion)() const) {
    std::size_t at = 0;
    for (std::size_t j = 1; j < fits.size(); ++j) {
      if ((fits[j].result.*criterion)() < (fits[at].result.*criterion)()) at = j;
    }
    return at;
  };
  const std::size_t best_aic = best(&v1::EstimationResult::aic), best_bic = best(&v1::EstimationResult::bic);
  std::printf("%-22s %-16s %-6s %4s %8s %16s %16s %16s %16s", "job", "model", "method", "k", "n", "log-likelihood",
              "AIC", "AICc", "BIC");
  for (const std::string& o : fits[0].outputs) std::printf(" %10s", ("fit % " + o).c_str());
  std::printf("\n");
  for (std::size_t j = 0; j < fits.size(); ++j) {
    const v1::EstimationResult& r = fits[j].result;
    std::printf("%-22s %-16s %-6s %4u %8llu %16.10g %15.10g%s %16.10g %15.10g%s", fits[j].id.c_str(),
                fits[j].job.identification().model().c_str(), method_name(r.method()).c_str(), r.estimated_quantities(),
                static_cast<unsigned long long>(r.samples()), r.log_likelihood(), r.aic(), j == best_aic ? "*" : " ",
                r.aicc(), r.bic(), j == best_bic ? "*" : " ");
    for (int i = 0; i < static_cast<int>(fits[j].outputs.size()); ++i) {
      const auto& fit = r.experiments(0).fits(i);
      std::printf(" %10.3f", fit.fit_percent());
    }
    std::printf("\n");
  }
  std::printf("(* the lowest: the best of these fits by that criterion; fit %%: the first record's, oe's simulated, "
              "ml's one step ahead)\n");
  if (!tests.empty()) {
    std::printf("\nlikelihood-ratio tests (the smaller model nested in the larger: same model, records and method)\n");
  }
  for (const RatioTest& t : tests) {
    std::printf("  %s within %s: 2 (ln L_large - ln L_small) = %.6g on %u dof, p = %.3g: %s\n", t.small->id.c_str(),
                t.large->id.c_str(), t.statistic, t.dof, t.p,
                t.p < 0.05 ? "the larger model fits significantly better (5 %)"
                           : "no significant gain: the smaller model suffices (5 %)");
  }
  return kExitOk;
}

}  // namespace riccati::cli
