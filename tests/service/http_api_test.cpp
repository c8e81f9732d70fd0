// The workbench's HTTP face on a real riccatid (--http-listen): the JSON API
// under /api/v1/ against the gRPC services of the same daemon (one store, one
// schema), bearer tokens and tenants, bad requests (malformed JSON, unknown
// routes, bodies too large), server-sent events of a job and of a session fed
// over gRPC, event streams counted with gRPC's streams against a tenant's
// cap, TLS with the gRPC certificates, and the refusal to serve plain HTTP
// off loopback.
#include <google/protobuf/util/json_util.h>
#include <google/protobuf/util/message_differencer.h>
#include <gtest/gtest.h>
#include <openssl/evp.h>

#include <array>
#include <fstream>

#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/models.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/daemon_fixture.hpp"
#include "support/requests.hpp"
#include "support/wait.hpp"

// After Eigen: <resolv.h>, which httplib includes, defines _res, a name Eigen uses.
#include <httplib.h>

namespace riccati {
namespace {

using google::protobuf::util::JsonStringToMessage;
using google::protobuf::util::MessageDifferencer;
using google::protobuf::util::MessageToJsonString;
using testing::DaemonProcess;
using testing::read_file;
using testing::TempDir;

const std::string kData = RICCATI_TEST_DATA_DIR;
const std::string kTls = RICCATI_TEST_TLS_DIR;  // the keys with mode 0600
const std::string kAlpha = "alpha-5d2e8c1f7a3b";  // tokens of two tenants
const std::string kBeta = "beta-9b4f0e6a2c7d";

std::string digest(const std::string& token) {
  std::array<unsigned char, EVP_MAX_MD_SIZE> md;
  unsigned int n = 0;
  EVP_Digest(token.data(), token.size(), md.data(), &n, EVP_sha256(), nullptr);
  std::string out = "sha256:";
  char hex[3];
  for (unsigned int i = 0; i < n; ++i) {
    std::snprintf(hex, sizeof hex, "%02x", md[i]);
    out += hex;
  }
  return out;
}

std::string write_tokens(const std::filesystem::path& dir) {
  const auto path = dir / "tokens";
  std::ofstream(path) << "alpha " << digest(kAlpha) << "\nbeta " << digest(kBeta) << "\n";
  return path.string();
}

httplib::Headers bearer(const std::string& token) { return {{"Authorization", "Bearer " + token}}; }

template <typename Message>
Message parse(const std::string& json) {
  Message m;
  const auto status = JsonStringToMessage(json, &m);
  EXPECT_TRUE(status.ok()) << status.ToString() << ": " << json.substr(0, 500);
  return m;
}

std::string json_of(const google::protobuf::Message& m) {
  std::string out;
  EXPECT_TRUE(MessageToJsonString(m, &out).ok());
  return out;
}

// Server-sent events as they arrive: (event, data) pairs.
struct Events {
  std::string buffer;
  std::vector<std::pair<std::string, std::string>> events;
  void add(const char* data, std::size_t size) {
    buffer.append(data, size);
    for (auto end = buffer.find("\n\n"); end != std::string::npos; end = buffer.find("\n\n")) {
      const std::string block = buffer.substr(0, end);
      buffer.erase(0, end + 2);
      std::string event, payload;
      std::istringstream lines(block);
      for (std::string line; std::getline(lines, line);) {
        if (line.rfind("event: ", 0) == 0) event = line.substr(7);
        if (line.rfind("data: ", 0) == 0) payload += line.substr(6);
      }
      if (!event.empty()) events.emplace_back(event, payload);
    }
  }
};

class HttpApiTest : public ::testing::Test {
 protected:
  void SetUp() override { start({}); }

  void start(std::vector<std::string> extra) {
    const std::vector<std::string> base = {"--tokens-file", write_tokens(dir_.path()), "--http-listen", "127.0.0.1:0",
                                           "--http-port-file", (dir_.path() / "http_port").string()};
    extra.insert(extra.begin(), base.begin(), base.end());
    daemon_ = std::make_unique<DaemonProcess>(dir_.path() / "data", extra);
    if (!log_file_.empty()) daemon_->set_log_file(log_file_);
    daemon_->start();
    std::ifstream(dir_.path() / "http_port") >> http_port_;
    ASSERT_GT(http_port_, 0) << "no --http-port-file";
    http_ = std::make_unique<httplib::Client>("127.0.0.1", http_port_);
    http_->set_read_timeout(60, 0);
    datasets_ = v1::DatasetService::NewStub(daemon_->channel());
    jobs_ = v1::JobService::NewStub(daemon_->channel());
    sessions_ = v1::SessionService::NewStub(daemon_->channel());
  }

  std::unique_ptr<grpc::ClientContext> as(const std::string& token) const {
    auto ctx = std::make_unique<grpc::ClientContext>();
    ctx->AddMetadata("authorization", "Bearer " + token);
    ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    return ctx;
  }

  v1::DatasetInfo upload_two_tank(const std::string& token, const std::string& name = "two_tank.csv") {
    const auto res = http_->Post(("/api/v1/datasets?format=csv&input_columns=F1,F2&output_columns=h1,h2&name=" +
                                  httplib::detail::encode_query_param(name))
                                     .c_str(),
                                 bearer(token), read_file(kData + "/two_tank.csv"), "text/csv");
    EXPECT_TRUE(res) << httplib::to_string(res.error());
    if (!res) return {};
    EXPECT_EQ(res->status, 200) << res->body;
    return parse<v1::DatasetInfo>(res->body);
  }

  TempDir dir_;
  std::filesystem::path log_file_;  // empty: the daemon's log goes to the test's output
  std::unique_ptr<DaemonProcess> daemon_;
  int http_port_ = 0;
  std::unique_ptr<httplib::Client> http_;
  std::unique_ptr<v1::DatasetService::Stub> datasets_;
  std::unique_ptr<v1::JobService::Stub> jobs_;
  std::unique_ptr<v1::SessionService::Stub> sessions_;
};

TEST_F(HttpApiTest, HealthzNeedsNoTokenAndTheApiNeedsAValidOne) {
  auto res = http_->Get("/healthz");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 200);
  res = http_->Get("/api/v1/models");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 401);
  EXPECT_NE(parse<v1::Error>(res->body).message().find("Bearer"), std::string::npos) << res->body;
  res = http_->Get("/api/v1/models", bearer("not-a-token"));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 401);
  res = http_->Get("/api/v1/models", bearer(kAlpha));
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  const auto models = parse<v1::ListModelsResponse>(res->body);
  const auto two_tank = std::find_if(models.models().begin(), models.models().end(),
                                     [](const v1::ModelInfo& m) { return m.name() == "two_tank"; });
  ASSERT_NE(two_tank, models.models().end());
  EXPECT_EQ(two_tank->param_names_size(), 4);
  // The workbench itself needs no token: it holds no data.
  res = http_->Get("/");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 200);
  EXPECT_NE(res->get_header_value("Content-Type").find("text/html"), std::string::npos);
  EXPECT_NE(res->get_header_value("Content-Security-Policy").find("script-src 'self'"), std::string::npos);
}

TEST_F(HttpApiTest, DatasetsUploadedOverHttpAreTheGrpcOnesAndOtherTenantsGet404) {
  const v1::DatasetInfo info = upload_two_tank(kAlpha);
  ASSERT_FALSE(info.id().empty());
  EXPECT_EQ(info.samples(), 2000u);
  EXPECT_EQ(std::vector<std::string>(info.output_names().begin(), info.output_names().end()),
            (std::vector<std::string>{"h1", "h2"}));
  // The same dataset over gRPC, field for field.
  v1::GetDatasetRequest get;
  get.set_id(info.id());
  v1::DatasetInfo over_grpc;
  ASSERT_TRUE(datasets_->GetDataset(as(kAlpha).get(), get, &over_grpc).ok());
  EXPECT_TRUE(MessageDifferencer::Equals(info, over_grpc)) << info.DebugString() << over_grpc.DebugString();
  // Its values.
  auto res = http_->Get(("/api/v1/datasets/" + info.id() + "/data").c_str(), bearer(kAlpha));
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200);
  const auto data = parse<v1::DatasetData>(res->body);
  EXPECT_EQ(data.t_size(), 2000);
  EXPECT_EQ(data.y().rows(), 2u);
  // Declared true parameters, kept with the dataset; a pair without a value is 400.
  const std::string with_truth = "/api/v1/datasets?input_columns=F1,F2&output_columns=h1,h2&true_parameters=";
  res = http_->Post((with_truth + "A1:10,k1:0.0791").c_str(), bearer(kAlpha), read_file(kData + "/two_tank.csv"),
                    "text/csv");
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  const auto declared = parse<v1::DatasetInfo>(res->body);
  EXPECT_EQ(declared.true_parameters().size(), 2u);
  EXPECT_EQ(declared.true_parameters().at("k1"), 0.0791);
  res = http_->Post((with_truth + "A1").c_str(), bearer(kAlpha), read_file(kData + "/two_tank.csv"), "text/csv");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 400);
  EXPECT_NE(parse<v1::Error>(res->body).message().find("true_parameters: expected name:value"), std::string::npos)
      << res->body;
  // Another tenant sees nothing of it, over either transport.
  for (const std::string& path : {"/api/v1/datasets/" + info.id(), "/api/v1/datasets/" + info.id() + "/data"}) {
    res = http_->Get(path.c_str(), bearer(kBeta));
    ASSERT_TRUE(res);
    EXPECT_EQ(res->status, 404) << path << ": " << res->body;
  }
  res = http_->Delete(("/api/v1/datasets/" + info.id()).c_str(), bearer(kBeta));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 404);
  res = http_->Get("/api/v1/datasets", bearer(kBeta));
  ASSERT_TRUE(res);
  EXPECT_EQ(parse<v1::ListDatasetsResponse>(res->body).datasets_size(), 0);
  // Its owner deletes it; gRPC no longer finds it.
  res = http_->Delete(("/api/v1/datasets/" + info.id()).c_str(), bearer(kAlpha));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 200) << res->body;
  EXPECT_EQ(datasets_->GetDataset(as(kAlpha).get(), get, &over_grpc).error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_F(HttpApiTest, AnIdentificationSubmittedInJsonIsWatchedByEventsAndItsResultIsTheGrpcOne) {
  const v1::DatasetInfo info = upload_two_tank(kAlpha);
  ASSERT_FALSE(info.id().empty());
  auto res = http_->Post("/api/v1/jobs/identification", bearer(kAlpha), json_of(testing::hensen_spec(info.id(), 3)),
                         "application/json");
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  const auto job = parse<v1::Job>(res->body);
  ASSERT_FALSE(job.id().empty());

  // Events until it ends: each a Job, the last one terminal.
  Events events;
  res = http_->Get(("/api/v1/jobs/" + job.id() + "/events").c_str(), bearer(kAlpha),
                   [&](const char* data, std::size_t size) {
                     events.add(data, size);
                     return true;
                   });
  ASSERT_TRUE(res) << httplib::to_string(res.error());
  EXPECT_EQ(res->status, 200);
  EXPECT_NE(res->get_header_value("Content-Type").find("text/event-stream"), std::string::npos);
  ASSERT_FALSE(events.events.empty());
  for (const auto& [event, data] : events.events) EXPECT_EQ(event, "job") << data;
  const auto last = parse<v1::Job>(events.events.back().second);
  EXPECT_EQ(last.state(), v1::JOB_STATE_SUCCEEDED) << events.events.back().second;

  res = http_->Get(("/api/v1/jobs/" + job.id() + "/result").c_str(), bearer(kAlpha));
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  const auto over_http = parse<v1::JobResult>(res->body);
  v1::GetResultRequest get;
  get.set_job_id(job.id());
  v1::JobResult over_grpc;
  ASSERT_TRUE(jobs_->GetResult(as(kAlpha).get(), get, &over_grpc).ok());
  ASSERT_TRUE(over_grpc.has_identification());
  EXPECT_EQ(over_grpc.identification().theta_mean_size(), 4);
  // Doubles survive JSON exactly (protobuf prints the shortest round trip).
  EXPECT_TRUE(MessageDifferencer::Equals(over_http, over_grpc));
  // Again: the JSON kept from the first time, the same to the byte.
  const std::string first_body = res->body;
  res = http_->Get(("/api/v1/jobs/" + job.id() + "/result").c_str(), bearer(kAlpha));
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  EXPECT_EQ(res->body, first_body);
  EXPECT_NE(res->get_header_value("Content-Type").find("application/json"), std::string::npos);

  // Another tenant: 404 for the job, its events and its result.
  for (const std::string& path : {"/api/v1/jobs/" + job.id(), "/api/v1/jobs/" + job.id() + "/events",
                                 "/api/v1/jobs/" + job.id() + "/result"}) {
    res = http_->Get(path.c_str(), bearer(kBeta));
    ASSERT_TRUE(res);
    EXPECT_EQ(res->status, 404) << path;
  }
  res = http_->Get("/api/v1/jobs", bearer(kAlpha));
  ASSERT_TRUE(res);
  EXPECT_EQ(parse<v1::ListJobsResponse>(res->body).jobs_size(), 1);

  // DeleteJob: not another tenant's (404); the owner's goes with its result
  // (the JSON kept in memory is not served for a job that is gone).
  res = http_->Delete(("/api/v1/jobs/" + job.id()).c_str(), bearer(kBeta));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 404);
  res = http_->Delete(("/api/v1/jobs/" + job.id()).c_str(), bearer(kAlpha));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 200) << res->body;
  res = http_->Get(("/api/v1/jobs/" + job.id() + "/result").c_str(), bearer(kAlpha));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 404);
}

// The workbench opens a result when its job's end event arrives: the JSON is
// written as the job ends (riccatid's debug log says where each one was
// written), so that GET only sends it.
TEST_F(HttpApiTest, AResultsJsonIsWrittenAsItsJobEndsAndTheFirstGetOnlySendsIt) {
  daemon_.reset();
  log_file_ = dir_.path() / "riccatid.log";
  start({"--log-level", "debug"});
  const v1::DatasetInfo info = upload_two_tank(kAlpha);
  ASSERT_FALSE(info.id().empty());
  v1::Job job;
  ASSERT_TRUE(jobs_->SubmitIdentification(as(kAlpha).get(), testing::hensen_spec(info.id(), 2), &job).ok());
  const std::string written_at_end = "result JSON written job=" + job.id() + " ";
  const auto log_has = [&](const std::string& what, const std::string& where) {
    const std::string log = read_file(log_file_.string());
    for (std::size_t at = log.find(what); at != std::string::npos; at = log.find(what, at + 1)) {
      if (log.compare(log.find('\n', at) - where.size(), where.size(), where) == 0) return true;
    }
    return false;
  };
  ASSERT_TRUE(testing::wait_until([&] { return log_has(written_at_end, "at=\"job end\""); },
                                  std::chrono::seconds(60), "the result's JSON is written as the job ends"));

  const auto res = http_->Get(("/api/v1/jobs/" + job.id() + "/result").c_str(), bearer(kAlpha));
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  v1::GetResultRequest get;
  get.set_job_id(job.id());
  v1::JobResult over_grpc;
  ASSERT_TRUE(jobs_->GetResult(as(kAlpha).get(), get, &over_grpc).ok());
  EXPECT_TRUE(MessageDifferencer::Equals(parse<v1::JobResult>(res->body), over_grpc));
  EXPECT_FALSE(log_has(written_at_end, "at=\"first GET\"")) << "the GET wrote the JSON again";
  // Another tenant's GET finds nothing, written or not.
  const auto other = http_->Get(("/api/v1/jobs/" + job.id() + "/result").c_str(), bearer(kBeta));
  ASSERT_TRUE(other);
  EXPECT_EQ(other->status, 404);
}

TEST_F(HttpApiTest, MalformedJsonIs400NamingTheFieldAndUnknownRoutesAre404) {
  auto res = http_->Post("/api/v1/jobs/identification", bearer(kAlpha), R"({"model": "two_tank", "passes": "many"})",
                         "application/json");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 400);
  auto error = parse<v1::Error>(res->body);
  EXPECT_EQ(error.code(), 3);
  EXPECT_NE(error.message().find("passes"), std::string::npos) << error.message();

  res = http_->Post("/api/v1/sessions", bearer(kAlpha), R"({"modle": "two_tank"})", "application/json");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 400);
  EXPECT_NE(parse<v1::Error>(res->body).message().find("modle"), std::string::npos) << res->body;

  res = http_->Post("/api/v1/sessions", bearer(kAlpha), R"({"model": )", "application/json");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 400) << res->body;

  // The managers' checks, as over gRPC.
  res = http_->Post("/api/v1/jobs/identification", bearer(kAlpha), R"({"model": "no_such_model"})",
                    "application/json");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status / 100, 4) << res->body;
  EXPECT_NE(parse<v1::Error>(res->body).message().find("no_such_model"), std::string::npos) << res->body;

  res = http_->Get("/api/v1/no-such-thing", bearer(kAlpha));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 404);
  EXPECT_EQ(parse<v1::Error>(res->body).code(), 5) << res->body;
  res = http_->Get("/no-such-page.html");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 404);
}

TEST_F(HttpApiTest, BodiesPastTheLimitsAre413) {
  daemon_.reset();
  start({"--max-dataset-bytes", "65536", "--max-message-bytes", "65536"});
  // The two-tank CSV is 170 kB.
  auto res = http_->Post("/api/v1/datasets?name=big.csv&input_columns=F1,F2&output_columns=h1,h2", bearer(kAlpha),
                         read_file(kData + "/two_tank.csv"), "text/csv");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 413) << res->body;
  res = http_->Post("/api/v1/sessions", bearer(kAlpha), "{\"model\": \"" + std::string(70000, 'x') + "\"}",
                    "application/json");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 413) << res->body;
  res = http_->Get("/api/v1/datasets", bearer(kAlpha));
  ASSERT_TRUE(res);
  EXPECT_EQ(parse<v1::ListDatasetsResponse>(res->body).datasets_size(), 0) << "nothing stored";
}

TEST_F(HttpApiTest, SessionEventsFollowMeasurementsStreamedOverGrpc) {
  auto res = http_->Post("/api/v1/sessions", bearer(kAlpha), json_of(testing::two_tank_session()), "application/json");
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  const auto session = parse<v1::SessionInfo>(res->body);
  ASSERT_FALSE(session.id().empty());

  // Measurements over gRPC, on their own thread, until the events have seen some.
  std::atomic<bool> seen{false};
  std::thread feeder([&] {
    auto ctx = as(kAlpha);
    auto stream = sessions_->Stream(ctx.get());
    v1::StreamRequest open;
    open.mutable_open()->set_session_id(session.id());
    stream->Write(open);
    ColumnMapping mapping;
    mapping.inputs = {"F1", "F2"};
    mapping.outputs = {"h1", "h2"};
    const Dataset data = read_csv_file(kData + "/two_tank.csv", mapping).value();
    for (Eigen::Index k = 0; k < data.t.size() && !seen; ++k) {
      v1::StreamRequest batch;
      testing::add_sample(batch, data, k);
      v1::StreamResponse response;
      if (!stream->Write(batch) || !stream->Read(&response)) break;
    }
    stream->WritesDone();
    v1::StreamResponse rest;
    while (stream->Read(&rest)) {
    }
    stream->Finish();
  });

  Events events;
  res = http_->Get(("/api/v1/sessions/" + session.id() + "/events").c_str(), bearer(kAlpha),
                   [&](const char* data, std::size_t size) {
                     events.add(data, size);
                     for (const auto& [event, json] : events.events) {
                       if (event != "session" || json.find("\"estimate\"") == std::string::npos) continue;
                       seen = true;
                     }
                     return !seen;  // the browser goes away
                   });
  feeder.join();
  ASSERT_TRUE(seen) << events.events.size() << " events";
  // The last event: the session's info and the filter's estimate with its std, nz of each.
  const std::string& last = events.events.back().second;
  const auto info_at = last.find("\"info\":"), estimate_at = last.find(",\"estimate\":");
  ASSERT_NE(estimate_at, std::string::npos) << last;
  const auto info = parse<v1::SessionInfo>(last.substr(info_at + 7, estimate_at - info_at - 7));
  const auto estimate = parse<v1::Estimate>(last.substr(estimate_at + 12, last.size() - estimate_at - 13));
  EXPECT_EQ(info.id(), session.id());
  EXPECT_GT(info.measurements(), 0u);
  EXPECT_EQ(estimate.state_size(), 6);
  EXPECT_EQ(estimate.std_size(), 6);

  // The browser went away: the session goes on, and another tenant cannot watch it.
  res = http_->Get(("/api/v1/sessions/" + session.id()).c_str(), bearer(kAlpha));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 200);
  res = http_->Get(("/api/v1/sessions/" + session.id() + "/events").c_str(), bearer(kBeta));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 404);
}

// Event streams are long-lived calls like gRPC's: with max_tenant_streams 2,
// a gRPC session stream and one event stream take a tenant's places, and its
// next event stream is 429 naming the limit; another tenant is served, and
// the place comes back when the browser goes away.
TEST_F(HttpApiTest, EventStreamsCountWithGrpcStreamsAgainstATenantsCap) {
  daemon_.reset();
  start({"--max-tenant-streams", "2"});
  auto res = http_->Post("/api/v1/sessions", bearer(kAlpha), json_of(testing::two_tank_session()), "application/json");
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  const auto session = parse<v1::SessionInfo>(res->body);

  // Place 1: a gRPC stream, open (one batch answered) and held.
  auto ctx = as(kAlpha);
  auto stream = sessions_->Stream(ctx.get());
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  ASSERT_TRUE(stream->Write(open));
  const Dataset data = read_csv_file(kData + "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
  v1::StreamRequest batch;
  testing::add_sample(batch, data, 0);
  v1::StreamResponse response;
  ASSERT_TRUE(stream->Write(batch) && stream->Read(&response));

  // Place 2: an event stream, held until `release`.
  std::atomic<bool> receiving{false}, release{false};
  httplib::Client held_client("127.0.0.1", http_port_);
  std::thread held([&] {
    held_client.Get(("/api/v1/sessions/" + session.id() + "/events").c_str(), bearer(kAlpha),
                    [&](const char*, std::size_t) {
                      receiving = true;
                      return !release.load();
                    });
  });
  ASSERT_TRUE(testing::wait_until([&] { return receiving.load(); }, testing::kWait, "the event stream is open"));

  res = http_->Get(("/api/v1/sessions/" + session.id() + "/events").c_str(), bearer(kAlpha));
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 429) << res->body;
  const auto refused = parse<v1::Error>(res->body);
  EXPECT_EQ(refused.message().rfind("limit max_tenant_streams = 2 reached", 0), 0u) << refused.message();
  EXPECT_NE(refused.message().find("session event stream"), std::string::npos) << refused.message();

  // Another tenant has places of its own.
  res = http_->Post("/api/v1/sessions", bearer(kBeta), json_of(testing::two_tank_session()), "application/json");
  ASSERT_TRUE(res);
  const auto other = parse<v1::SessionInfo>(res->body);
  bool beta_served = false;
  res = http_->Get(("/api/v1/sessions/" + other.id() + "/events").c_str(), bearer(kBeta),
                   [&](const char*, std::size_t) {
                     beta_served = true;
                     return false;
                   });
  EXPECT_TRUE(beta_served);

  // The browser goes away: its place is given back.
  release = true;
  held.join();
  bool alpha_served = false;
  ASSERT_TRUE(testing::wait_until(
      [&] {
        http_->Get(("/api/v1/sessions/" + session.id() + "/events").c_str(), bearer(kAlpha),
                   [&](const char*, std::size_t) {
                     alpha_served = true;
                     return false;
                   });
        return alpha_served;
      },
      testing::kWait, "the event stream's place is free again"));
  stream->WritesDone();
  while (stream->Read(&response)) {
  }
  stream->Finish();
}

// Live retuning: two sessions fed the same record; one gets a large R over
// the API between two measurements. At the next measurement (the same for
// both, its h1 pushed off by 0.05) the retuned filter corrects its state
// toward it far less: its gain responded. The retuning is in its history.
TEST_F(HttpApiTest, ARetunedSessionsGainRespondsAtTheNextMeasurement) {
  ColumnMapping mapping;
  mapping.inputs = {"F1", "F2"};
  mapping.outputs = {"h1", "h2"};
  const Dataset data = read_csv_file(kData + "/two_tank.csv", mapping).value();
  constexpr int kSamples = 200;
  struct Fed {
    std::string id;
    v1::MeasurementResult last;
  };
  // Creates a session and streams the first samples into it, then `extra`.
  auto feed = [&](const std::string& id, int from, int to, double h1_offset) {
    auto ctx = as(kAlpha);
    auto stream = sessions_->Stream(ctx.get());
    v1::StreamRequest open;
    open.mutable_open()->set_session_id(id);
    EXPECT_TRUE(stream->Write(open));
    v1::StreamRequest batch;
    for (int k = from; k < to; ++k) testing::add_sample(batch, data, k);
    batch.mutable_batch()->mutable_measurements()->rbegin()->set_y(0, data.y(0, to - 1) + h1_offset);
    v1::StreamResponse response;
    EXPECT_TRUE(stream->Write(batch));
    EXPECT_TRUE(stream->Read(&response));
    stream->WritesDone();
    EXPECT_TRUE(stream->Finish().ok());
    return response.results(response.results_size() - 1);
  };
  std::vector<Fed> sessions(2);
  for (Fed& s : sessions) {
    v1::SessionInfo info;
    ASSERT_TRUE(sessions_->CreateSession(as(kAlpha).get(), testing::two_tank_session(), &info).ok());
    s.id = info.id();
    feed(s.id, 0, kSamples, 0.0);
  }
  auto res = http_->Post(("/api/v1/sessions/" + sessions[1].id + "/retune").c_str(), bearer(kAlpha),
                         R"({"r": {"diagonal": {"values": [1000, 1000]}}})", "application/json");
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  const auto retuned = parse<v1::SessionInfo>(res->body);
  ASSERT_EQ(retuned.retunings_size(), 1);
  EXPECT_EQ(retuned.retunings(0).measurements(), static_cast<std::uint64_t>(kSamples));
  EXPECT_DOUBLE_EQ(retuned.retunings(0).t(), data.t[kSamples - 1]);
  EXPECT_EQ(retuned.retunings(0).r().diagonal().values(0), 1000);
  // The noise it runs with now, what a retuning starts from: r as retuned, q as created (none given: 0, nz x nz).
  ASSERT_EQ(retuned.r().diagonal().values_size(), 2);
  EXPECT_EQ(retuned.r().diagonal().values(1), 1000);
  ASSERT_EQ(retuned.q().diagonal().values_size(), 6);
  EXPECT_EQ(retuned.q().diagonal().values(0), 0.0);

  for (Fed& s : sessions) s.last = feed(s.id, kSamples, kSamples + 1, 0.05);
  const v1::Estimate& as_created = sessions[0].last.estimate();
  const v1::Estimate& with_large_r = sessions[1].last.estimate();
  // The same prior and innovation (the retuning changed no estimate)...
  EXPECT_DOUBLE_EQ(as_created.y_predicted(0), with_large_r.y_predicted(0));
  EXPECT_NEAR(as_created.innovation(0), 0.05, 0.01);
  // ...and a correction toward the measurement a gain's ratio apart.
  const double correction = as_created.state(0) - as_created.y_predicted(0);
  const double retuned_correction = with_large_r.state(0) - with_large_r.y_predicted(0);
  EXPECT_GT(correction, 0.0);
  EXPECT_LT(std::abs(retuned_correction), correction / 100) << correction << " " << retuned_correction;

  // Over gRPC: the history, and weights a session would refuse are refused, nothing changed.
  v1::GetSessionRequest get;
  get.set_id(sessions[1].id);
  v1::SessionInfo info;
  ASSERT_TRUE(sessions_->GetSession(as(kAlpha).get(), get, &info).ok());
  EXPECT_EQ(info.retunings_size(), 1);
  EXPECT_EQ(info.r().diagonal().values(0), 1000);
  {
    v1::SessionInfo created;
    v1::GetSessionRequest first;
    first.set_id(sessions[0].id);
    ASSERT_TRUE(sessions_->GetSession(as(kAlpha).get(), first, &created).ok());
    ASSERT_EQ(created.r().diagonal().values_size(), 2);
    EXPECT_EQ(created.r().diagonal().values(0), 1e-3);
  }
  v1::RetuneSessionRequest wrong;
  wrong.set_id(sessions[1].id);
  wrong.mutable_r()->mutable_diagonal()->add_values(1.0);  // ny = 2
  EXPECT_EQ(sessions_->RetuneSession(as(kAlpha).get(), wrong, &info).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  wrong.mutable_r()->mutable_diagonal()->add_values(-1.0);
  EXPECT_EQ(sessions_->RetuneSession(as(kAlpha).get(), wrong, &info).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  ASSERT_TRUE(sessions_->GetSession(as(kAlpha).get(), get, &info).ok());
  EXPECT_EQ(info.retunings_size(), 1);
  res = http_->Post(("/api/v1/sessions/" + sessions[1].id + "/retune").c_str(), bearer(kBeta),
                    R"({"r": {"diagonal": {"values": [1, 1]}}})", "application/json");
  ASSERT_TRUE(res);
  EXPECT_EQ(res->status, 404);
}

TEST(HttpTls, TheWorkbenchIsServedWithTheGrpcCertificates) {
  TempDir dir;
  DaemonProcess daemon(dir.path() / "data",
                       {"--tls-cert", kTls + "/server.pem", "--tls-key", kTls + "/server.key", "--tokens-file",
                        write_tokens(dir.path()), "--http-listen", "127.0.0.1:0", "--http-port-file",
                        (dir.path() / "http_port").string()});
  daemon.start();
  int port = 0;
  std::ifstream(dir.path() / "http_port") >> port;
  ASSERT_GT(port, 0);
  httplib::SSLClient tls("localhost", port);
  tls.set_ca_cert_path((kTls + "/ca.pem").c_str());
  tls.enable_server_certificate_verification(true);
  auto res = tls.Get("/api/v1/models", bearer(kAlpha));
  ASSERT_TRUE(res) << httplib::to_string(res.error());
  EXPECT_EQ(res->status, 200);
  // Not in plain text, and not to a client that does not trust the CA.
  httplib::Client plain("127.0.0.1", port);
  auto refused = plain.Get("/healthz");
  EXPECT_TRUE(!refused || refused->status != 200);
  httplib::SSLClient stranger("localhost", port);
  stranger.set_ca_cert_path((kTls + "/stranger.pem").c_str());
  stranger.enable_server_certificate_verification(true);
  EXPECT_FALSE(stranger.Get("/healthz"));
}

TEST(HttpStartup, RefusesPlainHttpOffLoopbackUnlessAskedFor) {
  TempDir dir;
  const std::string common = "--listen 127.0.0.1:0 --data-dir " + (dir.path() / "data").string() +
                             " --models-dir " RICCATI_TEST_PLUGIN_DIR " --tokens-file " + write_tokens(dir.path());
  const testing::Outcome r = testing::riccatid(common + " --http-listen 0.0.0.0:0");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("needs TLS"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("http_public"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace riccati
