// The HTTP face of riccatid (--http-listen): the web workbench's static files
// (client/web, embedded in the binary) and a JSON API under /api/v1/ that
// mirrors the gRPC services through the same managers, with the proto
// messages' JSON mapping (protobuf's JSON utilities), so there is one schema
// and one set of checks.
//
//   GET    /healthz                          no token
//   GET    /api/v1/models                    ListModelsResponse (the directory's and the tenant's)
//   POST   /api/v1/models                    CreateModelRequest -> ModelInfo (validate_only: a check, nothing stored)
//   POST   /api/v1/models/reload             ReloadModelsResponse (the models directory read again)
//   GET    /api/v1/models/{name}             ModelInfo
//   DELETE /api/v1/models/{name}             {}
//   GET    /api/v1/datasets                  ListDatasetsResponse
//   POST   /api/v1/datasets?name=&format=csv|mat&time_column=&input_columns=a,b&output_columns=c
//          &true_parameters=A1:10,k1:0.08    the file as the body; DatasetInfo
//   GET    /api/v1/datasets/{id}             DatasetInfo
//   GET    /api/v1/datasets/{id}/data        DatasetData
//   DELETE /api/v1/datasets/{id}             {}
//   GET    /api/v1/jobs                      ListJobsResponse
//   POST   /api/v1/jobs/identification       IdentificationSpec -> Job
//   POST   /api/v1/jobs/validation           ValidationSpec -> Job
//   POST   /api/v1/jobs/smoothing            SmoothingSpec -> Job
//   GET    /api/v1/jobs/{id}                 Job
//   POST   /api/v1/jobs/{id}/cancel          Job
//   DELETE /api/v1/jobs/{id}                 DeleteJobResponse (an ended job and its result)
//   GET    /api/v1/jobs/{id}/result          JobResult
//   GET    /api/v1/jobs/{id}/events          server-sent events: Job, at most 5 a second, until it ends
//   GET    /api/v1/sessions                  ListSessionsResponse
//   POST   /api/v1/sessions                  CreateSessionRequest -> SessionInfo
//   GET    /api/v1/sessions/{id}             SessionInfo
//   DELETE /api/v1/sessions/{id}             {}
//   POST   /api/v1/sessions/{id}/retune      RetuneSessionRequest (id from the path) -> SessionInfo
//   GET    /api/v1/sessions/{id}/events      server-sent events: {"info": SessionInfo, "estimate": Estimate},
//                                            at most 10 a second, while the session lives
//
// Every /api/ call needs "Authorization: Bearer <token>" (401 without a
// valid one, answered on the headers: the body is not read, and the
// connection closes); another tenant's ids are 404 as over gRPC. Checked on
// the headers of every request, with or without tokens (cross-site request
// forgery, DNS rebinding): the Host is the listen address, a loopback name
// or one of http_allowed_hosts (403); a write (POST, PUT, PATCH, DELETE)
// with an Origin is from this server's own origin (403), and its body is
// JSON (application/json; an upload anything but the types a cross-site form
// may send: 415); no chunked bodies (411); a body past its limit is 413
// before it is read. A Range of more than one range is ignored (the whole
// answer, once). The server (hardened_server.hpp) gathers request heads on
// one thread under a deadline, so slow clients cannot hold its workers. Errors are a v1.Error in JSON with the
// HTTP status of their code; malformed JSON is 400 with protobuf's message,
// which names the field; a body over the limits is 413. Transport as gRPC's:
// TLS with the same certificate and key when they are given; plain HTTP on
// a loopback address, or elsewhere only when asked for (http_public, behind a
// proxy that terminates TLS).
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <map>
#include <mutex>
#include <thread>
#include <vector>

#include "engine/models/plugin_loader.hpp"
#include "engine/status.hpp"
#include "service/auth.hpp"
#include "service/datasets/dataset_manager.hpp"
#include "service/http/rendered_results.hpp"
#include "service/jobs/job_manager.hpp"
#include "service/limits.hpp"
#include "service/models/model_catalog.hpp"
#include "service/sessions/session_manager.hpp"
#include "service/stream_slots.hpp"

namespace httplib {
struct Request;
struct Response;
}  // namespace httplib

namespace riccati::service {

class HardenedServer;

struct HttpOptions {
  std::string listen;        // host:port; port 0: any free one
  bool plain_public = false;  // plain HTTP off loopback (http_public)
  // Host names (without port) accepted beside the listen address, its
  // loopback names and IP literals (http_allowed_hosts); "*": any.
  std::vector<std::string> allowed_hosts;
};

class HttpApi {
 public:
  HttpApi(const Authenticator& auth, ModelCatalog& models, DatasetManager& datasets, JobManager& jobs,
          SessionManager& sessions, StreamSlots& stream_slots, Limits limits);
  ~HttpApi();
  HttpApi(const HttpApi&) = delete;
  HttpApi& operator=(const HttpApi&) = delete;

  // Binds and serves on its own threads; returns the bound port.
  // `description` says what was chosen, for the log.
  Result<int> serve(const HttpOptions& options, const SecurityConfig& security, std::string* description);
  // Ends event streams and stops serving.
  void stop();

  // Event streams take a place in StreamSlots, as gRPC's streams do
  // (max_tenant_streams, max_streams: 429 past them); each also holds one
  // of this server's threads while it lasts, so there are at most this many
  // at once (503 past it), leaving threads for the other requests; one
  // tenant at most max_tenant_event_streams of them (429).
  static constexpr int kMaxEventStreams = 32;
  // Results' JSON kept once written (rendered_results.hpp), at most this
  // many bytes in all; written when a job ends here, or at the first GET.
  static constexpr std::size_t kRenderedResultBytes = 64 * 1024 * 1024;

 private:
  class Routes;
  const Authenticator& auth_;
  ModelCatalog& models_;
  DatasetManager& datasets_;
  JobManager& jobs_;
  SessionManager& sessions_;
  StreamSlots& stream_slots_;
  const Limits limits_;
  // Shared with the job manager's result listener, which writes a result's
  // JSON as its job ends (set while serving).
  std::shared_ptr<RenderedResults> rendered_results_ = std::make_shared<RenderedResults>(kRenderedResultBytes);
  std::unique_ptr<Routes> routes_;  // the handlers, which the server calls
  std::unique_ptr<HardenedServer> server_;
  std::thread thread_;
  std::atomic<bool> stopping_{false};
  std::atomic<int> streams_{0};
  std::mutex tenant_streams_mu_;
  std::map<std::string, std::int64_t> tenant_streams_;  // event streams open per tenant
  // What the pre-routing checks accept (serve()).
  std::vector<std::string> allowed_hosts_;  // lower case, without port
  std::vector<std::string> operator_hosts_;  // http_allowed_hosts alone (Origins accepted by name)
  bool any_host_ = false;                   // "*" among them
  bool ip_hosts_ = false;                   // any IP literal (listening off loopback)
  bool tls_ = false;
  std::string listen_;
};

}  // namespace riccati::service
