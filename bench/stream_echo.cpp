// stream_echo: a bare gRPC SessionService that answers every measurement with
// a copy of a stored estimate, computing nothing: the baseline stream_bench
// runs beside riccatid, as a process of its own like riccatid.
//
//   stream_echo --listen 127.0.0.1:0 --port-file PORT --estimates-dir DIR
//
// CreateSession of model M answers the session id M; a stream opened on it
// answers each measurement with DIR/M.estimate (a serialized riccati.v1.
// Estimate, written by stream_bench from riccatid's first answer), its time
// set to the measurement's, so both servers move the same bytes.
#include <CLI/CLI.hpp>
#include <absl/synchronization/mutex.h>
#include <grpcpp/grpcpp.h>

#include <cstdio>
#include <fstream>
#include <map>
#include <mutex>
#include <string>

#include "riccati/v1/sessions.grpc.pb.h"

namespace {

using namespace riccati;

// One message in flight, as riccatid's own stream: a response is written
// before the next request is read.
class EchoStream final : public grpc::ServerBidiReactor<v1::StreamRequest, v1::StreamResponse> {
 public:
  explicit EchoStream(std::function<const v1::Estimate*(const std::string&)> find) : find_(std::move(find)) {
    StartRead(&request_);
  }
  void OnReadDone(bool ok) override {
    if (!ok) return Finish(grpc::Status::OK);
    if (request_.has_open()) {
      estimate_ = find_(request_.open().session_id());
      if (estimate_ == nullptr) return Finish({grpc::StatusCode::NOT_FOUND, "no session " + request_.open().session_id()});
      return StartRead(&request_);
    }
    if (estimate_ == nullptr) return Finish({grpc::StatusCode::INVALID_ARGUMENT, "StreamOpen first"});
    // The results of the previous response are reused, as riccatid reuses
    // its own (Clear() would free every estimate and allocate it again).
    int answered = 0;
    for (const auto& m : request_.batch().measurements()) {
      auto* r = answered < response_.results_size() ? response_.mutable_results(answered) : response_.add_results();
      ++answered;
      r->set_sequence(sequence_++);
      *r->mutable_estimate() = *estimate_;  // copies into the estimate already there
      r->mutable_estimate()->set_t(m.t());
    }
    while (response_.results_size() > answered) response_.mutable_results()->RemoveLast();
    StartWrite(&response_);
  }
  void OnWriteDone(bool ok) override {
    if (!ok) return Finish(grpc::Status::OK);
    StartRead(&request_);
  }
  void OnDone() override { delete this; }

 private:
  std::function<const v1::Estimate*(const std::string&)> find_;
  const v1::Estimate* estimate_ = nullptr;
  v1::StreamRequest request_;
  v1::StreamResponse response_;
  std::uint64_t sequence_ = 0;
};

class EchoSessions final : public v1::SessionService::CallbackService {
 public:
  explicit EchoSessions(std::string dir) : dir_(std::move(dir)) {}

  grpc::ServerUnaryReactor* CreateSession(grpc::CallbackServerContext* context, const v1::CreateSessionRequest* request,
                                          v1::SessionInfo* info) override {
    auto* reactor = context->DefaultReactor();
    const std::string path = dir_ + "/" + request->model() + ".estimate";
    std::ifstream in(path, std::ios::binary);
    v1::Estimate estimate;
    if (!in || !estimate.ParseFromIstream(&in)) {
      reactor->Finish({grpc::StatusCode::NOT_FOUND, "stream_echo: cannot read " + path});
      return reactor;
    }
    {
      std::lock_guard lock(mu_);
      estimates_[request->model()] = std::move(estimate);  // never erased: streams keep pointers to them
    }
    info->set_id(request->model());
    reactor->Finish(grpc::Status::OK);
    return reactor;
  }
  grpc::ServerUnaryReactor* CloseSession(grpc::CallbackServerContext* context, const v1::CloseSessionRequest*,
                                         v1::CloseSessionResponse*) override {
    auto* reactor = context->DefaultReactor();
    reactor->Finish(grpc::Status::OK);
    return reactor;
  }
  grpc::ServerBidiReactor<v1::StreamRequest, v1::StreamResponse>* Stream(grpc::CallbackServerContext*) override {
    return new EchoStream([this](const std::string& id) -> const v1::Estimate* {
      std::lock_guard lock(mu_);
      auto it = estimates_.find(id);
      return it == estimates_.end() ? nullptr : &it->second;
    });
  }

 private:
  const std::string dir_;
  std::mutex mu_;
  std::map<std::string, v1::Estimate> estimates_;  // by model; a map's elements stay where they are
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"stream_echo: a SessionService that echoes a stored estimate (stream_bench's baseline)"};
  std::string listen = "127.0.0.1:0", port_file, estimates_dir;
  app.add_option("--listen", listen, "Address to listen on (port 0: any free)");
  app.add_option("--port-file", port_file, "Write the bound port here once listening")->required();
  app.add_option("--estimates-dir", estimates_dir, "Directory of <model>.estimate files")->required();
  CLI11_PARSE(app, argc, argv);
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);  // as riccatid does: Debian's Abseil has its debug checks on

  EchoSessions service(estimates_dir);
  int port = 0;
  grpc::ServerBuilder builder;
  builder.AddListeningPort(listen, grpc::InsecureServerCredentials(), &port);
  builder.RegisterService(&service);
  auto server = builder.BuildAndStart();
  if (server == nullptr || port == 0) {
    std::fprintf(stderr, "stream_echo: cannot listen on %s\n", listen.c_str());
    return 1;
  }
  {
    std::ofstream out(port_file + ".tmp");
    out << port << "\n";
  }
  std::rename((port_file + ".tmp").c_str(), port_file.c_str());
  server->Wait();  // until SIGTERM ends the process
  return 0;
}
