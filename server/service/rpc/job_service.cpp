#include "service/rpc/job_service.hpp"

#include <spdlog/spdlog.h>

#include <chrono>

#include "service/convert.hpp"
#include "service/jobs/job_convert.hpp"

namespace riccati::service {

grpc::Status JobServiceImpl::SubmitIdentification(grpc::ServerContext* context, const v1::IdentificationSpec* spec,
                                                   v1::Job* response) {
  auto job = jobs_.submit_identification(auth_.tenant(*context), *spec);
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::SubmitValidation(grpc::ServerContext* context, const v1::ValidationSpec* spec,
                                              v1::Job* response) {
  auto job = jobs_.submit_validation(auth_.tenant(*context), *spec);
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::SubmitSmoothing(grpc::ServerContext* context, const v1::SmoothingSpec* spec,
                                             v1::Job* response) {
  auto job = jobs_.submit_smoothing(auth_.tenant(*context), *spec);
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::WatchJob(grpc::ServerContext* context, const v1::WatchJobRequest* request,
                                      grpc::ServerWriter<v1::Job>* writer) {
  const std::string tenant = auth_.tenant(*context);
  std::uint64_t version = 0;
  for (;;) {
    // Short waits, so a client that went away or a deadline is noticed.
    const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(500);
    auto job = jobs_.wait_for_change(tenant, request->id(), &version, until);
    if (!job.is_ok()) {
      spdlog::debug("watch ended job={} status=\"{}\"", request->id(), job.status().to_string());
      return to_grpc(job.status());
    }
    if (context->IsCancelled()) return {grpc::StatusCode::CANCELLED, "watch cancelled by the client"};
    if (!writer->Write(to_proto(job.value()))) return {grpc::StatusCode::CANCELLED, "client went away"};
    if (is_terminal(job.value().state)) return grpc::Status::OK;
  }
}

grpc::Status JobServiceImpl::GetJob(grpc::ServerContext* context, const v1::GetJobRequest* request,
                                    v1::Job* response) {
  auto job = jobs_.get(auth_.tenant(*context), request->id());
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::ListJobs(grpc::ServerContext* context, const v1::ListJobsRequest*,
                                      v1::ListJobsResponse* response) {
  auto jobs = jobs_.list(auth_.tenant(*context));
  if (!jobs.is_ok()) return to_grpc(jobs.status());
  for (const JobRecord& job : jobs.value()) *response->add_jobs() = to_proto(job);
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::CancelJob(grpc::ServerContext* context, const v1::CancelJobRequest* request,
                                       v1::Job* response) {
  auto job = jobs_.cancel(auth_.tenant(*context), request->id());
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

Result<v1::JobResult> job_result(JobManager& jobs, const std::string& tenant, const std::string& job_id) {
  RICCATI_ASSIGN_OR_RETURN(const std::string encoded, jobs.result(tenant, job_id));
  v1::JobResult result;
  if (!result.ParseFromString(encoded)) return internal_error("stored result of job " + job_id + " is unreadable");
  return result;
}

grpc::Status JobServiceImpl::GetResult(grpc::ServerContext* context, const v1::GetResultRequest* request,
                                       v1::JobResult* response) {
  Result<v1::JobResult> result = job_result(jobs_, auth_.tenant(*context), request->job_id());
  if (!result.is_ok()) return to_grpc(result.status());
  *response = std::move(result.value());
  return grpc::Status::OK;
}

}  // namespace riccati::service
