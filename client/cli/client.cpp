#include "client.hpp"

#include <cctype>
#include <chrono>
#include <cstdio>

#include "settings.hpp"

namespace riccati::cli {

int exit_code_for(grpc::StatusCode code) {
  switch (code) {
    case grpc::StatusCode::OK: return kExitOk;
    case grpc::StatusCode::UNAVAILABLE:
    case grpc::StatusCode::DEADLINE_EXCEEDED: return kExitUnreachable;
    case grpc::StatusCode::NOT_FOUND: return kExitNotFound;
    default: return kExitFailed;
  }
}

Client::Client(const Connection& connection, double timeout, bool json_output)
    : timeout_s(timeout), json(json_output), server_(connection.server), token_(connection.token) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(-1);  // results of long identifications are large
  connection.apply(&args);
  channel = grpc::CreateCustomChannel(connection.server, connection.credentials(), args);
  models = v1::ModelService::NewStub(channel);
  datasets = v1::DatasetService::NewStub(channel);
  jobs = v1::JobService::NewStub(channel);
  sessions = v1::SessionService::NewStub(channel);
}

std::unique_ptr<grpc::ClientContext> Client::context() const {
  auto ctx = stream_context();
  ctx->set_deadline(std::chrono::system_clock::now() +
                    std::chrono::milliseconds(static_cast<long long>(timeout_s * 1000)));
  return ctx;
}

std::unique_ptr<grpc::ClientContext> Client::stream_context() const {
  auto ctx = std::make_unique<grpc::ClientContext>();
  if (!token_.empty()) ctx->AddMetadata("authorization", "Bearer " + token_);
  return ctx;
}

std::string unreachable_message(const std::string& server, const grpc::Status& status) {
  const std::string& message = status.error_message();
  if (status.error_code() != grpc::StatusCode::UNAVAILABLE ||
      message.find("ailed to connect") == std::string::npos) {
    return message;
  }
  // gRPC's own words ("failed to connect to all addresses; last error: UNKNOWN:
  // ipv4:127.0.0.1:7531: Failed to connect to remote host: Connection refused"):
  // the cause, after the last colon.
  std::string cause = message.substr(message.rfind(':') + 1);
  cause.erase(0, cause.find_first_not_of(' '));
  if (!cause.empty()) cause[0] = static_cast<char>(std::tolower(static_cast<unsigned char>(cause[0])));
  return "cannot reach riccatid at " + server + " (" + cause + "); is it running?";
}

int Client::fail(const std::string& what, const grpc::Status& status) const {
  const std::string message = unreachable_message(server_, status);
  if (message.rfind("cannot reach riccatid", 0) == 0) {
    std::fprintf(stderr, "riccati: %s\n", message.c_str());
  } else {
    // riccatid names the request's fields; the flags that set them go beside.
    const std::string told = status.error_code() == grpc::StatusCode::INVALID_ARGUMENT ? with_flags(message) : message;
    std::fprintf(stderr, "riccati: %s: %s\n", what.c_str(), told.c_str());
  }
  return exit_code_for(status.error_code());
}

grpc::Status Client::get_model(const std::string& name, v1::ModelInfo* out) const {
  auto ctx = context();
  v1::GetModelRequest request;
  request.set_name(name);
  return models->GetModel(ctx.get(), request, out);
}

}  // namespace riccati::cli
