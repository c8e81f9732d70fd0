#include "service/rpc/session_service.hpp"

#include <spdlog/spdlog.h>

#include <array>
#include <atomic>
#include <memory>
#include <optional>

#include "service/convert.hpp"
#include "service/rpc/message_arena.hpp"

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

// A stream is a pipeline of three stages that overlap: gRPC reads the next
// message while one thread filters the last, and writes the response before
// it. With measurements batched, each stage waiting for the one before it
// left the filter idle a third of the time (a read's and a write's wake-ups
// per batch); a stream of single measurements still goes one message at a
// time, which answers each soonest (kReadAheadBytes). The stages hand
// messages over in two small rings, so what a stream holds stays bounded: a
// client that does not read its responses fills the outbox, the filter
// stops, the inbox fills, and reads stop (back-pressure). mu_ guards the
// stage flags and the rings' counts; the messages themselves are touched
// outside it by the one stage that owns them at the time (only one thread
// filters at a time: `processing_`).
class SessionServiceImpl::StreamReactor final : public grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer> {
 public:
  StreamReactor(SessionServiceImpl& service, grpc::CallbackServerContext* context)
      : service_(service), tenant_(service.auth_.tenant(*context)) {
    Result<StreamSlot> slot = service_.slots_.acquire(tenant_, "stream");
    if (!slot.is_ok()) {
      end(to_grpc(slot.status()));
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
      end({grpc::StatusCode::UNAVAILABLE,
           "riccatid is shutting down; open the stream again on another instance, or on this one after it restarts"});
      return;
    }
    pump();
  }

  void OnReadDone(bool ok) override {
    {
      std::lock_guard lock(mu_);
      reading_ = false;
      if (ok) {
        inbox_.push().Swap(&received_);
      } else {
        client_done_ = true;  // the client is done sending (or gone): finish once all it sent is answered
      }
    }
    pump();
  }

  void OnWriteDone(bool ok) override {
    {
      std::lock_guard lock(mu_);
      writing_ = false;
      outbox_.pop();
      if (!ok && !end_) end_ = grpc::Status::OK;  // the client went away
    }
    pump();
  }

  void OnCancel() override { end({grpc::StatusCode::CANCELLED, "stream cancelled"}); }

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
    end({grpc::StatusCode::FAILED_PRECONDITION,
         "session " + session_id + " was closed (CloseSession): its stream ends; create a new session"});
  }

  void drain() {
    end({grpc::StatusCode::UNAVAILABLE,
         "riccatid is shutting down; the session is stored: open the stream again, on this or another instance "
         "(GetSession gives its time t: send the measurements after t)"});
  }

 private:
  // A ring of N message buffers; push() and pop() only move its counts, so
  // that the buffer a stage works on stays where it is.
  template <int N>
  struct Ring {
    std::array<grpc::ByteBuffer, N> slots;
    int head = 0, count = 0;
    bool full() const { return count == N; }
    bool empty() const { return count == 0; }
    grpc::ByteBuffer& front() { return slots[head]; }
    grpc::ByteBuffer& back_free() { return slots[(head + count) % N]; }  // the next push()'s slot
    grpc::ByteBuffer& push() {
      grpc::ByteBuffer& slot = back_free();
      ++count;
      return slot;
    }
    void pop() {
      slots[head].Clear();
      head = (head + 1) % N;
      --count;
    }
  };
  // Messages read and not yet filtered, responses not yet written (the one
  // being written included). Two each: enough to keep the three stages
  // busy, and a bound on what a stream holds.
  static constexpr int kInbox = 2, kOutbox = 2;
  // A message larger than this (about 20 measurements of a small model)
  // takes long enough to filter that reading the next one beside it pays.
  // After a smaller one the next read waits until the stream is idle, as a
  // read beside the write cost streams of one measurement a message latency
  // (400 Hz sessions: p50 +15 %, docs/benchmarks-log.md).
  static constexpr std::size_t kReadAheadBytes = 1024;

  // Ends the stream from outside the pipeline (cancelled, drained, the
  // session closed): the batch being filtered stops at its next step, the
  // write in flight completes, and what is queued is dropped.
  void end(const grpc::Status& status) {
    stopping_ = true;
    {
      std::lock_guard lock(mu_);
      if (!end_) end_ = status;
    }
    pump();
  }

  // Moves the pipeline on, from whichever thread a reaction runs on: finish
  // when there is nothing left to do, write the next response, read the
  // next message while the inbox has room (for small messages only once
  // idle: kReadAheadBytes), and filter the next message while the outbox
  // has room (one thread at a time). Every stage starts outside mu_, as
  // gRPC may run a reaction inline.
  void pump() {
    std::unique_lock lock(mu_);
    while (!finished_) {
      const bool ending = end_ || last_;
      if (!processing_ && !writing_ &&
          (end_ || ((last_ || (client_done_ && inbox_.empty())) && outbox_.empty()))) {
        finish_locked(end_ ? *end_ : last_ ? *last_ : grpc::Status::OK);
        return;
      }
      if (!writing_ && !end_ && !outbox_.empty()) {
        writing_ = true;
        grpc::ByteBuffer* response = &outbox_.front();
        lock.unlock();
        StartWrite(response);
        lock.lock();
        continue;
      }
      const bool idle = !processing_ && !writing_ && inbox_.empty();
      if (!reading_ && !ending && !client_done_ && !inbox_.full() && (read_ahead_ || idle)) {
        reading_ = true;
        lock.unlock();
        StartRead(&received_);
        lock.lock();
        continue;
      }
      if (!processing_ && !ending && !inbox_.empty() && !outbox_.full()) {
        processing_ = true;
        read_ahead_ = inbox_.front().Length() > kReadAheadBytes;
        request_bytes_.Swap(&inbox_.front());
        inbox_.pop();
        // The outbox's free slot is this thread's until it is pushed: only
        // the filtering stage pushes, and only one thread filters.
        grpc::ByteBuffer& response_bytes = outbox_.back_free();
        lock.unlock();
        const Handled handled = handle(request_bytes_, response_bytes);
        lock.lock();
        processing_ = false;
        if (handled.responded) outbox_.push();
        if (handled.last && !last_) last_ = handled.last;
        continue;
      }
      return;
    }
  }

  struct Handled {
    bool responded = false;             // a response is in the outbox's free slot
    std::optional<grpc::Status> last;  // the stream ends with this once its responses are written
  };

  // Filters one message: StreamOpen attaches the session, a batch is
  // answered with one result per measurement.
  Handled handle(grpc::ByteBuffer& bytes, grpc::ByteBuffer& response_bytes) {
    ++messages_;
    struct TrimAfter {
      MessageArena& arena;
      ~TrimAfter() { arena.trim(); }
    } trim_after{arena_};
    v1::StreamRequest& request = arena_.fresh<v1::StreamRequest>();
    const bool parsed = grpc::SerializationTraits<v1::StreamRequest>::Deserialize(&bytes, &request).ok();
    if (!parsed) {
      return {false, to_grpc(invalid_argument("message " + std::to_string(messages_) +
                                              " of the stream is not a StreamRequest (its bytes do not parse): "
                                              "the stream ends here"))};
    }
    if (session_ == nullptr) return {false, open(request)};
    if (!request.has_batch()) return {false, to_grpc(invalid_argument("after StreamOpen, only measurement batches"))};
    const auto& measurements = request.batch().measurements();
    if (measurements.size() > service_.limits_.max_batch) {
      return {false, to_grpc(limit_reached("max_batch", service_.limits_.max_batch,
                                           "a message holds " + std::to_string(measurements.size()) +
                                               " measurements"))};
    }
    // The answer is one message too: bounded before any of it is computed
    // (a full covariance is nz^2 values a measurement).
    const std::int64_t per_result = result_bytes_;
    if (measurements.size() * per_result > service_.limits_.max_message_bytes) {
      const std::int64_t fits = std::max<std::int64_t>(1, service_.limits_.max_message_bytes / per_result);
      return {false, to_grpc(limit_reached(
                         "max_message_bytes", service_.limits_.max_message_bytes,
                         "the answer to " + std::to_string(measurements.size()) + " measurements would take about " +
                             std::to_string(measurements.size() * per_result) + " bytes (" +
                             std::to_string(per_result) + " each" + (full_covariance_ ? ", with the full covariance" : "") +
                             "): send at most " + std::to_string(fits) + " a message" +
                             (full_covariance_ ? ", or open the stream without full_covariance" : "")))};
    }
    int answered = 0;
    Status diverged;
    // Within a measurement too: the integrator polls the stream's end (cancel,
    // deadline, drain, CloseSession) and a sample's steps are bounded; the
    // measurement it stops in is answered with that error and not taken.
    interrupt_.poll = [this]() -> Status {
      if (stopping_.load(std::memory_order_relaxed)) return cancelled("the stream ended during this measurement");
      if (session_->closing()) return cancelled("the session was closed during this measurement");
      return Status::ok();
    };
    interrupt_.max_steps_per_interval = service_.limits_.max_simulation_steps;
    interrupt_.exhausted = [this](std::int64_t taken) {
      return limit_reached("max_simulation_steps", service_.limits_.max_simulation_steps,
                           "the step to this measurement took " + std::to_string(taken) +
                               " integration steps (an adaptive integrator's internal steps count each); the "
                               "measurement is not taken: send closer samples, loosen the tolerances, or raise "
                               "--max-simulation-steps");
    };
    InterruptScope under(interrupt_);
    auto began = std::chrono::steady_clock::now();
    for (const auto& m : measurements) {
      // A batch is thousands of steps: it stops between two once the call
      // is cancelled (deadline, client gone), riccatid is shutting down or
      // the session is being closed. The measurements left are not
      // answered; the session keeps its time.
      if (stopping_.load(std::memory_order_relaxed) || session_->closing()) break;
      // One result per measurement, even past a divergence: those after it
      // get the divergence as their error, and the stream ends once this
      // response is written.
      v1::MeasurementResult* result = reused_result(response_, answered++);
      diverged = session_->process(m, full_covariance_, result);
      const auto done = std::chrono::steady_clock::now();  // one clock read a step: its end is the next one's start
      service_.metrics_.measurement(result->has_estimate(), done - began);
      began = done;
    }
    while (response_.results_size() > answered) response_.mutable_results()->RemoveLast();  // kept for reuse
    service_.sessions_.after_batch(*session_);  // hands a snapshot to the writer when one is due
    bool own_buffer = false;
    response_bytes.Clear();
    const grpc::Status serialized =
        grpc::SerializationTraits<v1::StreamResponse>::Serialize(response_, &response_bytes, &own_buffer);
    if (!serialized.ok()) return {false, serialized};
    Handled handled{true, std::nullopt};
    if (!diverged.is_ok()) handled.last = to_grpc(diverged);
    return handled;
  }

  // The first message: attaches the session it names to this stream.
  std::optional<grpc::Status> open(const v1::StreamRequest& request) {
    if (!request.has_open()) return to_grpc(invalid_argument("the first message of a stream must be StreamOpen"));
    full_covariance_ = request.open().full_covariance();
    auto found = service_.sessions_.get(tenant_, request.open().session_id());
    if (!found.is_ok()) return to_grpc(found.status());
    const Status attached = found.value()->attach();
    if (!attached.is_ok()) return to_grpc(attached);
    // A result's size is fixed by the session's sizes: read once, not per message.
    result_bytes_ = found.value()->result_bytes(full_covariance_);
    std::lock_guard lock(mu_);  // end_if_on() reads it from another thread
    session_ = found.value();
    return std::nullopt;
  }

  // Finishes, once: nothing is being filtered or written by now.
  void finish_locked(const grpc::Status& status) {
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
  std::int64_t result_bytes_ = 0;  // at most one measurement's answer (Session::result_bytes)
  // The filtering stage's own: the message it parses, where it parses it,
  // and the response it fills (all reused, so that a steady stream of
  // batches up to about a hundred measurements does not allocate).
  grpc::ByteBuffer request_bytes_;
  int messages_ = 0;  // received so far, for the error that names one
  MessageArena arena_;
  v1::StreamResponse response_;
  Interrupt interrupt_;  // what the integrations of a batch poll (set per batch; no allocation per measurement)

  std::mutex mu_;
  grpc::ByteBuffer received_;  // the read in flight fills it
  Ring<kInbox> inbox_;
  Ring<kOutbox> outbox_;
  bool reading_ = false, processing_ = false, writing_ = false;
  bool read_ahead_ = false;  // the last message filtered was large: read beside filtering and writing
  bool client_done_ = false;               // the client finished sending
  std::optional<grpc::Status> last_;       // the pipeline's own end (an error, a divergence): after its responses
  std::optional<grpc::Status> end_;        // an end from outside: after the write in flight
  bool finished_ = false;
  std::atomic<bool> stopping_{false};  // read between filter steps
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
