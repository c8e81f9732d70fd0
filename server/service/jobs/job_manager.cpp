#include "service/jobs/job_manager.hpp"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <cstdio>
#include <limits>
#include <random>

#include "engine/estimation/identification.hpp"
#include "engine/estimation/validation.hpp"
#include "service/convert.hpp"
#include "service/ids.hpp"
#include "service/jobs/job_convert.hpp"
#include "service/jobs/identification_job.hpp"
#include "service/jobs/job_execution.hpp"
#include "service/run_settings.hpp"

namespace riccati::service {

namespace {

// <hostname>-<random>: unique among the instances sharing a store.
std::string default_instance_id() {
  char host[256] = {};
  if (gethostname(host, sizeof host - 1) != 0 || host[0] == '\0') std::snprintf(host, sizeof host, "riccatid");
  std::random_device random;
  char suffix[16];
  std::snprintf(suffix, sizeof suffix, "%08x", random());
  return std::string(host) + "-" + suffix;
}

// RESOURCE_EXHAUSTED (max_result_bytes) naming the estimate and what to
// change: a result past the store's limit (1 GB for SQLite) would be
// computed, then fail to be stored.
Status check_result_size(const ResultSize& size, std::int64_t limit) {
  if (size.bytes <= static_cast<double>(limit)) return Status::ok();
  char bytes[32];
  std::snprintf(bytes, sizeof bytes, "%.0f", size.bytes);
  return limit_reached("max_result_bytes", limit,
                       std::string("the job's result would take about ") + bytes + " bytes (" + size.what +
                           ", 8 bytes each): ask for " + size.smaller + ", or raise max_result_bytes");
}

}  // namespace

JobManager::JobManager(Store& store, const ModelCatalog& models, int workers, Limits limits, JobQueueOptions queue,
                       Metrics* metrics)
    : store_(store),
      models_(models),
      limits_(limits),
      worker_count_(std::max(1, workers)),
      queue_(queue),
      instance_(queue.instance_id.empty() ? default_instance_id() : queue.instance_id),
      metrics_(metrics) {}

JobManager::~JobManager() { shutdown(); }

Status JobManager::start() {
  // With a store of its own, every job left running was this instance's
  // (killed, or stopped mid-job); with a shared one, only those of this
  // instance's id: the others belong to live instances or wait for their
  // leases to expire.
  // Their claims count as attempts: their instance died with them.
  // On a full store (a full disk) the release cannot be written: riccatid
  // starts anyway, to read and delete (the jobs' leases expire instead, and
  // they are claimed again then).
  const Result<int> released = store_.release_jobs(queue_.exclusive_store ? "" : instance_, /*stopped=*/false);
  if (!released.is_ok() && released.status().code() != StatusCode::kResourceExhausted) return released.status();
  if (!released.is_ok()) {
    spdlog::warn("jobs of an earlier run not released error=\"{}\"", released.status().message());
  } else if (released.value() > 0) {
    spdlog::info("jobs queued again count={} (left running by an earlier run)", released.value());
  }
  spdlog::info("job queue instance={} lease_ms={} poll_ms={}", instance_, queue_.lease.count(), queue_.poll.count());
  std::lock_guard lock(mu_);
  for (int i = 0; i < worker_count_; ++i) workers_.emplace_back([this] { worker_loop(); });
  renewals_ = std::thread([this] { lease_loop(); });
  return Status::ok();
}

void JobManager::shutdown() {
  result_reads_.stop();
  {
    std::lock_guard lock(mu_);
    if (stopping_ && workers_.empty()) return;
    stopping_ = true;
    for (auto& [id, job] : live_) job.stop.request_stop();
  }
  work_ready_.notify_all();
  notify_changed({});
  stopped_.notify_all();
  for (auto& w : workers_) w.join();
  workers_.clear();
  if (renewals_.joinable()) renewals_.join();
  // The interrupted jobs go back to the queue now rather than when their
  // leases expire: another instance, or the next start, resumes them.
  auto released = store_.release_jobs(instance_, /*stopped=*/true);
  if (!released.is_ok()) spdlog::warn("interrupted jobs not released error=\"{}\"", released.status().message());
}

namespace {

// The spec as stored: its model named by the revision it was checked
// against (name@revision for a stored text model), so that a new upload of
// the name does not change the job's model before it runs.
template <typename Spec>
std::string with_model(const Spec& spec, const std::string& reference) {
  if (spec.model() == reference) return spec.SerializeAsString();
  Spec pinned = spec;
  pinned.set_model(reference);
  return pinned.SerializeAsString();
}

}  // namespace

Result<JobRecord> JobManager::submit_identification(const std::string& tenant, const v1::IdentificationSpec& spec) {
  RICCATI_ASSIGN_OR_RETURN(const ResolvedModel resolved, models_.resolve(tenant, spec.model()));
  const ModelPtr& model = resolved.model;
  const uint32_t passes = std::max(spec.passes(), spec.init_passes());
  if (passes > limits_.max_passes) {
    return limit_reached("max_passes", limits_.max_passes, "the job asks for " + std::to_string(passes) + " passes");
  }
  RICCATI_ASSIGN_OR_RETURN(const IdentificationJob plan, identification_from_proto(spec, *model));
  std::vector<DatasetRecord> datasets;
  for (const ExperimentSpec& e : plan.experiments) {
    RICCATI_ASSIGN_OR_RETURN(DatasetRecord record, store_.get_dataset(tenant, e.dataset_id));
    datasets.push_back(std::move(record));
  }
  RICCATI_RETURN_IF_ERROR(check_against_datasets(plan, datasets, *model));
  const ResultSize result_size = estimated_result_size(plan, datasets, *model);
  RICCATI_RETURN_IF_ERROR(check_result_size(result_size, limits_.max_result_bytes));
  JobRecord job;
  job.id = new_id("job");
  job.tenant = tenant;
  job.kind = JobKind::kIdentification;
  job.passes = identification_method_info(plan.method).iterated_filter ? plan.filter.passes : plan.init_passes;
  job.samples = datasets.front().samples;
  job.spec = with_model(spec, resolved.reference);
  job.model = resolved.reference;
  return enqueue(std::move(job), result_size.bytes, spec.request_id());
}

Result<JobRecord> JobManager::submit_smoothing(const std::string& tenant, const v1::SmoothingSpec& spec) {
  RICCATI_ASSIGN_OR_RETURN(const ResolvedModel resolved, models_.resolve(tenant, spec.model()));
  const ModelPtr& model = resolved.model;
  RICCATI_RETURN_IF_ERROR(check_settings_apply(spec));
  RICCATI_ASSIGN_OR_RETURN(const SmootherSettings settings, from_proto(spec, *model));
  RICCATI_ASSIGN_OR_RETURN(const DatasetRecord dataset, store_.get_dataset(tenant, spec.dataset_id()));
  RICCATI_RETURN_IF_ERROR(dataset_fits_model(dataset, *model).with_context("dataset " + dataset.id));
  const Eigen::Index end = settings.end_sample < 0 ? dataset.samples : settings.end_sample;
  if (end > dataset.samples || end - settings.first_sample < 2) {
    return invalid_argument("the sample range [" + std::to_string(settings.first_sample) + ", " + std::to_string(end) +
                            ") must hold at least two of the dataset's " + std::to_string(dataset.samples) + " samples");
  }
  ResultSize result_size;
  {
    // Per sample: t, the filtered and smoothed means and deviations of z
    // (the states, then the parameters), y_model and innovations, and with
    // full_covariance, P of z.
    const double samples = static_cast<double>(end - settings.first_sample);
    const double nz = model->nx() + model->ntheta();
    const double per_sample = 1 + 4 * nz + 2 * model->ny() + (spec.full_covariance() ? nz * nz : 0);
    result_size = {8 * samples * per_sample + kFixedResultBytes + kResultBytesPerName * nz,
         std::to_string(end - settings.first_sample) + " samples x " + std::to_string(static_cast<int>(per_sample)) +
             " values (" + std::to_string(static_cast<int>(nz)) + " states and parameters" +
             (spec.full_covariance() ? ", with their full covariance" : "") + ")",
         std::string("a shorter sample range (first_sample, end_sample)") +
             (spec.full_covariance() ? ", or no full_covariance" : "")};
    RICCATI_RETURN_IF_ERROR(check_result_size(result_size, limits_.max_result_bytes));
  }
  JobRecord job;
  job.id = new_id("job");
  job.tenant = tenant;
  job.kind = JobKind::kSmoothing;
  job.passes = 2;  // forward and back
  job.samples = end - settings.first_sample;
  job.spec = with_model(spec, resolved.reference);
  job.model = resolved.reference;
  return enqueue(std::move(job), result_size.bytes, spec.request_id());
}

Result<JobRecord> JobManager::submit_validation(const std::string& tenant, const v1::ValidationSpec& spec) {
  if (!v1::EstimateChoice_IsValid(spec.estimate())) {
    return invalid_argument("estimate " + std::to_string(spec.estimate()) + " is unknown (expected " +
                            api::enum_choice_list(*v1::EstimateChoice_descriptor()) + ")");
  }
  RICCATI_ASSIGN_OR_RETURN(const ResolvedModel resolved, models_.resolve(tenant, spec.model()));
  const ModelPtr& model = resolved.model;
  RICCATI_ASSIGN_OR_RETURN(const ValidationSettings settings, from_proto(spec));
  RICCATI_ASSIGN_OR_RETURN(const DatasetRecord dataset, store_.get_dataset(tenant, spec.dataset_id()));
  if (spec.horizon() > 0 && !spec.has_identification_job_id()) {
    return invalid_argument("horizon " + std::to_string(spec.horizon()) +
                            " needs an identification job's estimate (identification_job_id, --params JOB): a prediction corrects the "
                            "states with that job's filter and noise model (its Q, R and P0)");
  }
  if (spec.has_theta()) {
    RICCATI_RETURN_IF_ERROR(from_values(spec.theta().values(), model->ntheta(), "theta").status());
  } else if (spec.has_identification_job_id()) {
    RICCATI_ASSIGN_OR_RETURN(const JobRecord source, get(tenant, spec.identification_job_id()));
    if (source.kind != JobKind::kIdentification) {
      return invalid_argument("job " + source.id + " is not an identification");
    }
    v1::IdentificationSpec source_spec;
    const bool iterated_filter = !source_spec.ParseFromString(source.spec) ||
                                 source_spec.method() == v1::IDENTIFICATION_METHOD_UNSPECIFIED ||
                                 source_spec.method() == v1::IDENTIFICATION_METHOD_FILTER;
    // Its estimate is of its own model's parameters: another model's
    // validation would only fail as a job ("theta needs 6 values, got 4").
    const Result<ResolvedModel> identified = models_.resolve(tenant, source.model);
    if (identified.is_ok() && identified.value().model->param_names() != model->param_names()) {
      const auto list = [](const std::vector<std::string>& names) {
        std::string out;
        for (const std::string& n : names) out += (out.empty() ? "" : ", ") + n;
        return out;
      };
      return invalid_argument("job " + source.id + " identified model " + identified.value().model->name() + " (" +
                              list(identified.value().model->param_names()) + "), not " + model->name() + " (" +
                              list(model->param_names()) + "): validate it with model " +
                              identified.value().model->name());
    }
    if (spec.estimate() != v1::ESTIMATE_CHOICE_UNSPECIFIED && !iterated_filter) {
      return invalid_argument("estimate: job " + source.id +
                              " is an output-error or likelihood identification, with one estimate; the choice between "
                              "the last pass's mean and its end is the iterated filter's");
    }
  }
  RICCATI_RETURN_IF_ERROR(dataset_fits_model(dataset, *model).with_context("dataset " + dataset.id));
  RICCATI_ASSIGN_OR_RETURN(const std::vector<bool> estimated, estimated_states(spec.initial_state(), *model, "initial_state"));
  const bool any = std::find(estimated.begin(), estimated.end(), true) != estimated.end();
  if (spec.estimate_x0_samples() > 0 && !any) {
    return invalid_argument("estimate_x0_samples needs initial_state.estimate to name the states to fit (or all)");
  }
  if (spec.estimate_x0_samples() == 0 && any) {
    return invalid_argument("initial_state.estimate needs estimate_x0_samples: the samples to fit the states on");
  }
  if (spec.estimate_x0_samples() > static_cast<uint64_t>(dataset.samples) || spec.estimate_x0_samples() == 1) {
    return invalid_argument("estimate_x0_samples = " + std::to_string(spec.estimate_x0_samples()) +
                            ": the initial states are fitted on 2 to " + std::to_string(dataset.samples) + " samples");
  }
  if (settings.initial_state == InitialState::kGiven && settings.x0.size() != model->nx()) {
    return invalid_argument("initial_state.x0 needs " + std::to_string(model->nx()) +
                            " values (or first_measurement = true)");
  }
  // Per sample: t, the measured and the simulated outputs.
  const int per_sample = 1 + 2 * model->ny();
  const ResultSize result_size{8.0 * static_cast<double>(dataset.samples) * per_sample + kFixedResultBytes +
                                   kResultBytesPerName * (model->nx() + model->ntheta() + model->ny()),
                               std::to_string(dataset.samples) + " samples x " + std::to_string(per_sample) + " values",
                               "a dataset with fewer samples"};
  RICCATI_RETURN_IF_ERROR(check_result_size(result_size, limits_.max_result_bytes));
  JobRecord job;
  job.id = new_id("job");
  job.tenant = tenant;
  job.kind = JobKind::kValidation;
  job.samples = dataset.samples;
  job.spec = with_model(spec, resolved.reference);
  job.model = resolved.reference;
  return enqueue(std::move(job), result_size.bytes, spec.request_id());
}

Result<JobRecord> JobManager::enqueue(JobRecord job, double result_bytes, const std::string& request_id) {
  RICCATI_RETURN_IF_ERROR(check_client_string("request_id", request_id, kMaxRequestIdBytes));
  if (static_cast<std::int64_t>(job.spec.size()) > limits_.max_stored_request_bytes) {
    return limit_reached("max_stored_request_bytes", limits_.max_stored_request_bytes,
                         "the job's spec is " + std::to_string(job.spec.size()) + " bytes encoded");
  }
  job.state = JobState::kQueued;
  job.created_ms = now_ms();
  // A retry of a request that made a job gets that job. The request_id is
  // claimed only once the job has passed its limits: a refused submit
  // stores nothing.
  std::optional<std::string> earlier;
  if (!request_id.empty()) {
    RICCATI_ASSIGN_OR_RETURN(earlier, store_.find_request_id(job.tenant, request_id, "job"));
    if (earlier) {
      job.id = *earlier;
      if (Result<JobRecord> made = get(job.tenant, job.id);
          made.is_ok() || made.status().code() != StatusCode::kNotFound) {
        return made;
      }
    }
  }
  {
    std::lock_guard submit(submit_mu_);
    // Queued or running, on every instance sharing the store: counted, no
    // job's spec read.
    RICCATI_ASSIGN_OR_RETURN(const UnfinishedJobs unfinished, store_.count_unfinished_jobs(job.tenant));
    if (unfinished.queued + unfinished.running >= limits_.max_jobs) {
      return limit_reached("max_jobs", limits_.max_jobs, "that many jobs are queued or running");
    }
    if (unfinished.of_tenant >= limits_.max_tenant_jobs) {
      return limit_reached("max_tenant_jobs", limits_.max_tenant_jobs,
                           "this tenant has that many jobs queued or running; wait for one to end or cancel one");
    }
    // The tenant's stored results and this one's estimate: within its quota.
    RICCATI_ASSIGN_OR_RETURN(const std::int64_t results, store_.result_bytes(job.tenant));
    if (static_cast<double>(results) + result_bytes > static_cast<double>(limits_.max_tenant_result_bytes)) {
      return limit_reached("max_tenant_result_bytes", limits_.max_tenant_result_bytes,
                           "this tenant's results take " + std::to_string(results) + " bytes, and this job's about " +
                               std::to_string(static_cast<std::int64_t>(result_bytes)) +
                               " more: delete jobs it no longer needs (DeleteJob, riccati job delete ID)");
    }
    if (!request_id.empty() && !earlier) {
      const std::string mine = job.id;
      RICCATI_ASSIGN_OR_RETURN(job.id, store_.claim_request_id(job.tenant, request_id, "job", job.id));
      if (job.id != mine) {
        // Another call with the same request_id claimed it first.
        if (Result<JobRecord> made = get(job.tenant, job.id);
            made.is_ok() || made.status().code() != StatusCode::kNotFound) {
          return made;
        }
      }
    }
    const Status stored = store_.put_job(job);
    if (stored.code() == StatusCode::kAlreadyExists && !request_id.empty()) {
      return get(job.tenant, job.id);  // a retry of the same request stored it first
    }
    RICCATI_RETURN_IF_ERROR(stored);
  }
  {
    std::lock_guard lock(mu_);
    ++submitted_;
  }
  work_ready_.notify_one();
  spdlog::info("job queued id={} kind={} tenant={}", job.id, job_kind_name(job.kind), job.tenant);
  return job;
}

Result<JobRecord> JobManager::get(const std::string& tenant, const std::string& id) {
  {
    std::lock_guard lock(mu_);
    auto it = live_.find(id);
    if (it != live_.end() && it->second.record.tenant == tenant && !it->second.ending) return it->second.record;
  }
  return store_.get_job(tenant, id);
}

Result<std::vector<JobRecord>> JobManager::list(const std::string& tenant) {
  RICCATI_ASSIGN_OR_RETURN(std::vector<JobRecord> jobs, store_.list_jobs(tenant));
  std::lock_guard lock(mu_);
  for (JobRecord& job : jobs) {
    // Live progress is fresher than the store's; an ending job's is not.
    auto it = live_.find(job.id);
    if (it != live_.end() && it->second.record.tenant == tenant && !it->second.ending) job = it->second.record;
  }
  return jobs;
}

Result<JobManager::StoredResult> JobManager::result(const std::string& tenant, const std::string& id) {
  // The result first: the store writes it with the job's end, so a job that
  // has one has ended, whatever a reader saw before. Its size first, to wait
  // for room among the reads in progress before it is read.
  Result<std::int64_t> size = store_.result_size(tenant, id);
  if (size.is_ok()) {
    StoredResult out;
    RICCATI_ASSIGN_OR_RETURN(out.read, result_reads_.acquire(size.value()));
    Result<std::string> stored = store_.get_result(tenant, id);
    if (stored.is_ok()) {
      out.encoded = std::move(stored).value();
      return out;
    }
    if (stored.status().code() != StatusCode::kNotFound) return stored.status();  // else deleted meanwhile
  } else if (size.status().code() != StatusCode::kNotFound) {
    return size.status();
  }
  RICCATI_ASSIGN_OR_RETURN(const JobRecord job, get(tenant, id));
  return failed_precondition("job " + id + " has no result: it is " + job_state_name(job.state));
}

Result<JobRecord> JobManager::cancel(const std::string& tenant, const std::string& id) {
  {
    std::lock_guard lock(mu_);
    auto it = live_.find(id);
    if (it != live_.end() && it->second.record.tenant == tenant && !it->second.ending) {
      it->second.cancel_requested = true;
      it->second.record.cancel_requested = true;  // shown as CANCELLING until it stops
      it->second.stop.request_stop();
      return it->second.record;
    }
  }
  // Queued (cancelled at once) or running on another instance (which sees
  // the request at its next renewal), or ended (left as it is).
  return store_.cancel_job(tenant, id);
}

namespace {

// A watcher's version of a job it reads from the store: changes when the
// state or the progress does. The top bit keeps it apart from the counters
// of jobs running here.
std::uint64_t stored_version(const JobRecord& job) {
  std::uint64_t h = std::hash<std::string>{}(job.id);
  for (std::int64_t v : {static_cast<std::int64_t>(job.state), static_cast<std::int64_t>(job.pass), job.sample,
                         static_cast<std::int64_t>(job.iteration), job.started_ms, job.finished_ms}) {
    h = (h ^ static_cast<std::uint64_t>(v)) * 1099511628211ull;
  }
  return (h | (1ull << 63)) & ~1ull;  // never UINT64_MAX
}

}  // namespace

Result<std::optional<JobRecord>> JobManager::poll(const std::string& tenant, const std::string& id,
                                                  std::uint64_t* version, bool* running_here) {
  *running_here = false;
  {
    std::lock_guard lock(mu_);
    if (stopping_) {
      return Status(StatusCode::kUnavailable, "riccatid is shutting down; the job goes on after it restarts: watch again");
    }
    auto it = live_.find(id);
    // While its end is being stored, the store is read: it has the end and
    // the result together, or neither.
    if (it != live_.end() && it->second.record.tenant == tenant && !it->second.ending) {
      *running_here = true;
      if (it->second.version == *version) return std::optional<JobRecord>();
      *version = it->second.version;
      return std::optional<JobRecord>(it->second.record);
    }
  }
  RICCATI_ASSIGN_OR_RETURN(JobRecord stored, store_.get_job(tenant, id));
  const std::uint64_t v = stored_version(stored);
  if (v == *version) return std::optional<JobRecord>();
  *version = v;
  return std::optional<JobRecord>(std::move(stored));
}

void JobManager::set_change_listener(std::function<void(const std::string&)> listener) {
  std::lock_guard lock(mu_);
  change_listener_ = std::move(listener);
}

void JobManager::set_result_listener(ResultListener listener) {
  std::lock_guard lock(mu_);
  result_listener_ = std::move(listener);
}

void JobManager::notify_changed(const std::string& id) {
  std::function<void(const std::string&)> listener;
  {
    std::lock_guard lock(mu_);
    listener = change_listener_;
  }
  if (listener) listener(id);
}

template <typename Change>
std::optional<JobRecord> JobManager::update(const std::string& id, Change&& change) {
  std::optional<JobRecord> copy;
  {
    std::lock_guard lock(mu_);
    auto it = live_.find(id);
    if (it == live_.end()) return std::nullopt;
    change(it->second.record);
    ++it->second.version;
    copy = it->second.record;
  }
  notify_changed(id);
  return copy;
}

void JobManager::worker_loop() {
  // A store that fails (a full disk, a database gone) is asked again after
  // a pause that doubles up to kClaimBackoffMax, and said in the log when it
  // starts failing and when it recovers, not at every try.
  constexpr auto kClaimBackoffMax = std::chrono::seconds(30);
  int failures = 0;
  for (;;) {
    {
      std::lock_guard lock(mu_);
      if (stopping_) return;
    }
    auto claimed = store_.claim_job(instance_, queue_.lease.count());
    if (claimed.is_ok() && failures > 0) {
      spdlog::info("jobs are claimed again after {} failed tries", failures);
      failures = 0;
    }
    if (claimed.is_ok() && claimed.value().has_value()) {
      run(std::move(*claimed.value()));
      continue;
    }
    std::unique_lock lock(mu_);
    if (!claimed.is_ok()) {
      if (failures++ == 0) spdlog::warn("no job claimed, retrying with back-off error=\"{}\"", claimed.status().message());
      const auto pause = std::min<std::chrono::milliseconds>(queue_.poll * (1 << std::min(failures, 6)), kClaimBackoffMax);
      work_ready_.wait_for(lock, pause, [&] { return stopping_; });
      continue;
    }
    work_ready_.wait_for(lock, queue_.poll, [&] { return stopping_ || submitted_ > 0; });
    if (submitted_ > 0) --submitted_;
  }
}

void JobManager::lease_loop() {
  const auto every = std::min<std::chrono::milliseconds>(queue_.lease / 3, std::chrono::seconds(1));
  // Jobs age past max_job_age_days without anything ending: looked for hourly (and at start).
  constexpr auto kRetentionEvery = std::chrono::hours(1);
  auto next_retention = std::chrono::steady_clock::now();
  std::unique_lock lock(mu_);
  while (!stopped_.wait_for(lock, every, [&] { return stopping_; })) {
    std::vector<JobRecord> running;
    for (const auto& [id, job] : live_) running.push_back(job.record);
    lock.unlock();
    for (const JobRecord& job : running) renew(job);
    if (std::chrono::steady_clock::now() >= next_retention) {
      delete_old_jobs();
      next_retention = std::chrono::steady_clock::now() + kRetentionEvery;
    }
    lock.lock();
  }
}

void JobManager::renew(const JobRecord& job) {
  auto renewed = store_.renew_job(job, instance_, queue_.lease.count());
  if (renewed.is_ok() && !renewed.value()) return;
  std::lock_guard lock(mu_);
  auto it = live_.find(job.id);
  // Its end was stored meanwhile (the store answers ABORTED for an ended job).
  if (it == live_.end() || it->second.ending) return;
  if (renewed.is_ok()) {  // a client cancelled it through another instance
    it->second.cancel_requested = true;
    it->second.record.cancel_requested = true;
    it->second.stop.request_stop();
  } else if (renewed.status().code() == StatusCode::kAborted) {
    spdlog::warn("job lease lost id={} instance={}: another instance runs it", job.id, instance_);
    it->second.lease_lost = true;
    it->second.stop.request_stop();
  } else {
    // The store is unreachable: keep running; if it stays so past the
    // lease, another instance takes the job and this outcome is dropped.
    spdlog::warn("job lease not renewed id={} error=\"{}\"", job.id, renewed.status().message());
  }
}

void JobManager::run(JobRecord job) {
  const std::string id = job.id;
  const auto claimed = std::chrono::steady_clock::now();
  if (job.cancel_requested) {
    // Cancelled while its earlier instance ran it, which died before it
    // could stop it.
    finish(std::move(job), cancelled("cancelled"), claimed);
    return;
  }
  if (job.attempts > limits_.max_job_attempts) {
    // Claimed that often without an end: its run kills riccatid, or its end
    // cannot be stored. Failing it now is a small write, and the loop ends.
    const std::string why = job.error_message.empty()
                                ? "riccatid died or could not store its end each time"
                                : "the last error: " + job.error_message;
    spdlog::warn("job failed after too many attempts id={} attempts={} max_job_attempts={}", id, job.attempts - 1,
                 limits_.max_job_attempts);
    const Status exhausted = limit_reached("max_job_attempts", limits_.max_job_attempts,
                                           "the job was claimed " + std::to_string(job.attempts - 1) +
                                               " times without ending: " + why);
    finish(std::move(job), exhausted, claimed);
    return;
  }
  std::stop_token stop;
  {
    std::lock_guard lock(mu_);
    LiveJob& live = live_[id];
    live.record = job;
    stop = live.stop.get_token();
    if (stopping_) live.stop.request_stop();
  }
  notify_changed(id);
  spdlog::info("job started id={} kind={} instance={}", id, job_kind_name(job.kind), instance_);

  Result<std::string> result = execute(job, stop);
  LiveJob outcome;
  bool stopping = false;
  {
    std::lock_guard lock(mu_);
    outcome.record = live_[id].record;
    outcome.cancel_requested = live_[id].cancel_requested;
    outcome.lease_lost = live_[id].lease_lost;
    stopping = stopping_;
  }
  const bool interrupted = !result.is_ok() && result.status().code() == StatusCode::kCancelled &&
                           !outcome.cancel_requested;
  if (outcome.lease_lost || (interrupted && stopping)) {
    // Another instance holds it, or shutdown: leave it to the queue.
    spdlog::info("job left to the queue id={} reason={}", id, outcome.lease_lost ? "lease lost" : "shutdown");
    {
      std::lock_guard lock(mu_);
      live_.erase(id);
    }
    notify_changed(id);
    return;
  }
  if (result.is_ok() && static_cast<std::int64_t>(result.value().size()) > limits_.max_result_bytes) {
    // The estimate at submit is an upper bound (estimated_result_size); a
    // result past the limit anyway is a defect of the estimate, and is not
    // stored.
    spdlog::error("job result over its limit id={} bytes={} max_result_bytes={}", id, result.value().size(),
                  limits_.max_result_bytes);
    return finish(std::move(outcome.record),
                  limit_reached("max_result_bytes", limits_.max_result_bytes,
                                "the job's result took " + std::to_string(result.value().size()) +
                                    " bytes, more than its estimate at submit: nothing stored"),
                  claimed);
  }
  finish(std::move(outcome.record), result, claimed);
}

void JobManager::finish(JobRecord job, const Result<std::string>& result,
                        std::chrono::steady_clock::time_point claimed) {
  const Status outcome = result.status();
  job.finished_ms = now_ms();
  if (outcome.is_ok()) {
    job.state = JobState::kSucceeded;
  } else {
    job.state = outcome.code() == StatusCode::kCancelled ? JobState::kCancelled : JobState::kFailed;
    job.error_code = static_cast<int>(outcome.code());
    job.error_message = outcome.message();
  }
  {
    std::lock_guard lock(mu_);
    auto it = live_.find(job.id);
    if (it != live_.end()) it->second.ending = true;
  }
  Status stored = store_.finish_job(job, instance_, result.is_ok() ? &result.value() : nullptr);
  if (!stored.is_ok() && stored.code() != StatusCode::kAborted && result.is_ok()) {
    // The result could not be stored (over the store's size limit, a full
    // disk): the job fails saying so, a small write without the result,
    // rather than running again once its lease expires, and failing again.
    spdlog::warn("job result not stored id={} bytes={} error=\"{}\"", job.id, result.value().size(), stored.message());
    job.state = JobState::kFailed;
    job.error_code = static_cast<int>(stored.code());
    job.error_message =
        "the result of " + std::to_string(result.value().size()) + " bytes could not be stored: " + stored.message();
    stored = store_.finish_job(job, instance_, nullptr);
  }
  // Counted before watchers here hear of the end, so that what they see
  // next on /metrics includes it.
  if (stored.is_ok() && metrics_ != nullptr) {
    metrics_->job_ended(job.kind, job.state, std::chrono::steady_clock::now() - claimed);
  }
  if (stored.is_ok() && job.state == JobState::kSucceeded) {
    ResultListener listener;
    {
      std::lock_guard lock(mu_);
      listener = result_listener_;
    }
    if (listener) listener(job, result.value());
  }
  {
    std::lock_guard lock(mu_);
    live_.erase(job.id);  // watchers read the end from the store
  }
  notify_changed(job.id);
  if (!stored.is_ok()) {
    // ABORTED: another instance holds it now and writes the end itself.
    // Otherwise the store failed: the lease expires and the job runs again,
    // up to max_job_attempts times.
    spdlog::warn("job end not stored id={} error=\"{}\"", job.id, stored.message());
  } else if (job.state == JobState::kSucceeded) {
    spdlog::info("job succeeded id={}", job.id);
  } else {
    spdlog::info("job ended id={} state={} error=\"{}\"", job.id, job_state_name(job.state), job.error_message);
  }
  if (stored.is_ok()) delete_old_jobs();  // one more ended job: one more past max_tenant_jobs_kept, maybe
}

void JobManager::delete_old_jobs() {
  constexpr std::int64_t kDayMs = 24ll * 3600 * 1000;
  const std::int64_t max_age_ms =
      limits_.max_job_age_days > std::numeric_limits<std::int64_t>::max() / kDayMs ? -1 : limits_.max_job_age_days * kDayMs;
  const std::int64_t finished_before = max_age_ms < 0 ? 0 : now_ms() - max_age_ms;
  Result<int> deleted = store_.delete_ended_jobs(finished_before, limits_.max_tenant_jobs_kept);
  if (!deleted.is_ok()) {
    spdlog::warn("old jobs not deleted error=\"{}\"", deleted.status().message());
  } else if (deleted.value() > 0) {
    spdlog::info("old jobs deleted count={} max_tenant_jobs_kept={} max_job_age_days={}", deleted.value(),
                 limits_.max_tenant_jobs_kept, limits_.max_job_age_days);
  }
  // A deleted text model's revisions go once no job that may still run names them.
  Result<int> purged = store_.purge_unused_models();
  if (!purged.is_ok()) spdlog::warn("deleted models not purged error=\"{}\"", purged.status().message());
  // Request ids (every kind's: jobs, datasets, sessions) answer retries for
  // a week, then go: a retry is seconds or minutes after its first call.
  Result<int> forgotten = store_.delete_request_ids(now_ms() - kRequestIdRetentionMs);
  if (!forgotten.is_ok()) spdlog::warn("old request ids not deleted error=\"{}\"", forgotten.status().message());
}

Status JobManager::remove(const std::string& tenant, const std::string& id) {
  RICCATI_RETURN_IF_ERROR(store_.delete_job(tenant, id));
  spdlog::info("job deleted id={} tenant={}", id, tenant);
  return Status::ok();
}

Result<std::string> JobManager::execute(const JobRecord& job, std::stop_token stop) {
  auto last_publish = std::chrono::steady_clock::now();
  // Where the job stands, in numbers, as the last callback said it: what the
  // throttle held back is published when the run ends, so a finished job
  // shows its last iteration or sample, not the last one published. (The
  // filter's theta is published at every pass's end anyway.)
  struct Counters {
    bool optimizer = false;
    int pass = 0, passes = 0, iteration = 0;
    std::int64_t sample = 0, samples = 0;
    double cost = 0.0;
  };
  std::optional<Counters> held_back;
  auto apply = [](const Counters& c, JobRecord& r) {
    if (c.optimizer) {
      r.iteration = c.iteration;
      r.cost = c.cost;
      return;
    }
    r.pass = c.pass;
    r.passes = c.passes;
    r.sample = c.sample;
    r.samples = c.samples;
  };
  JobExecution run{store_, models_, stop, {}};
  run.progress = [&](const JobProgress& p) {
    const Counters counters{p.optimizer, p.pass, p.passes, p.iteration, p.sample, p.samples, p.cost};
    const auto now = std::chrono::steady_clock::now();
    const bool pass_done = !p.optimizer && p.sample == p.samples;
    // Samples come by the thousand a second; an optimiser's iterations are
    // few (each at least a run over the record), and a fast job would
    // otherwise end before any was told.
    if (!pass_done && !p.optimizer && now - last_publish < kProgressInterval) {
      held_back = counters;
      return;
    }
    held_back.reset();
    last_publish = now;
    // Progress is for watchers here; the store gets it at every lease
    // renewal and at the end of each pass (for watchers elsewhere).
    const auto changed = update(job.id, [&](JobRecord& r) {
      apply(counters, r);
      if (!p.optimizer) r.theta.assign(p.theta.begin(), p.theta.end());
    });
    if (pass_done && changed) renew(*changed);
  };
  // Within a sample too: the integrator polls the job's stop (CancelJob,
  // shutdown) and bounds a sample's steps, where the engine's own checks
  // come between samples and iterations.
  Interrupt interrupt;
  interrupt.poll = [&stop]() -> Status {
    return stop.stop_requested() ? cancelled("the job was stopped during a sample") : Status::ok();
  };
  interrupt.max_steps_per_interval = limits_.max_simulation_steps;
  interrupt.exhausted = [this](std::int64_t taken) {
    return limit_reached("max_simulation_steps", limits_.max_simulation_steps,
                         "the step between two samples took " + std::to_string(taken) +
                             " integration steps (an adaptive integrator's internal steps count each); loosen the "
                             "tolerances, or raise --max-simulation-steps");
  };
  InterruptScope under(interrupt);
  Result<std::string> outcome = execute_job(job, run);
  if (held_back) update(job.id, [&](JobRecord& r) { apply(*held_back, r); });
  return outcome;
}

}  // namespace riccati::service
