// JobManager: runs identification and validation jobs on a worker pool.
//
// The store is the queue: a submitted job is stored as queued, and idle
// workers claim jobs from the store (Store::claim_job) under a lease that a
// renewal thread extends while they run. So several riccatid sharing one
// PostgreSQL database share the work, any of them answers for any job, and
// a job whose instance died (its lease expired) is taken over by another.
// An identification stores a checkpoint record after every pass
// (Store::put_job_pass), so a job taken over, or run again after a restart,
// resumes after its last completed pass with the result the uninterrupted
// run would have given; its result is written once, by the holder of the
// lease (Store::finish_job). Workers are the only threads that run the
// engine; RPC threads submit, read and wait.
//
// A job running here has a version number that changes with every state or
// progress change (a filter's progress through its samples is published at
// most every kProgressInterval, each optimiser iteration and each pass's
// end always), and each change is told to the change listener; watchers of
// a job queued or running elsewhere poll the store, which has its progress
// at every lease renewal and pass.
#pragma once

#include "service/jobs/result_reads.hpp"
#include "service/limits.hpp"
#include "service/metrics.hpp"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include "engine/models/plugin_loader.hpp"
#include "service/models/model_catalog.hpp"
#include "riccati/v1/jobs.pb.h"
#include "store/store.hpp"

namespace riccati::service {

// How this instance takes part in the shared job queue.
struct JobQueueOptions {
  // Owner of the jobs this instance claims; unique among running instances.
  // Empty: <hostname>-<random>. A stable id (a StatefulSet pod's name, say)
  // lets a restarted instance take its own jobs back at once instead of
  // after their leases expire.
  std::string instance_id;
  // A claim holds this long unless renewed (renewed every third of it, at
  // least every second): how long a dead instance's jobs wait to be taken over.
  std::chrono::milliseconds lease{15000};
  // How often an idle worker looks for jobs submitted to other instances
  // (jobs submitted here wake a worker at once).
  std::chrono::milliseconds poll{500};
  // The store is this instance's alone (SQLite): at start, every job left
  // running is queued again at once; none can be another live instance's.
  bool exclusive_store = true;
};

class JobManager {
 public:
  // `metrics` (optional) counts the jobs this instance ends.
  JobManager(Store& store, const ModelCatalog& models, int workers, Limits limits = {}, JobQueueOptions queue = {},
             Metrics* metrics = nullptr);
  ~JobManager();
  JobManager(const JobManager&) = delete;
  JobManager& operator=(const JobManager&) = delete;

  // Takes back the jobs left running by this instance's previous life (every
  // running job, with an exclusive store) and starts the workers.
  Status start();
  // Stops the workers. Running jobs are interrupted and queued again in the
  // store, for another instance or the next start() (from their last pass).
  void shutdown();

  const std::string& instance_id() const { return instance_; }

  // Checks the spec against the model and the dataset, stores the job and queues it.
  Result<JobRecord> submit_identification(const std::string& tenant, const v1::IdentificationSpec& spec);
  Result<JobRecord> submit_validation(const std::string& tenant, const v1::ValidationSpec& spec);
  Result<JobRecord> submit_smoothing(const std::string& tenant, const v1::SmoothingSpec& spec);
  Result<JobRecord> cancel(const std::string& tenant, const std::string& id);
  // Deletes an ended job with its result; FAILED_PRECONDITION while it is
  // queued or running.
  Status remove(const std::string& tenant, const std::string& id);
  Result<JobRecord> get(const std::string& tenant, const std::string& id);
  // The tenant's jobs, oldest first, with the progress of those running here.
  Result<std::vector<JobRecord>> list(const std::string& tenant);
  // The result of a job that succeeded (encoded JobResult); FAILED_PRECONDITION
  // naming the job's state when it has none. `read` holds the result's room
  // among the reads in progress (ResultReads): keep it until the answer is sent.
  struct StoredResult {
    std::string encoded;
    std::shared_ptr<const void> read;
  };
  Result<StoredResult> result(const std::string& tenant, const std::string& id);

  // The job if it has changed since `*version` (0: any job), updating
  // `*version`; nullopt if it has not. Never waits on this instance's jobs:
  // a job not running here is read from the store. `*running_here` says
  // whether it runs here, so that a watcher knows whether the change
  // listener will tell it of the job's next change or it must read the
  // store again later.
  Result<std::optional<JobRecord>> poll(const std::string& tenant, const std::string& id, std::uint64_t* version,
                                        bool* running_here);
  // Called (on the thread that made it) with the job's id after every
  // change of a job running here (its claim here and its end included), and
  // with an empty id at shutdown; empty: none. The watch pump
  // (service/rpc/job_service.cpp) wakes on it.
  void set_change_listener(std::function<void(const std::string& id)> listener);
  // Called on the worker thread with a job that succeeded and its result
  // (encoded JobResult) once both are stored, before watchers hear of the
  // end; empty: none. The HTTP API writes the result's JSON there, so that
  // the workbench's GET after the end event finds it written.
  using ResultListener = std::function<void(const JobRecord& job, const std::string& result)>;
  void set_result_listener(ResultListener listener);

  static constexpr std::chrono::milliseconds kProgressInterval{100};

 private:
  // A job running on this instance.
  struct LiveJob {
    JobRecord record;
    std::uint64_t version = 1;
    std::stop_source stop;
    bool cancel_requested = false;
    bool lease_lost = false;  // another instance holds it now: drop the outcome
    // Its end is being stored: from now on the store, where the end and the
    // result appear together, is what every reader sees, so that no reader
    // hears "running" here after another heard the end from the store.
    bool ending = false;
  };

  // Stores the job as queued, within the jobs' limits and the tenant's
  // result quota (with `result_bytes`, the estimate of its result); a
  // retry with the same `request_id` gets the job the first call made.
  Result<JobRecord> enqueue(JobRecord record, double result_bytes, const std::string& request_id);
  // Retention: deletes the ended jobs past max_tenant_jobs_kept or
  // max_job_age_days, every tenant's.
  void delete_old_jobs();
  void worker_loop();
  void lease_loop();
  void run(JobRecord job);
  // Ends a claimed job in the store (state, error, result) and for watchers.
  void finish(JobRecord job, const Result<std::string>& result, std::chrono::steady_clock::time_point claimed);
  // Renews the lease of a running job and publishes its progress; marks the
  // job lost (and stops it) if another instance holds it now, or cancelled if
  // a client asked for that through another instance.
  void renew(const JobRecord& job);
  // The result (encoded JobResult), or why the job failed.
  // Runs the job (job_execution.hpp), publishing its progress to watchers.
  Result<std::string> execute(const JobRecord& job, std::stop_token stop);
  // Applies `change` to a running job's record, bumps its version and wakes
  // watchers; returns the changed record (nullopt: not running here).
  template <typename Change>
  std::optional<JobRecord> update(const std::string& id, Change&& change);
  // Tells the change listener that job `id` changed (empty: every job).
  void notify_changed(const std::string& id);

  Store& store_;
  const ModelCatalog& models_;
  // max_jobs, max_tenant_jobs, max_passes, max_result_bytes, max_job_attempts,
  // max_tenant_result_bytes, max_tenant_jobs_kept, max_job_age_days
  const Limits limits_;
  ResultReads result_reads_{limits_.max_result_read_bytes};
  const int worker_count_;
  const JobQueueOptions queue_;
  const std::string instance_;
  Metrics* const metrics_;

  std::mutex submit_mu_;  // a limit check and the insert it allows go together
  std::mutex mu_;
  std::function<void(const std::string&)> change_listener_;  // a running job changed, or shutdown
  ResultListener result_listener_;                            // a job's result was stored
  std::condition_variable work_ready_;  // a job was submitted here, or shutdown (workers)
  std::condition_variable stopped_;     // shutdown (the renewal thread)
  std::map<std::string, LiveJob> live_;  // the jobs running on this instance
  int submitted_ = 0;                    // submissions not yet looked for by a worker
  bool stopping_ = false;
  std::vector<std::thread> workers_;
  std::thread renewals_;
};

}  // namespace riccati::service
