// JobService: identification and validation jobs through the JobManager.
#pragma once

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <condition_variable>
#include <mutex>
#include <set>
#include <string>
#include <thread>

#include "riccati/v1/jobs.grpc.pb.h"
#include "service/auth.hpp"
#include "service/jobs/job_manager.hpp"
#include "service/stream_slots.hpp"

namespace riccati::service {

// WatchJob uses gRPC's callback API (a reactor per watch) and one thread,
// the watch pump, serves them all: it waits for a change of any job running
// here (and every kStorePoll reads the store for jobs that are not), and
// writes to each idle watch whose job changed. So an open watch holds no
// thread, and each takes a place in StreamSlots.
class JobServiceImpl final : public v1::JobService::WithCallbackMethod_WatchJob<v1::JobService::Service> {
 public:
  JobServiceImpl(const Authenticator& auth, JobManager& jobs, StreamSlots& slots);
  ~JobServiceImpl() override;
  grpc::Status SubmitIdentification(grpc::ServerContext*, const v1::IdentificationSpec*, v1::Job*) override;
  grpc::Status SubmitValidation(grpc::ServerContext*, const v1::ValidationSpec*, v1::Job*) override;
  grpc::Status SubmitSmoothing(grpc::ServerContext*, const v1::SmoothingSpec*, v1::Job*) override;
  grpc::ServerWriteReactor<v1::Job>* WatchJob(grpc::CallbackServerContext*, const v1::WatchJobRequest*) override;
  grpc::Status GetJob(grpc::ServerContext*, const v1::GetJobRequest*, v1::Job*) override;
  grpc::Status ListJobs(grpc::ServerContext*, const v1::ListJobsRequest*, v1::ListJobsResponse*) override;
  grpc::Status CancelJob(grpc::ServerContext*, const v1::CancelJobRequest*, v1::Job*) override;
  grpc::Status GetResult(grpc::ServerContext*, const v1::GetResultRequest*, v1::JobResult*) override;
  grpc::Status DeleteJob(grpc::ServerContext*, const v1::DeleteJobRequest*, v1::DeleteJobResponse*) override;
  grpc::Status CompareJobs(grpc::ServerContext*, const v1::CompareJobsRequest*, v1::CompareJobsResponse*) override;

  // Ends every open watch with UNAVAILABLE and refuses new ones; returns
  // once all have ended or `deadline` has passed.
  void drain(std::chrono::steady_clock::time_point deadline);

  // How often a watch of a job not running here reads the store.
  static constexpr std::chrono::milliseconds kStorePoll{200};

 private:
  class WatchReactor;
  void pump();

  const Authenticator& auth_;
  JobManager& jobs_;
  StreamSlots& slots_;
  std::mutex watches_mu_;
  std::condition_variable watches_changed_;  // a watch opened, ended or finished a write; drain
  std::set<WatchReactor*> watches_;          // open watches, for the pump and drain()
  bool draining_ = false;
  bool pump_wake_ = false;     // a watch is due, or may be
  std::set<std::string> changed_jobs_;  // jobs that changed here since the pump's last round ("": all)
  bool stop_pump_ = false;
  std::thread pump_;
};

// A succeeded job's result (GetResult), with its room among the reads in
// progress (ResultReads), to hold until the answer is sent.
struct ReadJobResult {
  v1::JobResult result;
  std::shared_ptr<const void> read;
};
Result<ReadJobResult> job_result(JobManager& jobs, const std::string& tenant, const std::string& job_id);

}  // namespace riccati::service
