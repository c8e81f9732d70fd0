// JobService: identification and validation jobs through the JobManager.
#pragma once

#include <grpcpp/grpcpp.h>

#include "riccati/v1/jobs.grpc.pb.h"
#include "service/auth.hpp"
#include "service/jobs/job_manager.hpp"

namespace riccati::service {

class JobServiceImpl final : public v1::JobService::Service {
 public:
  JobServiceImpl(const Authenticator& auth, JobManager& jobs) : auth_(auth), jobs_(jobs) {}
  grpc::Status SubmitIdentification(grpc::ServerContext*, const v1::IdentificationSpec*, v1::Job*) override;
  grpc::Status SubmitValidation(grpc::ServerContext*, const v1::ValidationSpec*, v1::Job*) override;
  grpc::Status SubmitSmoothing(grpc::ServerContext*, const v1::SmoothingSpec*, v1::Job*) override;
  grpc::Status WatchJob(grpc::ServerContext*, const v1::WatchJobRequest*, grpc::ServerWriter<v1::Job>*) override;
  grpc::Status GetJob(grpc::ServerContext*, const v1::GetJobRequest*, v1::Job*) override;
  grpc::Status ListJobs(grpc::ServerContext*, const v1::ListJobsRequest*, v1::ListJobsResponse*) override;
  grpc::Status CancelJob(grpc::ServerContext*, const v1::CancelJobRequest*, v1::Job*) override;
  grpc::Status GetResult(grpc::ServerContext*, const v1::GetResultRequest*, v1::JobResult*) override;

 private:
  const Authenticator& auth_;
  JobManager& jobs_;
};

// A succeeded job's result (GetResult).
Result<v1::JobResult> job_result(JobManager& jobs, const std::string& tenant, const std::string& job_id);

}  // namespace riccati::service
