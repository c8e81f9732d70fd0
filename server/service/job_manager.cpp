#include "service/job_manager.hpp"

#include <spdlog/spdlog.h>

#include "engine/identification.hpp"
#include "engine/validation.hpp"
#include "service/convert.hpp"

namespace riccati::service {

namespace {

constexpr const char* kIdentification = "identification";
constexpr const char* kValidation = "validation";

Result<ModelPtr> find_model(const ModelRegistry& models, const std::string& name) {
  ModelPtr m = models.find(name);
  if (m == nullptr) return not_found("no model \"" + name + "\" is loaded");
  return m;
}

}  // namespace

JobManager::JobManager(Store& store, const ModelRegistry& models, int workers, Limits limits)
    : store_(store), models_(models), limits_(limits), worker_count_(std::max(1, workers)) {}

JobManager::~JobManager() { shutdown(); }

Status JobManager::start() {
  RICCATI_ASSIGN_OR_RETURN(const std::vector<JobRecord> unfinished,
                           store_.jobs_in_states({JobState::kQueued, JobState::kRunning}));
  for (JobRecord job : unfinished) {
    spdlog::info("job requeued id={} kind={} was={}", job.id, job.kind, job_state_name(job.state));
    job.state = JobState::kQueued;
    job.started_ms = 0;
    RICCATI_RETURN_IF_ERROR(store_.update_job(job));
    std::lock_guard lock(mu_);
    queue_.push_back(job.id);
    live_[job.id].record = std::move(job);
  }
  std::lock_guard lock(mu_);
  for (int i = 0; i < worker_count_; ++i) workers_.emplace_back([this] { worker_loop(); });
  return Status::ok();
}

void JobManager::shutdown() {
  {
    std::lock_guard lock(mu_);
    if (stopping_ && workers_.empty()) return;
    stopping_ = true;
    for (auto& [id, job] : live_) job.stop.request_stop();
  }
  work_ready_.notify_all();
  changed_.notify_all();
  for (auto& w : workers_) w.join();
  workers_.clear();
}

Result<JobRecord> JobManager::submit_identification(const std::string& tenant, const v1::IdentificationSpec& spec) {
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, find_model(models_, spec.model()));
  if (spec.passes() > limits_.max_passes) {
    return limit_reached("max_passes", limits_.max_passes, "the job asks for " + std::to_string(spec.passes()) + " passes");
  }
  RICCATI_ASSIGN_OR_RETURN(const IdentificationSettings settings, from_proto(spec, *model));
  RICCATI_ASSIGN_OR_RETURN(const DatasetRecord dataset, store_.get_dataset(tenant, spec.dataset_id()));
  JobRecord job;
  job.id = new_id("job");
  job.tenant = tenant;
  job.kind = kIdentification;
  job.passes = settings.passes;
  job.samples = dataset.samples;
  job.spec = spec.SerializeAsString();
  return enqueue(std::move(job));
}

Result<JobRecord> JobManager::submit_validation(const std::string& tenant, const v1::ValidationSpec& spec) {
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, find_model(models_, spec.model()));
  RICCATI_ASSIGN_OR_RETURN(const ValidationSettings settings, from_proto(spec, *model));
  RICCATI_ASSIGN_OR_RETURN(const DatasetRecord dataset, store_.get_dataset(tenant, spec.dataset_id()));
  if (spec.has_theta()) {
    RICCATI_RETURN_IF_ERROR(from_values(spec.theta().values(), model->ntheta(), "theta").status());
  } else if (spec.has_identification_job_id()) {
    RICCATI_ASSIGN_OR_RETURN(const JobRecord source, get(tenant, spec.identification_job_id()));
    if (source.kind != kIdentification) {
      return invalid_argument("job " + source.id + " is not an identification");
    }
  }
  JobRecord job;
  job.id = new_id("job");
  job.tenant = tenant;
  job.kind = kValidation;
  job.samples = dataset.samples;
  job.spec = spec.SerializeAsString();
  return enqueue(std::move(job));
}

Result<JobRecord> JobManager::enqueue(JobRecord job) {
  job.state = JobState::kQueued;
  job.created_ms = now_ms();
  {
    // live_ holds exactly the queued and running jobs.
    std::lock_guard lock(mu_);
    if (static_cast<std::int64_t>(live_.size()) >= limits_.max_jobs) {
      return limit_reached("max_jobs", limits_.max_jobs, "riccatid has that many jobs queued or running");
    }
    const auto own = std::count_if(live_.begin(), live_.end(),
                                   [&](const auto& entry) { return entry.second.record.tenant == job.tenant; });
    if (own >= limits_.max_tenant_jobs) {
      return limit_reached("max_tenant_jobs", limits_.max_tenant_jobs,
                           "this tenant has that many jobs queued or running; wait for one to end or cancel one");
    }
  }
  RICCATI_RETURN_IF_ERROR(store_.put_job(job));
  {
    std::lock_guard lock(mu_);
    if (stopping_) return Status(StatusCode::kUnavailable, "riccatid is shutting down; the job is stored and will run");
    queue_.push_back(job.id);
    live_[job.id].record = job;
  }
  work_ready_.notify_one();
  spdlog::info("job queued id={} kind={} tenant={}", job.id, job.kind, job.tenant);
  return job;
}

Result<JobRecord> JobManager::get(const std::string& tenant, const std::string& id) {
  {
    std::lock_guard lock(mu_);
    auto it = live_.find(id);
    if (it != live_.end() && it->second.record.tenant == tenant) return it->second.record;
  }
  return store_.get_job(tenant, id);
}

Result<JobRecord> JobManager::cancel(const std::string& tenant, const std::string& id) {
  bool was_queued = false;
  {
    std::lock_guard lock(mu_);
    auto it = live_.find(id);
    if (it == live_.end() || it->second.record.tenant != tenant) {
      // Not live: finished already (or unknown, which get() reports).
      return store_.get_job(tenant, id);
    }
    it->second.cancel_requested = true;
    it->second.stop.request_stop();
    was_queued = it->second.record.state == JobState::kQueued;
  }
  if (was_queued) {
    // No worker will see it: settle it here (a worker popping it skips it).
    RICCATI_RETURN_IF_ERROR(update(id, true, [](JobRecord& r) {
      r.state = JobState::kCancelled;
      r.error_code = static_cast<int>(StatusCode::kCancelled);
      r.error_message = "cancelled before it started";
      r.finished_ms = now_ms();
    }));
  }
  return get(tenant, id);
}

Result<JobRecord> JobManager::wait_for_change(const std::string& tenant, const std::string& id,
                                              std::uint64_t* version,
                                              std::chrono::steady_clock::time_point deadline) {
  std::unique_lock lock(mu_);
  auto it = live_.find(id);
  if (it == live_.end() || it->second.record.tenant != tenant) {
    lock.unlock();
    *version = UINT64_MAX;  // not live: it will not change any more
    return store_.get_job(tenant, id);
  }
  changed_.wait_until(lock, deadline, [&] {
    auto found = live_.find(id);
    return stopping_ || found == live_.end() || found->second.version > *version;
  });
  if (stopping_) {
    return Status(StatusCode::kUnavailable, "riccatid is shutting down; the job goes on after it restarts: watch again");
  }
  auto found = live_.find(id);
  if (found == live_.end()) {
    lock.unlock();
    *version = UINT64_MAX;
    return store_.get_job(tenant, id);
  }
  *version = found->second.version;
  return found->second.record;
}

template <typename Change>
Status JobManager::update(const std::string& id, bool persist, Change&& change) {
  JobRecord copy;
  {
    std::lock_guard lock(mu_);
    auto it = live_.find(id);
    if (it == live_.end()) return Status::ok();
    change(it->second.record);
    ++it->second.version;
    copy = it->second.record;
    if (is_terminal(copy.state)) live_.erase(it);  // the store has the final word
  }
  Status stored = persist ? store_.update_job(copy) : Status::ok();
  changed_.notify_all();
  if (!stored.is_ok()) spdlog::error("job update not stored id={} error=\"{}\"", id, stored.message());
  return stored;
}

void JobManager::worker_loop() {
  for (;;) {
    std::string id;
    {
      std::unique_lock lock(mu_);
      work_ready_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      id = std::move(queue_.front());
      queue_.pop_front();
    }
    run(id);
  }
}

void JobManager::run(const std::string& id) {
  JobRecord job;
  std::stop_token stop;
  {
    std::lock_guard lock(mu_);
    auto it = live_.find(id);
    if (it == live_.end() || it->second.record.state != JobState::kQueued) return;  // cancelled meanwhile
    job = it->second.record;
    stop = it->second.stop.get_token();
  }
  (void)update(id, true, [](JobRecord& r) {
    r.state = JobState::kRunning;
    r.started_ms = now_ms();
  });
  spdlog::info("job started id={} kind={}", id, job.kind);

  Result<std::string> result = execute(job, stop);
  bool cancel_requested = false;
  bool stopping = false;
  {
    std::lock_guard lock(mu_);
    auto it = live_.find(id);
    cancel_requested = it != live_.end() && it->second.cancel_requested;
    stopping = stopping_;
  }
  if (!result.is_ok() && result.status().code() == StatusCode::kCancelled && stopping && !cancel_requested) {
    // Interrupted by shutdown: leave it "running" in the store, so that the
    // next start runs it again.
    spdlog::info("job interrupted by shutdown id={} (runs again at the next start)", id);
    std::lock_guard lock(mu_);
    live_.erase(id);
    return;
  }
  if (result.is_ok()) {
    Status stored = store_.put_result(job.tenant, id, result.value());
    if (!stored.is_ok()) result = stored;
  }
  const Status outcome = result.status();
  (void)update(id, true, [&](JobRecord& r) {
    r.finished_ms = now_ms();
    if (outcome.is_ok()) {
      r.state = JobState::kSucceeded;
    } else {
      r.state = outcome.code() == StatusCode::kCancelled ? JobState::kCancelled : JobState::kFailed;
      r.error_code = static_cast<int>(outcome.code());
      r.error_message = outcome.message();
    }
  });
  if (outcome.is_ok()) {
    spdlog::info("job succeeded id={}", id);
  } else {
    spdlog::info("job ended id={} state={} error=\"{}\"", id,
                 outcome.code() == StatusCode::kCancelled ? "cancelled" : "failed", outcome.message());
  }
}

Result<std::string> JobManager::execute(const JobRecord& job, std::stop_token stop) {
  if (job.kind == kIdentification) return execute_identification(job, stop);
  if (job.kind == kValidation) return execute_validation(job, stop);
  return internal_error("job " + job.id + " has unknown kind \"" + job.kind + "\"");
}

namespace {

// A checkpoint record: one pass and the covariance at its end, as an
// IdentificationResult with a single pass.
std::string encode_pass(const PassResult& pass, const Eigen::MatrixXd& covariance) {
  IdentificationResult one;
  one.passes.push_back(pass);
  one.theta = pass.theta_final;
  one.theta_mean = pass.theta_mean;
  one.theta_std = pass.theta_std;
  one.covariance = covariance;
  v1::IdentificationResult encoded = to_proto(one);
  encoded.clear_param_names();
  return encoded.SerializeAsString();
}

Status decode_passes(const std::vector<std::string>& records, IdentificationCheckpoint* out) {
  for (std::size_t i = 0; i < records.size(); ++i) {
    v1::IdentificationResult encoded;
    if (!encoded.ParseFromString(records[i]) || encoded.passes_size() != 1) {
      return internal_error("pass record " + std::to_string(i + 1) + " is unreadable");
    }
    // from_proto checks sizes against param_names; records leave them out.
    for (int k = 0; k < encoded.theta_size(); ++k) encoded.add_param_names("theta" + std::to_string(k));
    RICCATI_ASSIGN_OR_RETURN(IdentificationResult one, from_proto(encoded));
    out->passes.push_back(std::move(one.passes.front()));
    out->covariance = std::move(one.covariance);
  }
  return Status::ok();
}

}  // namespace

Result<std::string> JobManager::execute_identification(const JobRecord& job, std::stop_token stop) {
  v1::IdentificationSpec spec;
  if (!spec.ParseFromString(job.spec)) return internal_error("job " + job.id + ": stored spec is unreadable");
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, find_model(models_, spec.model()));
  RICCATI_ASSIGN_OR_RETURN(const IdentificationSettings settings, from_proto(spec, *model));
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, store_.load_dataset(job.tenant, spec.dataset_id()));

  auto last_publish = std::chrono::steady_clock::now();
  auto progress = [&](const IdentificationProgress& p) {
    const auto now = std::chrono::steady_clock::now();
    const bool pass_done = p.sample == p.samples;
    if (!pass_done && now - last_publish < kProgressInterval) return;
    last_publish = now;
    // Progress is for watchers; the store gets it at the end of each pass.
    (void)update(job.id, pass_done, [&](JobRecord& r) {
      r.pass = p.pass;
      r.passes = p.passes;
      r.sample = p.sample;
      r.samples = p.samples;
      r.theta.assign(p.theta->data() + model->nx(), p.theta->data() + p.theta->size());
    });
  };
  IdentificationHooks hooks;
  hooks.progress = progress;
  hooks.stop = stop;
  // After each pass, what resumes the job if the daemon dies (kill -9,
  // power loss) before the next one ends.
  hooks.pass_done = [&](int pass, const PassResult& result, const Eigen::MatrixXd& covariance) {
    return store_.put_job_pass(job.tenant, job.id, pass, encode_pass(result, covariance));
  };
  RICCATI_ASSIGN_OR_RETURN(const std::vector<std::string> records, store_.list_job_passes(job.tenant, job.id));
  IdentificationCheckpoint resume;
  if (!records.empty()) {
    Status decoded = decode_passes(records, &resume);
    if (decoded.is_ok()) {
      hooks.resume = &resume;
      spdlog::info("job resumes id={} after_pass={}", job.id, resume.passes.size());
    } else {
      spdlog::warn("job checkpoint unusable, running from the start id={} error=\"{}\"", job.id, decoded.message());
    }
  }
  RICCATI_ASSIGN_OR_RETURN(const IdentificationResult r, identify(model, data, settings, hooks));
  v1::JobResult result;
  result.set_job_id(job.id);
  *result.mutable_identification() = to_proto(r);
  return result.SerializeAsString();
}

Result<std::string> JobManager::execute_validation(const JobRecord& job, std::stop_token stop) {
  v1::ValidationSpec spec;
  if (!spec.ParseFromString(job.spec)) return internal_error("job " + job.id + ": stored spec is unreadable");
  RICCATI_ASSIGN_OR_RETURN(const ModelPtr model, find_model(models_, spec.model()));
  RICCATI_ASSIGN_OR_RETURN(ValidationSettings settings, from_proto(spec, *model));
  if (spec.has_identification_job_id()) {
    RICCATI_ASSIGN_OR_RETURN(const std::string encoded, store_.get_result(job.tenant, spec.identification_job_id()));
    v1::JobResult source;
    if (!source.ParseFromString(encoded) || !source.has_identification()) {
      return failed_precondition("job " + spec.identification_job_id() + " has no identification result");
    }
    RICCATI_ASSIGN_OR_RETURN(settings.theta,
                             from_values(source.identification().theta_mean(), model->ntheta(), "theta"));
  } else if (spec.has_theta()) {
    RICCATI_ASSIGN_OR_RETURN(settings.theta, from_values(spec.theta().values(), model->ntheta(), "theta"));
  } else {
    settings.theta = model->theta_default();
  }
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, store_.load_dataset(job.tenant, spec.dataset_id()));
  if (stop.stop_requested()) return cancelled("validation cancelled");
  RICCATI_ASSIGN_OR_RETURN(const ValidationResult r, validate_model(*model, data, settings));
  v1::JobResult result;
  result.set_job_id(job.id);
  *result.mutable_validation() = to_proto(r, settings.theta);
  return result.SerializeAsString();
}

}  // namespace riccati::service
