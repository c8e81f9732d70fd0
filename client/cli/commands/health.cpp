#include <cstdio>

#include "commands/commands.hpp"

namespace riccati::cli {

int health(Client& c, const std::string& service) {
  using grpc::health::v1::HealthCheckResponse;
  auto ctx = c.context();
  grpc::health::v1::HealthCheckRequest request;
  request.set_service(service);
  HealthCheckResponse response;
  const grpc::Status s = c.health->Check(ctx.get(), request, &response);
  const std::string what = service.empty() ? "health" : "health of service \"" + service + "\"";
  std::string status;
  int code = kExitOk;
  if (s.ok()) {
    status = HealthCheckResponse::ServingStatus_Name(response.status());
    if (response.status() != HealthCheckResponse::SERVING) code = kExitFailed;
  } else if (s.error_code() == grpc::StatusCode::NOT_FOUND) {
    // Check answers NOT_FOUND for a service it does not know (Watch would
    // send SERVICE_UNKNOWN): print it as Watch would.
    status = HealthCheckResponse::ServingStatus_Name(HealthCheckResponse::SERVICE_UNKNOWN);
    code = kExitNotFound;
  } else {
    return c.fail(what, s);
  }
  if (c.json) {
    std::printf("{\n  \"service\": \"%s\",\n  \"status\": \"%s\"\n}\n", service.c_str(), status.c_str());
  } else {
    std::printf("%s\n", status.c_str());
  }
  if (code != kExitOk) std::fprintf(stderr, "riccati: %s: %s\n", what.c_str(), status.c_str());
  return code;
}

}  // namespace riccati::cli
