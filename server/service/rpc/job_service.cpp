#include "service/rpc/job_service.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <optional>
#include <utility>
#include <vector>

#include "service/convert.hpp"
#include "service/jobs/job_compare.hpp"
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

// A watch's state is guarded by the service's watches_mu_. The pump takes a
// watch for a poll (polling) or a write is in flight (writing); meanwhile
// nothing finishes it (a finish waits in pending_finish), so it is never
// deleted under the pump.
class JobServiceImpl::WatchReactor final : public grpc::ServerWriteReactor<v1::Job> {
 public:
  WatchReactor(JobServiceImpl& service, std::string tenant, std::string id)
      : service_(service), tenant_(std::move(tenant)), id_(std::move(id)) {
    Result<StreamSlot> slot = service_.slots_.acquire(tenant_, "watch of job " + id_);
    std::lock_guard lock(service_.watches_mu_);
    if (!slot.is_ok()) {
      finish(to_grpc(slot.status()));
      return;
    }
    slot_ = std::move(slot.value());
    if (service_.draining_) {
      drain();
      return;
    }
    service_.watches_.insert(this);
    registered_ = true;
    service_.pump_wake_ = true;
    service_.watches_changed_.notify_all();
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard lock(service_.watches_mu_);
    writing_ = false;
    if (settle()) return;
    if (!ok) return finish({grpc::StatusCode::CANCELLED, "client went away"});
    if (wrote_end_) return finish(grpc::Status::OK);
    // The job may have changed while the write was in flight.
    recheck_ = true;
    service_.pump_wake_ = true;
    service_.watches_changed_.notify_all();
  }

  void OnCancel() override {
    std::lock_guard lock(service_.watches_mu_);
    finish({grpc::StatusCode::CANCELLED, "watch cancelled by the client"});
  }

  void OnDone() override {
    {
      std::lock_guard lock(service_.watches_mu_);
      if (registered_) service_.watches_.erase(this);
      service_.watches_changed_.notify_all();
    }
    delete this;
  }

  // The pump's side, with watches_mu_ held unless said otherwise.
  // Whether to poll it now: it is new or a write ended, its job changed
  // here (`changed`: the ids, "" for all), or the store is due.
  bool due(const std::set<std::string>& changed, std::chrono::steady_clock::time_point now) const {
    if (finished_ || writing_ || polling_) return false;
    return recheck_ || changed.count(id_) > 0 || changed.count("") > 0 || now >= next_store_read_;
  }
  void begin_poll() {
    polling_ = true;
    recheck_ = false;
  }
  // Without the lock: only the pump touches version_ and running_here_
  // while polling_ is set.
  Result<std::optional<JobRecord>> poll(JobManager& jobs) {
    return jobs.poll(tenant_, id_, &version_, &running_here_);
  }
  void end_poll(const Result<std::optional<JobRecord>>& polled, std::chrono::steady_clock::time_point now) {
    polling_ = false;
    if (settle()) return;
    if (!polled.is_ok()) {
      spdlog::debug("watch ended job={} status=\"{}\"", id_, polled.status().to_string());
      return finish(to_grpc(polled.status()));
    }
    // Changes here come through the listener; elsewhere, through the store.
    next_store_read_ = now + kStorePoll;
    if (!polled->has_value()) return;
    message_ = to_proto(**polled);
    wrote_end_ = is_terminal((*polled)->state);
    writing_ = true;
    StartWrite(&message_);
  }
  void drain() {
    finish({grpc::StatusCode::UNAVAILABLE, "riccatid is shutting down; the job goes on after it restarts: watch again"});
  }

 private:
  // Finishes once; while the pump polls or a write is in flight, after it.
  void finish(const grpc::Status& status) {
    if (finished_) return;
    if (writing_ || polling_) {
      if (!pending_finish_) pending_finish_ = status;
      return;
    }
    finished_ = true;
    slot_ = StreamSlot();  // free before the client hears the status
    Finish(status);
  }
  // Finishes with the status that waited for the poll or write; whether it did.
  bool settle() {
    if (!pending_finish_) return false;
    finish(*std::exchange(pending_finish_, std::nullopt));
    return true;
  }

  JobServiceImpl& service_;
  const std::string tenant_;
  const std::string id_;
  StreamSlot slot_;
  bool registered_ = false;
  std::uint64_t version_ = 0;  // 0: the first poll returns the job as it is
  bool running_here_ = false;
  bool recheck_ = true;  // poll at the next round (opened, or a write ended)
  std::chrono::steady_clock::time_point next_store_read_{};
  bool polling_ = false;
  bool writing_ = false;
  bool wrote_end_ = false;
  bool finished_ = false;
  std::optional<grpc::Status> pending_finish_;
  v1::Job message_;
};

JobServiceImpl::JobServiceImpl(const Authenticator& auth, JobManager& jobs, StreamSlots& slots)
    : auth_(auth), jobs_(jobs), slots_(slots) {
  jobs_.set_change_listener([this](const std::string& id) {
    std::lock_guard lock(watches_mu_);
    if (watches_.empty()) return;
    changed_jobs_.insert(id);
    pump_wake_ = true;
    watches_changed_.notify_all();
  });
  pump_ = std::thread([this] { pump(); });
}

JobServiceImpl::~JobServiceImpl() {
  jobs_.set_change_listener(nullptr);
  {
    std::lock_guard lock(watches_mu_);
    stop_pump_ = true;
  }
  watches_changed_.notify_all();
  pump_.join();
}

grpc::ServerWriteReactor<v1::Job>* JobServiceImpl::WatchJob(grpc::CallbackServerContext* context,
                                                            const v1::WatchJobRequest* request) {
  return new WatchReactor(*this, auth_.tenant(*context), request->id());
}

void JobServiceImpl::pump() {
  std::unique_lock lock(watches_mu_);
  for (;;) {
    // Watches of jobs not running here read the store every kStorePoll.
    watches_changed_.wait_for(lock, watches_.empty() ? std::chrono::milliseconds(60'000) : kStorePoll,
                              [&] { return stop_pump_ || pump_wake_; });
    if (stop_pump_) return;
    pump_wake_ = false;
    const std::set<std::string> changed = std::exchange(changed_jobs_, {});
    const auto now = std::chrono::steady_clock::now();
    std::vector<WatchReactor*> due;
    for (WatchReactor* watch : watches_) {
      if (watch->due(changed, now)) {
        watch->begin_poll();
        due.push_back(watch);
      }
    }
    if (due.empty()) continue;
    lock.unlock();
    std::vector<Result<std::optional<JobRecord>>> polled;
    polled.reserve(due.size());
    for (WatchReactor* watch : due) polled.push_back(watch->poll(jobs_));
    lock.lock();
    const auto polled_at = std::chrono::steady_clock::now();
    for (std::size_t i = 0; i < due.size(); ++i) due[i]->end_poll(polled[i], polled_at);
  }
}

void JobServiceImpl::drain(std::chrono::steady_clock::time_point deadline) {
  std::unique_lock lock(watches_mu_);
  draining_ = true;
  for (WatchReactor* watch : watches_) watch->drain();
  watches_changed_.wait_until(lock, deadline, [&] { return watches_.empty(); });
  spdlog::info("watches drained open={}", watches_.size());
}

grpc::Status JobServiceImpl::GetJob(grpc::ServerContext* context, const v1::GetJobRequest* request,
                                    v1::Job* response) {
  auto job = jobs_.get(auth_.tenant(*context), request->id());
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

namespace {

const std::string& model_of(const v1::Job& job) {
  return job.has_smoothing() ? job.smoothing().model()
         : job.has_validation() ? job.validation().model()
                                : job.identification().model();
}

// ListJobsRequest's filters: the states asked for, and the model by name
// (any revision) or by name@revision.
bool listed(const v1::Job& job, const v1::ListJobsRequest& request) {
  if (!request.states().empty() &&
      std::find(request.states().begin(), request.states().end(), job.state()) == request.states().end()) {
    return false;
  }
  if (request.model().empty()) return true;
  const std::string& model = model_of(job);
  return model == request.model() ||
         (model.size() > request.model().size() && model.compare(0, request.model().size(), request.model()) == 0 &&
          model[request.model().size()] == '@');
}

}  // namespace

grpc::Status JobServiceImpl::ListJobs(grpc::ServerContext* context, const v1::ListJobsRequest* request,
                                      v1::ListJobsResponse* response) {
  auto jobs = jobs_.list(auth_.tenant(*context));
  if (!jobs.is_ok()) return to_grpc(jobs.status());
  // The page token is the id of the previous page's last job (oldest first).
  auto from = jobs.value().begin();
  if (!request->page_token().empty()) {
    from = std::find_if(jobs.value().begin(), jobs.value().end(),
                        [&](const JobRecord& job) { return job.id == request->page_token(); });
    if (from == jobs.value().end()) {
      return {grpc::StatusCode::INVALID_ARGUMENT,
              "page_token \"" + request->page_token() +
                  "\" is not a page token of ListJobs (or its job was deleted since): list from the start"};
    }
    ++from;
  }
  for (auto it = from; it != jobs.value().end(); ++it) {
    v1::Job job = to_proto(*it);
    if (!listed(job, *request)) continue;
    if (request->page_size() > 0 && static_cast<uint32_t>(response->jobs_size()) == request->page_size()) {
      response->set_next_page_token(response->jobs(response->jobs_size() - 1).id());
      break;
    }
    *response->add_jobs() = std::move(job);
  }
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::CancelJob(grpc::ServerContext* context, const v1::CancelJobRequest* request,
                                       v1::Job* response) {
  auto job = jobs_.cancel(auth_.tenant(*context), request->id());
  if (!job.is_ok()) return to_grpc(job.status());
  *response = to_proto(job.value());
  return grpc::Status::OK;
}

Result<ReadJobResult> job_result(JobManager& jobs, const std::string& tenant, const std::string& job_id) {
  RICCATI_ASSIGN_OR_RETURN(JobManager::StoredResult stored, jobs.result(tenant, job_id));
  ReadJobResult out;
  out.read = std::move(stored.read);
  if (!out.result.ParseFromString(stored.encoded)) {
    return internal_error("stored result of job " + job_id + " is unreadable");
  }
  return out;
}

grpc::Status JobServiceImpl::GetResult(grpc::ServerContext* context, const v1::GetResultRequest* request,
                                       v1::JobResult* response) {
  Result<ReadJobResult> read = job_result(jobs_, auth_.tenant(*context), request->job_id());
  if (!read.is_ok()) return to_grpc(read.status());
  // Swapped, not copied: the message is the result's largest copy.
  response->Swap(&read.value().result);
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::CompareJobs(grpc::ServerContext* context, const v1::CompareJobsRequest* request,
                                         v1::CompareJobsResponse* response) {
  Result<v1::CompareJobsResponse> compared = compare_jobs(jobs_, auth_.tenant(*context), *request);
  if (!compared.is_ok()) return to_grpc(compared.status());
  response->Swap(&compared.value());
  return grpc::Status::OK;
}

grpc::Status JobServiceImpl::DeleteJob(grpc::ServerContext* context, const v1::DeleteJobRequest* request,
                                       v1::DeleteJobResponse*) {
  return to_grpc(jobs_.remove(auth_.tenant(*context), request->id()));
}

}  // namespace riccati::service
