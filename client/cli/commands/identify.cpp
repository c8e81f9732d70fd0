#include <cstdio>

#include "commands/commands.hpp"
#include "output.hpp"

namespace riccati::cli {

int identify(Client& c, const RunSettings& settings, bool wait) {
  if (!settings.model || !settings.data) {
    std::fprintf(stderr, "riccati: identify needs --model and --data (or model: and data: in --config)\n");
    return kExitUsage;
  }
  std::string error;
  if (!check_identification(settings, &error)) {
    std::fprintf(stderr, "riccati: %s\n", error.c_str());
    return kExitUsage;
  }
  // Experiment 1 (--data), then the others (--experiment), uploaded where they are files.
  std::string dataset;
  if (const int rc = dataset_for(c, *settings.data, settings.inputs, settings.outputs, &dataset, *settings.model);
      rc != kExitOk) {
    return rc;
  }
  std::vector<std::string> more(settings.experiments.size());
  for (std::size_t e = 0; e < more.size(); ++e) {
    const int rc =
        dataset_for(c, settings.experiments[e], settings.inputs, settings.outputs, &more[e], *settings.model);
    if (rc != kExitOk) return rc;
  }
  const v1::IdentificationSpec spec = to_identification_spec(settings, dataset, more);
  v1::Job job;
  {
    auto ctx = c.context();
    const grpc::Status s = c.jobs->SubmitIdentification(ctx.get(), spec, &job);
    if (!s.ok()) return c.fail("submitting the identification", s);
  }
  if (!wait) {
    std::printf("%s\n", c.json ? to_json(job).c_str() : job.id().c_str());
    return kExitOk;
  }
  v1::Job last;
  if (const int rc = watch_until_done(c, job.id(), &last, OnInterrupt::kCancelJob); rc != kExitOk) return rc;
  return result(c, job.id(), c.json ? "json" : "table", "", settings.truth.value_or(std::vector<double>{}));
}

}  // namespace riccati::cli
