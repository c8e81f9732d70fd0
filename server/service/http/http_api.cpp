#include "service/http/http_api.hpp"
#include "service/http/json_writer.hpp"

#include <arpa/inet.h>
#include <google/protobuf/util/json_util.h>
#include <httplib.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <chrono>
#include <optional>
#include <string_view>

#include "riccati/settings_schema.hpp"
#include "service/convert.hpp"
#include "service/http/hardened_server.hpp"
#include "service/http/web_assets.hpp"
#include "service/jobs/job_compare.hpp"
#include "service/jobs/job_convert.hpp"
#include "service/metrics.hpp"
#include "service/rpc/dataset_service.hpp"
#include "service/rpc/job_service.hpp"
#include "service/rpc/model_service.hpp"
#include "service/rpc/session_service.hpp"

namespace riccati::service {
namespace {

using httplib::Request;
using httplib::Response;
using Clock = std::chrono::steady_clock;

// What a screen can draw: job progress at most 5 events a second, a
// session's estimate at most 10 (the newest; those between are skipped).
constexpr std::chrono::milliseconds kJobEventInterval{200};
constexpr std::chrono::milliseconds kSessionEventInterval{100};
// A comment line at least this often on a quiet stream, so that a browser
// that went away is noticed (the write fails) and its thread freed.
constexpr std::chrono::milliseconds kHeartbeat{1000};

int http_status(StatusCode code) {
  switch (code) {
    case StatusCode::kOk: return 200;
    case StatusCode::kInvalidArgument:
    case StatusCode::kOutOfRange: return 400;
    case StatusCode::kUnauthenticated: return 401;
    case StatusCode::kPermissionDenied: return 403;
    case StatusCode::kNotFound: return 404;
    case StatusCode::kAlreadyExists:
    case StatusCode::kFailedPrecondition:
    case StatusCode::kAborted:
    case StatusCode::kCancelled: return 409;
    case StatusCode::kResourceExhausted: return 429;
    case StatusCode::kUnavailable: return 503;
    case StatusCode::kDeadlineExceeded: return 504;
    case StatusCode::kInternal: return 500;
  }
  return 500;
}

// Zeros and empty lists printed too (the page need not guess), as
// protobuf's printer with always_print_primitive_fields writes them.
std::string to_json(const google::protobuf::Message& message) { return message_to_json(message); }

// A result's JSON, written and kept for GETs to send; `when` ("job end",
// "first GET") goes to the debug log with the time it took.
std::shared_ptr<const std::string> keep_result_json(RenderedResults& kept, const std::string& tenant,
                                                    const std::string& job_id, const v1::JobResult& result,
                                                    const char* when) {
  const auto began = std::chrono::steady_clock::now();
  auto json = std::make_shared<const std::string>(to_json(result));
  const auto us =
      std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::steady_clock::now() - began).count();
  spdlog::debug("result JSON written job={} bytes={} us={} at=\"{}\"", job_id, json->size(), us, when);
  kept.put(tenant, job_id, json);
  return json;
}

// A result is mostly doubles: 8 bytes each encoded, at most 24 characters
// (with the comma) in JSON.
constexpr std::size_t kJsonBytesPerEncodedByte = 3;

// The JSON is moved into the response: set_content copies its argument, a
// second allocation and copy of a result's megabytes.
void reply_json(Response& res, std::string json) {
  res.status = 200;
  res.body = std::move(json);
  const auto [first, last] = res.headers.equal_range("Content-Type");
  res.headers.erase(first, last);
  res.set_header("Content-Type", "application/json");
}

void reply(Response& res, const google::protobuf::Message& message) { reply_json(res, to_json(message)); }

// JSON that is kept (RenderedResults): sent from where it is, not copied
// into the response; the response holds it while it is written.
void reply_kept_json(Response& res, std::shared_ptr<const std::string> json,
                     std::shared_ptr<const void> hold = nullptr) {
  res.status = 200;
  const std::size_t size = json->size();
  res.set_content_provider(size, "application/json",
                           [json = std::move(json), hold = std::move(hold)](std::size_t offset, std::size_t length,
                                                                            httplib::DataSink& sink) {
                             return sink.write(json->data() + offset, length);
                           });
}

void fail(Response& res, const Status& status, int http = 0) {
  res.status = http != 0 ? http : http_status(status.code());
  if (res.status == 401) res.set_header("WWW-Authenticate", "Bearer");
  res.set_content(to_json(to_error(status)), "application/json");
}

// "text/event-stream": one event.
bool send_event(httplib::DataSink& sink, std::string_view event, const std::string& data) {
  std::string text = "event: ";
  text.append(event).append("\ndata: ").append(data).append("\n\n");
  return sink.write(text.data(), text.size());
}

std::vector<std::string> split_list(const std::string& text) {
  std::vector<std::string> out;
  std::size_t at = 0;
  while (at <= text.size() && !text.empty()) {
    const std::size_t comma = std::min(text.find(',', at), text.size());
    out.push_back(text.substr(at, comma - at));
    at = comma + 1;
  }
  return out;
}

std::string lower(std::string text) {
  std::transform(text.begin(), text.end(), text.begin(), [](unsigned char c) { return std::tolower(c); });
  return text;
}

// A Content-Type's media type, lower case, without its parameters.
std::string media_type(const std::string& content_type) {
  std::string type = lower(content_type.substr(0, content_type.find(';')));
  while (!type.empty() && std::isspace(static_cast<unsigned char>(type.back()))) type.pop_back();
  while (!type.empty() && std::isspace(static_cast<unsigned char>(type.front()))) type.erase(0, 1);
  return type;
}

// What a page of another site may send without asking the server first
// (a CORS "simple" request).
bool cross_site_type(const std::string& type) {
  return type == "text/plain" || type == "application/x-www-form-urlencoded" || type == "multipart/form-data";
}

// One event stream held open: its place in StreamSlots, in the server's
// threads and in its tenant's share of them, while it lives.
struct EventStream {
  EventStream(std::atomic<int>& count, std::function<void()> release, StreamSlot slot)
      : count_(count), release_(std::move(release)), slot_(std::move(slot)) {}
  ~EventStream() {
    --count_;
    release_();
  }
  std::atomic<int>& count_;
  std::function<void()> release_;
  StreamSlot slot_;
  Clock::time_point last_event{};
  Clock::time_point last_write = Clock::now();
  std::uint64_t version = 0;       // job: JobManager::poll's
  std::uint64_t sent_accepted = 0; // session: measurements at the last event
  bool sent_any = false;
};

}  // namespace

class HttpApi::Routes {
 public:
  explicit Routes(HttpApi& api) : api_(api) {}

  void install(httplib::Server& server) {
    server.set_pre_routing_handler([this](const Request& req, Response& res) { return check_headers(req, res); });
    // A client that asks before it sends its body (Expect: 100-continue,
    // curl's way past 1 MB) hears a refusal instead of "go on".
    server.set_expect_100_continue_handler([this](const Request& req, Response& res) {
      return check_headers(req, res) == httplib::Server::HandlerResponse::Handled ? res.status : 100;
    });
    server.Get("/healthz", [](const Request&, Response& res) { res.set_content("ok\n", "text/plain"); });

    // The requests' settings (riccati/settings_schema.hpp): what the
    // workbench makes its forms from. The same for every tenant.
    server.Get("/api/v1/schema", authed([](const std::string&, const Request&, Response& res) {
      static const std::string schema = api::settings_schema_json();
      res.set_content(schema, "application/json");
    }));
    server.Get("/api/v1/models", authed([this](const std::string& tenant, const Request&, Response& res) {
      const auto entries = api_.models_.list(tenant);
      if (!entries.is_ok()) return fail(res, entries.status());
      v1::ListModelsResponse out;
      for (const CatalogEntry& e : entries.value()) *out.add_models() = to_proto(e);
      reply(res, out);
    }));
    server.Post("/api/v1/models", with_body<v1::CreateModelRequest>(
        [this](const std::string& tenant, const v1::CreateModelRequest& request, Response& res) {
          const auto entry = create_model(api_.models_, tenant, request);
          if (!entry.is_ok()) return fail(res, entry.status());
          reply(res, to_proto(entry.value()));
        }));
    server.Post("/api/v1/models/reload", authed([this](const std::string& tenant, const Request& req, Response& res) {
      if (!api_.auth_.is_operator_header(req.get_header_value("Authorization"))) {
        return fail(res, operator_only("ReloadModels"));
      }
      const auto report = api_.models_.reload();
      if (!report.is_ok()) return fail(res, report.status());
      spdlog::info("models reloaded by tenant={}", tenant);
      reply(res, to_proto(report.value()));
    }));
    server.Get(R"(/api/v1/models/([^/]+))", authed([this](const std::string& tenant, const Request& req,
                                                          Response& res) {
      const auto entry = api_.models_.describe(tenant, req.matches[1].str());
      if (!entry.is_ok()) return fail(res, entry.status());
      reply(res, to_proto(entry.value()));
    }));
    server.Delete(R"(/api/v1/models/([^/]+))", authed([this](const std::string& tenant, const Request& req,
                                                             Response& res) {
      const Status removed = api_.models_.remove(tenant, req.matches[1].str());
      if (!removed.is_ok()) return fail(res, removed);
      reply(res, v1::DeleteModelResponse());
    }));

    server.Get("/api/v1/datasets", authed([this](const std::string& tenant, const Request&, Response& res) {
      const auto records = api_.datasets_.list(tenant);
      if (!records.is_ok()) return fail(res, records.status());
      v1::ListDatasetsResponse out;
      for (const auto& r : records.value()) *out.add_datasets() = to_proto(r);
      reply(res, out);
    }));
    server.Post("/api/v1/datasets", [this](const Request& req, Response& res, const httplib::ContentReader& reader) {
      const auto tenant = authenticate(req, res);
      if (tenant) upload(*tenant, req, res, reader);
    });
    server.Get(R"(/api/v1/datasets/([^/]+))", authed([this](const std::string& tenant, const Request& req,
                                                            Response& res) {
      const auto record = api_.datasets_.get(tenant, req.matches[1].str());
      if (!record.is_ok()) return fail(res, record.status());
      reply(res, to_proto(record.value()));
    }));
    server.Get(R"(/api/v1/datasets/([^/]+)/data)", authed([this](const std::string& tenant, const Request& req,
                                                                 Response& res) {
      const auto data = dataset_data(api_.datasets_, tenant, req.matches[1].str());
      if (!data.is_ok()) return fail(res, data.status());
      reply(res, data.value());
    }));
    server.Delete(R"(/api/v1/datasets/([^/]+))", authed([this](const std::string& tenant, const Request& req,
                                                               Response& res) {
      const Status removed = api_.datasets_.remove(tenant, req.matches[1].str());
      if (!removed.is_ok()) return fail(res, removed);
      reply(res, v1::DeleteDatasetResponse());
    }));

    server.Get("/api/v1/jobs", authed([this](const std::string& tenant, const Request&, Response& res) {
      const auto jobs = api_.jobs_.list(tenant);
      if (!jobs.is_ok()) return fail(res, jobs.status());
      v1::ListJobsResponse out;
      for (const JobRecord& job : jobs.value()) *out.add_jobs() = to_proto(job);
      reply(res, out);
    }));
    server.Post("/api/v1/jobs/identification", with_body<v1::IdentificationSpec>(
        [this](const std::string& tenant, const v1::IdentificationSpec& spec, Response& res) {
          reply_job(res, api_.jobs_.submit_identification(tenant, spec));
        }));
    server.Post("/api/v1/jobs/validation", with_body<v1::ValidationSpec>(
        [this](const std::string& tenant, const v1::ValidationSpec& spec, Response& res) {
          reply_job(res, api_.jobs_.submit_validation(tenant, spec));
        }));
    server.Post("/api/v1/jobs/smoothing", with_body<v1::SmoothingSpec>(
        [this](const std::string& tenant, const v1::SmoothingSpec& spec, Response& res) {
          reply_job(res, api_.jobs_.submit_smoothing(tenant, spec));
        }));
    server.Post("/api/v1/jobs/compare", with_body<v1::CompareJobsRequest>(
        [this](const std::string& tenant, const v1::CompareJobsRequest& request, Response& res) {
          const auto compared = compare_jobs(api_.jobs_, tenant, request);
          if (!compared.is_ok()) return fail(res, compared.status());
          reply(res, compared.value());
        }));
    server.Get(R"(/api/v1/jobs/([^/]+))", authed([this](const std::string& tenant, const Request& req, Response& res) {
      reply_job(res, api_.jobs_.get(tenant, req.matches[1].str()));
    }));
    server.Post(R"(/api/v1/jobs/([^/]+)/cancel)", authed([this](const std::string& tenant, const Request& req,
                                                                Response& res) {
      reply_job(res, api_.jobs_.cancel(tenant, req.matches[1].str()));
    }));
    server.Delete(R"(/api/v1/jobs/([^/]+))", authed([this](const std::string& tenant, const Request& req,
                                                           Response& res) {
      const Status removed = api_.jobs_.remove(tenant, req.matches[1].str());
      if (!removed.is_ok()) return fail(res, removed);
      reply(res, v1::DeleteJobResponse());
    }));
    server.Get(R"(/api/v1/jobs/([^/]+)/result)", authed([this](const std::string& tenant, const Request& req,
                                                               Response& res) {
      const std::string id = req.matches[1].str();
      if (const auto kept = api_.rendered_results_->find(tenant, id)) {
        // Served from memory only while the job is there (DeleteJob, retention).
        const Result<JobRecord> job = api_.jobs_.get(tenant, id);
        if (job.is_ok()) return reply_kept_json(res, kept);
        api_.rendered_results_->erase(tenant, id);
        return fail(res, job.status());
      }
      auto read = job_result(api_.jobs_, tenant, id);
      if (!read.is_ok()) return fail(res, read.status());
      auto json = keep_result_json(*api_.rendered_results_, tenant, id, read->result, "first GET");
      read->result.Clear();  // the JSON is what is sent
      // The read's room is held until the JSON is sent.
      reply_kept_json(res, std::move(json), std::move(read->read));
    }));
    server.Get(R"(/api/v1/jobs/([^/]+)/events)", authed([this](const std::string& tenant, const Request& req,
                                                               Response& res) { job_events(tenant, req.matches[1].str(), res); }));

    server.Get("/api/v1/sessions", authed([this](const std::string& tenant, const Request&, Response& res) {
      auto listed = api_.sessions_.list(tenant);
      if (!listed.is_ok()) return fail(res, listed.status());
      v1::ListSessionsResponse out;
      for (v1::SessionInfo& info : listed.value()) *out.add_sessions() = std::move(info);
      reply(res, out);
    }));
    server.Post("/api/v1/sessions", with_body<v1::CreateSessionRequest>(
        [this](const std::string& tenant, const v1::CreateSessionRequest& request, Response& res) {
          const auto session = api_.sessions_.create(tenant, request);
          if (!session.is_ok()) return fail(res, session.status());
          reply(res, session.value()->info());
        }));
    server.Get(R"(/api/v1/sessions/([^/]+))", authed([this](const std::string& tenant, const Request& req,
                                                            Response& res) {
      const auto session = api_.sessions_.get(tenant, req.matches[1].str());
      if (!session.is_ok()) return fail(res, session.status());
      reply(res, session.value()->info());
    }));
    server.Delete(R"(/api/v1/sessions/([^/]+))", authed([this](const std::string& tenant, const Request& req,
                                                               Response& res) {
      const Status closed = api_.sessions_.close(tenant, req.matches[1].str());
      if (!closed.is_ok()) return fail(res, closed);
      reply(res, v1::CloseSessionResponse());
    }));
    server.Post(R"(/api/v1/sessions/([^/]+)/retune)", [this](const Request& req, Response& res) {
      const std::string id = req.matches[1].str();
      with_body<v1::RetuneSessionRequest>([this, id](const std::string& tenant, const v1::RetuneSessionRequest& body,
                                                     Response& out) {
        v1::RetuneSessionRequest request = body;
        request.set_id(id);
        const auto info = retune_session(api_.sessions_, tenant, request);
        if (!info.is_ok()) return fail(out, info.status());
        reply(out, info.value());
      })(req, res);
    });
    server.Get(R"(/api/v1/sessions/([^/]+)/events)", authed([this](const std::string& tenant, const Request& req,
                                                                   Response& res) {
      session_events(tenant, req.matches[1].str(), res);
    }));

    // The workbench: its static files, from the binary.
    server.Get(R"(/([^?]*))", [](const Request& req, Response& res) {
      std::string path = req.matches[1].str();
      if (path.empty()) path = "index.html";
      for (const WebAsset& asset : web_assets()) {
        if (asset.path == path) {
          res.set_header("Cache-Control", "no-cache");
          res.set_content(std::string(asset.body), std::string(asset.content_type).c_str());
          return;
        }
      }
      res.status = 404;
    });

    // Unknown routes, bodies too large, and what httplib refuses itself:
    // a v1.Error in JSON under /api/, plain text elsewhere.
    server.set_error_handler(httplib::Server::HandlerWithResponse([](const Request& req, Response& res) {
      if (!res.body.empty()) return httplib::Server::HandlerResponse::Unhandled;
      std::string message;
      if (!HardenedServer::read_failure().empty()) {  // its body too slow: the rest is not a request
        res.status = 408;
        res.set_header("Connection", "close");
      }
      switch (res.status) {
        case 408: message = "the request's body was cut (" + HardenedServer::read_failure() + ")"; break;
        case 404: message = "no such route: " + req.method + " " + req.path; break;
        case 413: message = "the request is larger than this server accepts"; break;
        default: message = "the request was refused (HTTP " + std::to_string(res.status) + ")"; break;
      }
      const StatusCode code = res.status == 404   ? StatusCode::kNotFound
                              : res.status == 413 ? StatusCode::kResourceExhausted
                                                  : StatusCode::kInvalidArgument;
      if (req.path.rfind("/api/", 0) == 0) {
        res.set_content(to_json(to_error(Status(code, message))), "application/json");
      } else {
        res.set_content(message + "\n", "text/plain");
      }
      return httplib::Server::HandlerResponse::Handled;
    }));
    server.set_exception_handler([](const Request& req, Response& res, std::exception_ptr e) {
      std::string what = "unknown exception";
      try {
        if (e) std::rethrow_exception(e);
      } catch (const std::exception& ex) {
        what = ex.what();
      } catch (...) {
      }
      spdlog::error("http handler failed method={} path={} error=\"{}\"", req.method, req.path, what);
      fail(res, internal_error("the request failed inside riccatid; see its log"));
    });
    server.set_post_routing_handler([](const Request&, Response& res) {
      res.set_header("X-Content-Type-Options", "nosniff");
      res.set_header("Content-Security-Policy",
                     "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
                     "connect-src 'self'; frame-ancestors 'none'");
      res.set_header("Referrer-Policy", "no-referrer");
      if (!res.has_header("Cache-Control")) res.set_header("Cache-Control", "no-store");
    });
  }

 private:
  using Authed = std::function<void(const std::string& tenant, const Request&, Response&)>;

  // On the headers, before any body is read (httplib's pre-routing
  // handler): the Host (DNS rebinding), a write's Origin (cross-site
  // request forgery) and Content-Type, the token, and the body's framing
  // and size. A refusal closes the connection (its body is not read).
  httplib::Server::HandlerResponse check_headers(const Request& req, Response& res) const {
    const bool api = req.path.rfind("/api/", 0) == 0;
    const auto refuse = [&](int http, StatusCode code, const std::string& message) {
      res.status = http;
      if (api) {
        res.set_content(to_json(to_error(Status(code, message))), "application/json");
      } else {
        res.set_content(message + "\n", "text/plain");
      }
      res.set_header("Connection", "close");
      HardenedServer::close_after_response();
      return httplib::Server::HandlerResponse::Handled;
    };
    const std::string host = req.get_header_value("Host");
    // /healthz tells nothing: probes may name the server as they like.
    if (!host_allowed(host) && req.path != "/healthz") {
      return refuse(403, StatusCode::kFailedPrecondition,
                    "the Host \"" + printable(host) + "\" is not a name of this server (" + api_.listen_ +
                        "): a page that had its own name resolved to this address (DNS rebinding) is refused; "
                        "allow another name with http_allowed_hosts (--http-allowed-hosts)");
    }
    const bool write = req.method == "POST" || req.method == "PUT" || req.method == "PATCH" || req.method == "DELETE";
    if (write && req.has_header("Origin")) {
      const std::string origin = lower(req.get_header_value("Origin"));
      const std::string own = lower(host);
      if (host.empty() || (origin != "http://" + own && origin != "https://" + own && !origin_allowed(origin))) {
        return refuse(403, StatusCode::kFailedPrecondition,
                      "the Origin \"" + printable(req.get_header_value("Origin")) + "\" is not this server's (" +
                          (api_.tls_ ? "https://" : "http://") + printable(host) +
                          "): writes from another site's page are refused (cross-site request forgery)");
      }
    }
    if (api && api_.auth_.enabled()) {
      if (!authenticate(req, res)) {
        res.set_header("Connection", "close");
        HardenedServer::close_after_response();
        return httplib::Server::HandlerResponse::Handled;
      }
    }
    if (req.has_header("Transfer-Encoding")) {
      return refuse(411, StatusCode::kInvalidArgument,
                    "a body sent with Transfer-Encoding (\"" + printable(req.get_header_value("Transfer-Encoding")) +
                        "\") is refused: send its size in Content-Length, so that it is checked against the limit "
                        "(max_message_bytes, or max_dataset_bytes for an upload) before it is read");
    }
    const bool upload = req.method == "POST" && req.path == "/api/v1/datasets";
    const std::string length_text = req.get_header_value("Content-Length");
    std::int64_t length = 0;
    if (!length_text.empty()) {
      const auto parsed = std::from_chars(length_text.data(), length_text.data() + length_text.size(), length);
      if (parsed.ec != std::errc() || parsed.ptr != length_text.data() + length_text.size() || length < 0) {
        return refuse(400, StatusCode::kInvalidArgument,
                      "Content-Length \"" + printable(length_text) + "\" is not a number of bytes");
      }
    }
    if (length > 0) {
      if (!api) {
        return refuse(413, StatusCode::kResourceExhausted, "the workbench's pages take no body (" + req.method + " " +
                                                               printable(req.path) + " with " +
                                                               std::to_string(length) + " bytes)");
      }
      const char* key = upload ? "max_dataset_bytes" : "max_message_bytes";
      const std::int64_t limit = upload ? api_.limits_.max_dataset_bytes : api_.limits_.max_message_bytes;
      if (length > limit) {
        return refuse(413, StatusCode::kResourceExhausted,
                      limit_reached(key, limit, "the body is " + std::to_string(length) + " bytes (" + req.method +
                                                    " " + printable(req.path) + ")")
                          .message());
      }
    }
    if (api && write && (length > 0 || req.has_header("Content-Type"))) {
      const std::string type = media_type(req.get_header_value("Content-Type"));
      if (upload && cross_site_type(type)) {
        return refuse(415, StatusCode::kInvalidArgument,
                      "an upload sent as " + type +
                          " is refused (a type another site's page may send without asking): send the file as "
                          "application/octet-stream (or text/csv)");
      }
      if (!upload && type != "application/json") {
        return refuse(415, StatusCode::kInvalidArgument,
                      "the body's Content-Type is \"" + printable(type) +
                          "\": the JSON API takes application/json (another site's page may send text/plain, "
                          "forms and multipart without asking, so they are refused)");
      }
    }
    return httplib::Server::HandlerResponse::Unhandled;
  }

  // The Host header names this server: its listen address, localhost, a
  // loopback address (any IP literal when listening off loopback), or one
  // of http_allowed_hosts; with any port. None (HTTP/1.0) is accepted.
  bool host_allowed(const std::string& header) const {
    if (header.empty() || api_.any_host_) return true;
    std::string host = lower(header);
    if (host.front() == '[') {
      const std::size_t close = host.find(']');
      if (close == std::string::npos) return false;
      host = host.substr(1, close - 1);
    } else if (const std::size_t colon = host.rfind(':'); colon != std::string::npos && host.find(':') == colon) {
      host = host.substr(0, colon);
    }
    if (std::find(api_.allowed_hosts_.begin(), api_.allowed_hosts_.end(), host) != api_.allowed_hosts_.end()) {
      return true;
    }
    in_addr v4{};
    in6_addr v6{};
    if (inet_pton(AF_INET, host.c_str(), &v4) == 1) return api_.ip_hosts_ || (ntohl(v4.s_addr) >> 24) == 127;
    if (inet_pton(AF_INET6, host.c_str(), &v6) == 1) return api_.ip_hosts_ || IN6_IS_ADDR_LOOPBACK(&v6);
    return false;
  }

  // An Origin whose host an operator named in http_allowed_hosts (a
  // proxy's public name, which need not be the Host the proxy sends on).
  bool origin_allowed(const std::string& origin) const {
    const std::size_t scheme = origin.find("://");
    if (scheme == std::string::npos) return false;
    std::string name = origin.substr(scheme + 3);
    if (!name.empty() && name.front() == '[') {
      name = name.substr(1, name.find(']') == std::string::npos ? 0 : name.find(']') - 1);
    } else {
      name = name.substr(0, name.find(':'));
    }
    return !name.empty() && std::find(api_.operator_hosts_.begin(), api_.operator_hosts_.end(), name) !=
                                api_.operator_hosts_.end();
  }

  // The caller's tenant, or a 401 answered.
  std::optional<std::string> authenticate(const Request& req, Response& res) const {
    if (!api_.auth_.enabled()) return std::string(kDefaultTenant);
    if (!req.has_header("Authorization")) {
      fail(res, Status(StatusCode::kUnauthenticated, "no bearer token: send the header \"Authorization: Bearer <token>\""));
      return std::nullopt;
    }
    const auto tenant = api_.auth_.tenant_for_header(req.get_header_value("Authorization"));
    if (!tenant.is_ok()) {
      fail(res, tenant.status());
      return std::nullopt;
    }
    return tenant.value();
  }

  httplib::Server::Handler authed(Authed handler) const {
    return [this, handler = std::move(handler)](const Request& req, Response& res) {
      const auto tenant = authenticate(req, res);
      if (tenant) handler(*tenant, req, res);
    };
  }

  // A POST whose body is the JSON of `Message`.
  template <typename Message>
  httplib::Server::Handler with_body(std::function<void(const std::string&, const Message&, Response&)> handler) const {
    return authed([this, handler = std::move(handler)](const std::string& tenant, const Request& req, Response& res) {
      if (static_cast<std::int64_t>(req.body.size()) > api_.limits_.max_message_bytes) {
        return fail(res, limit_reached("max_message_bytes", api_.limits_.max_message_bytes,
                                       "the body is " + std::to_string(req.body.size()) + " bytes"),
                    413);
      }
      Message message;
      google::protobuf::util::JsonParseOptions options;
      options.ignore_unknown_fields = false;  // a misspelt field is an error, not a default
      const auto parsed = google::protobuf::util::JsonStringToMessage(req.body.empty() ? "{}" : req.body, &message,
                                                                      options);
      if (!parsed.ok()) {
        return fail(res, invalid_argument("the body is not a " + std::string(Message::descriptor()->full_name()) +
                                          " in JSON: " + std::string(parsed.message())));
      }
      handler(tenant, message, res);
    });
  }

  void reply_job(Response& res, const Result<JobRecord>& job) const {
    if (!job.is_ok()) return fail(res, job.status());
    reply(res, to_proto(job.value()));
  }

  // The file is the body; the header's fields are the query's. Room is
  // reserved as the bytes arrive, as for a gRPC upload.
  void upload(const std::string& tenant, const Request& req, Response& res, const httplib::ContentReader& reader) {
    v1::UploadHeader header;
    header.set_name(req.get_param_value("name"));
    const std::string format = req.get_param_value("format");
    if (format == "csv") {
      header.set_format(v1::DATASET_FORMAT_CSV);
    } else if (format == "mat") {
      header.set_format(v1::DATASET_FORMAT_MAT);
    } else if (!format.empty()) {
      return fail(res, invalid_argument("format: expected csv or mat, not \"" + printable(format) + "\""));
    }
    header.set_time_column(req.get_param_value("time_column"));
    for (const auto& c : split_list(req.get_param_value("input_columns"))) header.add_input_columns(c);
    for (const auto& c : split_list(req.get_param_value("output_columns"))) header.add_output_columns(c);
    for (const auto& pair : split_list(req.get_param_value("true_parameters"))) {
      const std::size_t colon = pair.find(':');
      double value = 0.0;
      const char* const end = pair.data() + pair.size();
      const auto parsed = colon == std::string::npos ? std::from_chars_result{pair.data(), std::errc::invalid_argument}
                                                     : std::from_chars(pair.data() + colon + 1, end, value);
      if (parsed.ec != std::errc() || parsed.ptr != end) {
        return fail(res, invalid_argument("true_parameters: expected name:value pairs separated by commas, not \"" +
                                          printable(pair) + "\""));
      }
      (*header.mutable_true_parameters())[pair.substr(0, colon)] = value;
    }
    DatasetUpload upload = upload_from_header(header);
    if (req.has_header("Content-Length")) {
      const std::int64_t length = std::strtoll(req.get_header_value("Content-Length").c_str(), nullptr, 10);
      if (length > api_.limits_.max_dataset_bytes) {
        return fail(res, limit_reached("max_dataset_bytes", api_.limits_.max_dataset_bytes,
                                       "the upload of " + printable(upload.name) + " is " + std::to_string(length) +
                                           " bytes"),
                    413);
      }
    }
    Result<UploadTicket> ticket = api_.datasets_.begin_upload(tenant, upload.name);
    if (!ticket.is_ok()) return fail(res, ticket.status());
    Status room;
    const bool read = reader([&](const char* data, std::size_t size) {
      room = ticket->grow(static_cast<std::int64_t>(upload.bytes.size() + size));
      if (!room.is_ok()) return false;
      upload.bytes.append(data, size);
      return true;
    });
    if (!room.is_ok()) {
      return fail(res, room, room.code() == StatusCode::kResourceExhausted ? 413 : 0);
    }
    if (!read) {
      const std::string& slow = HardenedServer::read_failure();
      return fail(res,
                  Status(StatusCode::kCancelled, "the upload of " + printable(upload.name) + " was cut" +
                                                     (slow.empty() ? "" : " (" + slow + ")") + ": nothing stored"),
                  slow.empty() ? 0 : 408);
    }
    const Result<DatasetRecord> stored = api_.datasets_.upload(ticket.value(), upload);
    if (!stored.is_ok()) return fail(res, stored.status());
    reply(res, to_proto(stored.value()));
  }

  // Takes a place for an event stream: one of the tenant's (and riccatid's)
  // long-lived calls, 429 naming the limit past it; and one of this server's
  // threads, 503 past them.
  std::shared_ptr<EventStream> open_stream(const std::string& tenant, const std::string& what, Response& res) const {
    {
      std::lock_guard lock(api_.tenant_streams_mu_);
      const std::int64_t open = api_.tenant_streams_[tenant];
      if (open >= api_.limits_.max_tenant_event_streams) {
        fail(res, limit_reached("max_tenant_event_streams", api_.limits_.max_tenant_event_streams,
                                "the tenant has " + std::to_string(open) + " workbench event streams open (of the " +
                                    std::to_string(kMaxEventStreams) + " the workbench serves)"));
        return nullptr;
      }
      ++api_.tenant_streams_[tenant];
    }
    auto release = [this, tenant] {
      std::lock_guard lock(api_.tenant_streams_mu_);
      if (--api_.tenant_streams_[tenant] <= 0) api_.tenant_streams_.erase(tenant);
    };
    Result<StreamSlot> slot = api_.stream_slots_.acquire(tenant, what);
    if (!slot.is_ok()) {
      release();
      fail(res, slot.status());
      return nullptr;
    }
    if (++api_.streams_ > kMaxEventStreams) {
      --api_.streams_;
      release();
      fail(res, Status(StatusCode::kUnavailable,
                       "the workbench serves " + std::to_string(kMaxEventStreams) +
                           " event streams at once (a thread each), and as many are open; try again shortly"),
           503);
      return nullptr;
    }
    return std::make_shared<EventStream>(api_.streams_, std::move(release), std::move(slot).value());
  }

  void job_events(const std::string& tenant, const std::string& id, Response& res) {
    const auto found = api_.jobs_.get(tenant, id);  // 404 before the stream starts
    if (!found.is_ok()) return fail(res, found.status());
    auto slot = open_stream(tenant, "job event stream", res);
    if (slot == nullptr) return;
    res.set_chunked_content_provider("text/event-stream", [this, tenant, id, slot](std::size_t,
                                                                                   httplib::DataSink& sink) {
      if (api_.stopping_) {
        sink.done();
        return true;
      }
      const auto now = Clock::now();
      if (slot->sent_any && now < slot->last_event + kJobEventInterval) {
        std::this_thread::sleep_for(slot->last_event + kJobEventInterval - now);
      }
      // The job once it has changed, looked at every 100 ms for half a second.
      std::optional<JobRecord> job;
      for (const auto until = Clock::now() + std::chrono::milliseconds(500);;) {
        bool running_here = false;
        auto polled = api_.jobs_.poll(tenant, id, &slot->version, &running_here);
        if (!polled.is_ok()) {
          send_event(sink, "error", to_json(to_error(polled.status())));
          sink.done();
          return true;
        }
        if (polled->has_value()) {
          job = std::move(*polled.value());
          break;
        }
        if (Clock::now() >= until || api_.stopping_) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      }
      if (!job) {
        if (Clock::now() - slot->last_write < kHeartbeat) return true;
        slot->last_write = Clock::now();
        return sink.write(": \n\n", 4);
      }
      if (!send_event(sink, "job", to_json(to_proto(*job)))) return false;
      slot->sent_any = true;
      slot->last_event = slot->last_write = Clock::now();
      if (is_terminal(job->state)) sink.done();
      return true;
    });
  }

  void session_events(const std::string& tenant, const std::string& id, Response& res) {
    const auto found = api_.sessions_.get(tenant, id);  // 404 before the stream starts
    if (!found.is_ok()) return fail(res, found.status());
    auto slot = open_stream(tenant, "session event stream", res);
    if (slot == nullptr) return;
    res.set_chunked_content_provider("text/event-stream", [this, tenant, id, slot](std::size_t,
                                                                                   httplib::DataSink& sink) {
      if (api_.stopping_) {
        sink.done();
        return true;
      }
      const auto now = Clock::now();
      if (now < slot->last_event + kSessionEventInterval) {
        std::this_thread::sleep_for(slot->last_event + kSessionEventInterval - now);
      }
      slot->last_event = Clock::now();
      const auto session = api_.sessions_.get(tenant, id);
      if (!session.is_ok()) {
        send_event(sink, "error", to_json(to_error(session.status())));
        sink.done();
        return true;
      }
      v1::Estimate estimate;
      std::uint64_t accepted = 0;
      const bool estimated = session.value()->latest(&estimate, &accepted);
      if (slot->sent_any && accepted == slot->sent_accepted) {
        if (Clock::now() - slot->last_write < kHeartbeat) return true;
        slot->last_write = Clock::now();
        return sink.write(": \n\n", 4);
      }
      std::string data = "{\"info\":" + to_json(session.value()->info());
      if (estimated) data += ",\"estimate\":" + to_json(estimate);
      data += "}";
      if (!send_event(sink, "session", data)) return false;
      slot->sent_any = true;
      slot->sent_accepted = accepted;
      slot->last_write = Clock::now();
      return true;
    });
  }

  HttpApi& api_;
};

HttpApi::HttpApi(const Authenticator& auth, ModelCatalog& models, DatasetManager& datasets, JobManager& jobs,
                 SessionManager& sessions, StreamSlots& stream_slots, Limits limits)
    : auth_(auth),
      models_(models),
      datasets_(datasets),
      jobs_(jobs),
      sessions_(sessions),
      stream_slots_(stream_slots),
      limits_(limits) {}

HttpApi::~HttpApi() { stop(); }

Result<int> HttpApi::serve(const HttpOptions& options, const SecurityConfig& security, std::string* description) {
  RICCATI_ASSIGN_OR_RETURN(auto host_port, split_address(options.listen, "http_listen"));
  const bool tls = !security.tls_cert.empty() || !security.tls_key.empty();
  const bool loopback = is_loopback(options.listen);
  if (!tls && !loopback && !options.plain_public) {
    return failed_precondition("http_listen " + options.listen +
                               " is not a loopback address: serving the workbench there needs TLS (tls_cert and "
                               "tls_key, as for gRPC), or http_public: true (--http-public) behind a proxy that "
                               "terminates TLS");
  }
  if (!auth_.enabled() && !loopback) {
    return invalid_argument("http_listen " + options.listen +
                            " needs a tokens file: without authentication riccatid listens on loopback only");
  }
  if (tls && (security.tls_cert.empty() || security.tls_key.empty())) {
    return invalid_argument("TLS needs both tls_cert and tls_key");
  }
  HardenedOptions hardened;
  // Event streams and uploads hold a worker while they last: room for all
  // of them, and 8 for the other requests.
  hardened.workers = kMaxEventStreams + static_cast<int>(std::min<std::int64_t>(limits_.max_uploads, 64)) + 8;
  hardened.keep_alive_idle = std::chrono::seconds(2);
  server_ = std::make_unique<HardenedServer>(hardened);
  if (tls) {
    std::string why;
    if (!server_->use_tls(security.tls_cert, security.tls_key, security.tls_client_ca, &why)) {
      server_.reset();
      return invalid_argument("http_listen: " + why);
    }
  }
  listen_ = options.listen;
  tls_ = tls;
  ip_hosts_ = !loopback;
  allowed_hosts_ = {lower(host_port.first), "localhost"};
  for (const std::string& name : options.allowed_hosts) {
    if (name == "*") any_host_ = true;
    allowed_hosts_.push_back(lower(name));
    operator_hosts_.push_back(lower(name));
  }
  server_->set_payload_max_length(
      static_cast<std::size_t>(std::max(limits_.max_dataset_bytes, limits_.max_message_bytes)));
  routes_ = std::make_unique<Routes>(*this);
  routes_->install(*server_);
  const auto& [host, port] = host_port;
  const int bound = server_->bind_port(host, port);
  if (bound < 0) {
    server_.reset();
    return failed_precondition("cannot serve HTTP on " + options.listen + ": cannot bind (in use, or no such address)");
  }
  // A result's JSON is written when its job ends (about 10 ms for the
  // two-tank 10-pass result, 14 times what sending it takes), on the job's
  // worker, so that the workbench's GET after the end event is served from
  // memory. Results whose JSON could not be kept are not written.
  jobs_.set_result_listener([kept = rendered_results_](const JobRecord& job, const std::string& encoded) {
    if (encoded.size() * kJsonBytesPerEncodedByte > kRenderedResultBytes) return;
    v1::JobResult result;
    if (!result.ParseFromString(encoded)) return;  // GetResult says so
    keep_result_json(*kept, job.tenant, job.id, result, "job end");
  });
  thread_ = std::thread([server = server_.get()] { server->listen_after_bind(); });
  *description = std::string(tls ? (security.tls_client_ca.empty() ? "https" : "https, client certificates")
                                 : "plain http") +
                 (auth_.enabled() ? ", bearer tokens" : ", no authentication (loopback)");
  return bound;
}

void HttpApi::stop() {
  if (server_ == nullptr) return;
  jobs_.set_result_listener(nullptr);
  stopping_ = true;
  server_->shutdown();  // waiting connections closed, workers ended (their reads and writes fail at once)
  if (thread_.joinable()) thread_.join();
  server_.reset();
  routes_.reset();
}

}  // namespace riccati::service
