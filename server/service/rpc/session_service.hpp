// SessionService: filter sessions through the SessionManager, and their
// measurement streams.
#pragma once

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <condition_variable>
#include <mutex>
#include <set>

#include "riccati/v1/sessions.grpc.pb.h"
#include "service/auth.hpp"
#include "service/limits.hpp"
#include "service/metrics.hpp"
#include "service/sessions/session_manager.hpp"
#include "service/stream_slots.hpp"

namespace riccati::service {

// Stream uses gRPC's callback API (a reactor per stream): no thread is held
// by an idle stream, reading, filtering and writing overlap with at most two
// messages queued between them (back-pressure: a client that does not read
// its responses stops being read, so its memory on the server stays
// bounded), and drain() can end
// every stream at once with UNAVAILABLE when the daemon stops. Its messages
// arrive as bytes and are parsed here (gRPC's raw callback method): a frame
// that is not a StreamRequest ends the stream with INVALID_ARGUMENT naming
// it, where gRPC's own parsing would end it as if the client had finished.
class SessionServiceImpl final
    : public v1::SessionService::WithRawCallbackMethod_Stream<v1::SessionService::Service> {
 public:
  SessionServiceImpl(const Authenticator& auth, SessionManager& sessions, Limits limits, Metrics& metrics,
                     StreamSlots& slots)
      : auth_(auth), sessions_(sessions), limits_(limits), metrics_(metrics), slots_(slots) {}
  ~SessionServiceImpl() override;
  grpc::Status CreateSession(grpc::ServerContext*, const v1::CreateSessionRequest*, v1::SessionInfo*) override;
  grpc::Status GetSession(grpc::ServerContext*, const v1::GetSessionRequest*, v1::SessionInfo*) override;
  grpc::Status ListSessions(grpc::ServerContext*, const v1::ListSessionsRequest*, v1::ListSessionsResponse*) override;
  grpc::Status CloseSession(grpc::ServerContext*, const v1::CloseSessionRequest*, v1::CloseSessionResponse*) override;
  grpc::Status RetuneSession(grpc::ServerContext*, const v1::RetuneSessionRequest*, v1::SessionInfo*) override;
  grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* Stream(grpc::CallbackServerContext*) override;

  // Ends every open stream with UNAVAILABLE and refuses new ones; returns
  // once all have ended or `deadline` has passed.
  void drain(std::chrono::steady_clock::time_point deadline);

 private:
  class StreamReactor;
  const Authenticator& auth_;
  SessionManager& sessions_;
  const Limits limits_;
  Metrics& metrics_;
  StreamSlots& slots_;
  std::mutex streams_mu_;
  std::condition_variable streams_done_;
  std::set<StreamReactor*> streams_;  // open streams, for drain()
  bool draining_ = false;
};

// Retunes a session of the tenant and stores its snapshot (RetuneSession).
Result<v1::SessionInfo> retune_session(SessionManager& sessions, const std::string& tenant,
                                       const v1::RetuneSessionRequest& request);

}  // namespace riccati::service
