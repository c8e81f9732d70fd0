// JobManager: runs identification and validation jobs on a worker pool.
//
// Jobs are stored before they are queued, so none is lost: at start() every
// job the store has as queued or running is queued again. An identification
// stores a checkpoint record after every pass (Store::put_job_pass), so a
// daemon that was stopped, or killed, mid-job resumes it after its last
// completed pass, with the result the uninterrupted run would have given. Workers are the
// only threads that run the engine; RPC threads submit, read and wait.
// Watchers wait on a version number that changes with every state or
// progress change (progress is published at most every kProgressInterval).
#pragma once

#include "service/limits.hpp"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include "engine/plugin_loader.hpp"
#include "riccati/v1/jobs.pb.h"
#include "store/store.hpp"

namespace riccati::service {

class JobManager {
 public:
  JobManager(Store& store, const ModelRegistry& models, int workers, Limits limits = {});
  ~JobManager();
  JobManager(const JobManager&) = delete;
  JobManager& operator=(const JobManager&) = delete;

  // Re-queues unfinished jobs from the store and starts the workers.
  Status start();
  // Stops the workers. Running jobs are interrupted but stay "running" in the
  // store, so the next start() runs them again.
  void shutdown();

  // Checks the spec against the model and the dataset, stores the job and queues it.
  Result<JobRecord> submit_identification(const std::string& tenant, const v1::IdentificationSpec& spec);
  Result<JobRecord> submit_validation(const std::string& tenant, const v1::ValidationSpec& spec);
  Result<JobRecord> cancel(const std::string& tenant, const std::string& id);
  Result<JobRecord> get(const std::string& tenant, const std::string& id);

  // Blocks until the job has changed since `*version` (0 = return now),
  // the job has ended, `deadline` passes, or shutdown; returns the job then.
  Result<JobRecord> wait_for_change(const std::string& tenant, const std::string& id, std::uint64_t* version,
                                    std::chrono::steady_clock::time_point deadline);

  static constexpr std::chrono::milliseconds kProgressInterval{100};

 private:
  struct LiveJob {
    JobRecord record;
    std::uint64_t version = 1;
    std::stop_source stop;
    bool cancel_requested = false;
  };

  Result<JobRecord> enqueue(JobRecord record);
  void worker_loop();
  void run(const std::string& id);
  // The job's result (encoded JobResult), or why it failed.
  Result<std::string> execute(const JobRecord& job, std::stop_token stop);
  Result<std::string> execute_identification(const JobRecord& job, std::stop_token stop);
  Result<std::string> execute_validation(const JobRecord& job, std::stop_token stop);
  // Applies `change` to the live record, bumps the version, wakes watchers;
  // writes to the store when `persist`.
  template <typename Change>
  Status update(const std::string& id, bool persist, Change&& change);

  Store& store_;
  const ModelRegistry& models_;
  const Limits limits_;  // max_jobs, max_tenant_jobs, max_passes
  const int worker_count_;

  std::mutex mu_;
  std::condition_variable changed_;     // a live job changed (watchers)
  std::condition_variable work_ready_;  // the queue has work (workers)
  std::map<std::string, LiveJob> live_;  // queued or running jobs
  std::deque<std::string> queue_;
  bool stopping_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace riccati::service
