#include <cstdio>

#include "commands/commands.hpp"
#include "output.hpp"

namespace riccati::cli {

int smooth(Client& c, const SmoothOptions& o) {
  const RunSettings& s = o.settings;
  if (!s.model || !s.data) {
    std::fprintf(stderr, "riccati: smooth needs --model and --data (or model: and data: in --config)\n");
    return kExitUsage;
  }
  std::string dataset;
  if (const int rc = dataset_for(c, *s.data, s.inputs, s.outputs, &dataset, s.model.value_or("")); rc != kExitOk) {
    return rc;
  }
  v1::SmoothingSpec spec = to_smoothing_spec(s, dataset);
  if (!o.params.empty()) {
    std::vector<double> theta;
    std::string error;
    if (!resolve_parameters(c, o.params, estimate_choice(s), nullptr, &theta, &error)) {
      std::fprintf(stderr, "riccati: %s\n", error.c_str());
      return kExitUsage;
    }
    spec.clear_theta0();
    spec.mutable_theta0()->Add(theta.begin(), theta.end());
  }
  v1::Job job;
  {
    auto ctx = c.context();
    const grpc::Status status = c.jobs->SubmitSmoothing(ctx.get(), spec, &job);
    if (!status.ok()) return c.fail("submitting the smoothing", status);
  }
  v1::Job last;
  if (const int rc = watch_until_done(c, job.id(), &last, OnInterrupt::kCancelJob); rc != kExitOk) return rc;
  return result(c, job.id(), c.json ? "json" : o.format, o.output, {});
}

}  // namespace riccati::cli
