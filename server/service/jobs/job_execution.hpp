// What each kind of job computes, from its record: the encoded JobResult, or
// why it failed. The JobManager claims, leases, watches and ends jobs; it
// runs them through execute_job on its workers.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <stop_token>
#include <string>

#include "engine/models/plugin_loader.hpp"
#include "service/models/model_catalog.hpp"
#include "store/store.hpp"

namespace riccati::service {

// Where a job stands (identification: after every sample; throttle in the callback).
struct JobProgress {
  int pass = 0;  // 1-based
  int passes = 0;
  std::int64_t sample = 0;  // 1-based, within the pass
  std::int64_t samples = 0;
  std::span<const double> theta;  // the estimate now
  // An optimiser's (output error, likelihood): its iterations and criterion.
  bool optimizer = false;
  int iteration = 0;
  double cost = 0.0;
};

struct JobExecution {
  Store& store;                 // the job's dataset, checkpoints and source results
  const ModelCatalog& models;  // resolved with the job's tenant
  std::stop_token stop;         // checked between samples: kCancelled
  std::function<void(const JobProgress&)> progress;  // optional
};

Result<std::string> execute_job(const JobRecord& job, const JobExecution& run);

}  // namespace riccati::service
