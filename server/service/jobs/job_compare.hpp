// Output-error and likelihood fits side by side (CompareJobs; docs/identification.md,
// "Likelihood and information criteria"): each job's likelihood, criteria
// and fits, the lowest AIC and BIC marked, and a likelihood-ratio test for
// each pair where one model is nested in the other. The one place the
// comparison is made: the CLI, Python and the workbench show its answer.
#pragma once

#include <string>

#include "engine/status.hpp"
#include "riccati/v1/jobs.pb.h"
#include "service/jobs/job_manager.hpp"

namespace riccati::service {

inline constexpr int kMaxComparedJobs = 20;

// Each result is read under the result-read budget and kept only as its
// summary, so that comparing large results holds one at a time.
Result<v1::CompareJobsResponse> compare_jobs(JobManager& jobs, const std::string& tenant,
                                             const v1::CompareJobsRequest& request);

}  // namespace riccati::service
