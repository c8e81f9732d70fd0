#include "service/rpc/session_service.hpp"

#include <spdlog/spdlog.h>

#include <atomic>
#include <optional>

#include "service/convert.hpp"

namespace riccati::service {

grpc::Status SessionServiceImpl::CreateSession(grpc::ServerContext* context, const v1::CreateSessionRequest* request,
                                               v1::SessionInfo* response) {
  auto session = sessions_.create(auth_.tenant(*context), *request);
  if (!session.is_ok()) return to_grpc(session.status());
  *response = session.value()->info();
  response->set_instance(sessions_.instance_id());  // it serves the session: it created or resumed it
  return grpc::Status::OK;
}

grpc::Status SessionServiceImpl::GetSession(grpc::ServerContext* context, const v1::GetSessionRequest* request,
                                            v1::SessionInfo* response) {
  auto session = sessions_.get(auth_.tenant(*context), request->id());
  if (!session.is_ok()) return to_grpc(session.status());
  *response = session.value()->info();
  response->set_instance(sessions_.instance_id());  // it serves the session: it created or resumed it
  return grpc::Status::OK;
}

grpc::Status SessionServiceImpl::ListSessions(grpc::ServerContext* context, const v1::ListSessionsRequest*,
                                              v1::ListSessionsResponse* response) {
  Result<std::vector<v1::SessionInfo>> listed = sessions_.list(auth_.tenant(*context));
  if (!listed.is_ok()) return to_grpc(listed.status());
  for (v1::SessionInfo& info : listed.value()) *response->add_sessions() = std::move(info);
  return grpc::Status::OK;
}

Result<v1::SessionInfo> retune_session(SessionManager& sessions, const std::string& tenant,
                                       const v1::RetuneSessionRequest& request) {
  RICCATI_ASSIGN_OR_RETURN(const std::shared_ptr<Session> session, sessions.get(tenant, request.id()));
  RICCATI_RETURN_IF_ERROR(session->retune(request));
  sessions.save(*session);  // the new weights outlive this instance
  return session->info();
}

grpc::Status SessionServiceImpl::RetuneSession(grpc::ServerContext* context, const v1::RetuneSessionRequest* request,
                                               v1::SessionInfo* response) {
  auto info = retune_session(sessions_, auth_.tenant(*context), *request);
  if (!info.is_ok()) return to_grpc(info.status());
  *response = std::move(info.value());
  return grpc::Status::OK;
}

namespace {

// Result `index` of the previous response, emptied for a new measurement,
// or a new one. Response.Clear() would free each result's estimate (a oneof
// member) and its seven arrays, to allocate them again for the next batch;
// emptied in place they keep their room, so a steady stream does not
// allocate per measurement.
v1::MeasurementResult* reused_result(v1::StreamResponse& response, int index) {
  if (index >= response.results_size()) return response.add_results();
  v1::MeasurementResult* result = response.mutable_results(index);
  if (result->has_estimate()) {
    result->mutable_estimate()->Clear();
  } else {
    result->clear_outcome();
  }
  return result;
}

}  // namespace

class SessionServiceImpl::StreamReactor final : public grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer> {
 public:
  StreamReactor(SessionServiceImpl& service, grpc::CallbackServerContext* context)
      : service_(service), tenant_(service.auth_.tenant(*context)) {
    Result<StreamSlot> slot = service_.slots_.acquire(tenant_, "stream");
    if (!slot.is_ok()) {
      finish(to_grpc(slot.status()));
      return;
    }
    slot_ = std::move(slot.value());
    {
      std::lock_guard lock(service_.streams_mu_);
      if (!service_.draining_) service_.streams_.insert(this);
      registered_ = !service_.draining_;
    }
    spdlog::debug("stream opened registered={}", registered_);
    if (!registered_) {
      finish({grpc::StatusCode::UNAVAILABLE,
              "riccatid is shutting down; open the stream again on another instance, or on this one after it "
              "restarts"});
      return;
    }
    StartRead(&received_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) return finish(grpc::Status::OK);  // the client is done sending (or gone)
    ++messages_;
    if (!grpc::SerializationTraits<v1::StreamRequest>::Deserialize(&received_, &request_).ok()) {
      return finish(to_grpc(invalid_argument("message " + std::to_string(messages_) +
                                             " of the stream is not a StreamRequest (its bytes do not parse): "
                                             "the stream ends here")));
    }
    if (session_ == nullptr) return open();
    if (!request_.has_batch()) return finish(to_grpc(invalid_argument("after StreamOpen, only measurement batches")));
    const auto& measurements = request_.batch().measurements();
    if (measurements.size() > service_.limits_.max_batch) {
      return finish(to_grpc(limit_reached("max_batch", service_.limits_.max_batch,
                                          "a message holds " + std::to_string(measurements.size()) + " measurements")));
    }
    int answered = 0;
    auto began = std::chrono::steady_clock::now();
    for (const auto& m : measurements) {
      // A batch is thousands of steps: it stops between two once the call
      // is cancelled (deadline, client gone) or riccatid is shutting down.
      // The measurements left are not answered; the session keeps its time.
      if (stopping_.load(std::memory_order_relaxed)) break;
      // One result per measurement, even past a divergence: those after it
      // get the divergence as their error, and the stream ends once this
      // response is written.
      v1::MeasurementResult* result = reused_result(response_, answered++);
      diverged_ = session_->process(m, full_covariance_, result);
      const auto done = std::chrono::steady_clock::now();  // one clock read a step: its end is the next one's start
      service_.metrics_.measurement(result->has_estimate(), done - began);
      began = done;
    }
    while (response_.results_size() > answered) response_.mutable_results()->RemoveLast();  // kept for reuse
    service_.sessions_.after_batch(*session_);  // hands a snapshot to the writer when one is due
    bool own_buffer = false;
    sent_.Clear();  // the last response's bytes, written by now: serializing asks for an empty buffer
    const grpc::Status serialized =
        grpc::SerializationTraits<v1::StreamResponse>::Serialize(response_, &sent_, &own_buffer);
    if (!serialized.ok()) return finish(serialized);
    std::lock_guard lock(mu_);
    if (finished_) return;  // drained meanwhile: the status is on its way
    writing_ = true;
    StartWrite(&sent_);
  }

  void OnWriteDone(bool ok) override {
    std::optional<grpc::Status> pending;
    {
      std::lock_guard lock(mu_);
      writing_ = false;
      pending.swap(pending_finish_);
    }
    if (pending) return finish(*pending);
    if (!ok) return finish(grpc::Status::OK);  // the client went away
    if (!diverged_.is_ok()) return finish(to_grpc(diverged_));
    StartRead(&received_);
  }

  void OnCancel() override {
    stopping_ = true;
    finish({grpc::StatusCode::CANCELLED, "stream cancelled"});
  }

  void OnDone() override {
    spdlog::debug("stream done session={}", session_ != nullptr ? session_->id() : "");
    if (registered_) {
      std::lock_guard lock(service_.streams_mu_);
      service_.streams_.erase(this);
      service_.streams_done_.notify_all();
    }
    delete this;
  }

  // CloseSession of the session this stream is attached to.
  void end_if_on(const std::string& session_id) {
    {
      std::lock_guard lock(mu_);
      if (session_ == nullptr || session_->id() != session_id) return;
    }
    stopping_ = true;
    finish({grpc::StatusCode::FAILED_PRECONDITION,
            "session " + session_id + " was closed (CloseSession): its stream ends; create a new session"});
  }

  void drain() {
    stopping_ = true;
    finish({grpc::StatusCode::UNAVAILABLE,
            "riccatid is shutting down; the session is stored: open the stream again, on this or another instance "
            "(GetSession gives its time t: send the measurements after t)"});
  }

 private:
  void open() {
    if (!request_.has_open()) return finish(to_grpc(invalid_argument("the first message of a stream must be StreamOpen")));
    full_covariance_ = request_.open().full_covariance();
    auto found = service_.sessions_.get(tenant_, request_.open().session_id());
    if (!found.is_ok()) return finish(to_grpc(found.status()));
    const Status attached = found.value()->attach();
    if (!attached.is_ok()) return finish(to_grpc(attached));
    {
      std::lock_guard lock(mu_);
      if (finished_) {  // drained meanwhile
        found.value()->detach();
        return;
      }
      session_ = found.value();
    }
    StartRead(&received_);
  }

  // Finishes once; while a write is in flight, when it completes.
  void finish(const grpc::Status& status) {
    std::lock_guard lock(mu_);
    if (finished_) return;
    if (writing_) {
      if (!pending_finish_) pending_finish_ = status;
      return;
    }
    finished_ = true;
    // Detached (and its snapshot handed to the writer) before the client
    // hears the status, so that a client that reconnects at once finds the
    // session free.
    if (session_ != nullptr) {
      session_->detach();
      service_.sessions_.save(*session_);
    }
    slot_ = StreamSlot();
    service_.metrics_.rpc_finished(Metrics::kSessionStreamMethod, status.error_code());  // no interceptor counts it
    Finish(status);
  }

  SessionServiceImpl& service_;
  const std::string tenant_;
  StreamSlot slot_;
  bool registered_ = false;
  std::shared_ptr<Session> session_;
  bool full_covariance_ = false;
  grpc::ByteBuffer received_, sent_;  // the messages as bytes (parsed and written here)
  int messages_ = 0;                  // received so far, for the error that names one
  v1::StreamRequest request_;
  v1::StreamResponse response_;
  Status diverged_;
  std::mutex mu_;  // finish() may come from drain() on another thread
  bool writing_ = false;
  bool finished_ = false;
  std::atomic<bool> stopping_{false};  // set from other threads: OnCancel, drain()
  std::optional<grpc::Status> pending_finish_;
};

grpc::Status SessionServiceImpl::CloseSession(grpc::ServerContext* context, const v1::CloseSessionRequest* request,
                                              v1::CloseSessionResponse*) {
  const Status closed = sessions_.close(auth_.tenant(*context), request->id());
  if (closed.is_ok()) {
    // A stream attached to it ends now, not at its next batch.
    std::lock_guard lock(streams_mu_);
    for (StreamReactor* stream : streams_) stream->end_if_on(request->id());
  }
  return to_grpc(closed);
}

grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* SessionServiceImpl::Stream(
    grpc::CallbackServerContext* context) {
  return new StreamReactor(*this, context);
}

void SessionServiceImpl::drain(std::chrono::steady_clock::time_point deadline) {
  std::unique_lock lock(streams_mu_);
  draining_ = true;
  // Finish() never runs OnDone on this thread (gRPC completes it on its
  // own), so holding streams_mu_ here cannot deadlock with OnDone.
  for (StreamReactor* stream : streams_) stream->drain();
  streams_done_.wait_until(lock, deadline, [&] { return streams_.empty(); });
  spdlog::info("streams drained open={}", streams_.size());
}

SessionServiceImpl::~SessionServiceImpl() = default;

}  // namespace riccati::service
