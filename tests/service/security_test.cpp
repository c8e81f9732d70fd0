// Security of a real riccatid on loopback: bearer tokens checked before
// anything is processed, tenants that never see each other's objects, TLS
// and mutual TLS, and the refusals at start (plain TCP or no authentication
// off loopback, a tokens file with a token in clear).
#include <gtest/gtest.h>
#include <openssl/evp.h>

#include <array>
#include <cstdio>
#include <fstream>
#include <future>
#include <grpcpp/generic/generic_stub.h>
#include <sstream>

#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/models.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/daemon_fixture.hpp"
#include "support/requests.hpp"

namespace riccati {
namespace {

using testing::DaemonProcess;
using testing::read_file;
using testing::TempDir;

const std::string kData = RICCATI_TEST_DATA_DIR;
const std::string kTls = RICCATI_TEST_TLS_DIR;  // the keys with mode 0600
const std::string kAlpha = "alpha-7f3c9e2b4d1a";  // tokens of two tenants
const std::string kBeta = "beta-0c5e8a6f2b9d";

// "sha256:<hex>", computed here independently of the daemon's code.
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
  std::ofstream(path) << "# tenant digest\n"
                      << "alpha " << digest(kAlpha) << "\n\n"
                      << "beta " << digest(kBeta) << "\n";
  return path.string();
}

// A context that carries `token` (none if empty).
std::unique_ptr<grpc::ClientContext> as(const std::string& token) {
  auto ctx = std::make_unique<grpc::ClientContext>();
  if (!token.empty()) ctx->AddMetadata("authorization", "Bearer " + token);
  ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  return ctx;
}

class TokensTest : public ::testing::Test {
 protected:
  void SetUp() override {
    daemon_ = std::make_unique<DaemonProcess>(dir_.path() / "data",
                                              std::vector<std::string>{"--tokens-file", write_tokens(dir_.path())});
    daemon_->start();
    models_ = v1::ModelService::NewStub(daemon_->channel());
    datasets_ = v1::DatasetService::NewStub(daemon_->channel());
    jobs_ = v1::JobService::NewStub(daemon_->channel());
    sessions_ = v1::SessionService::NewStub(daemon_->channel());
  }

  std::string upload_two_tank(const std::string& token) {
    auto ctx = as(token);
    v1::DatasetInfo info;
    const grpc::Status s = testing::upload_dataset(*datasets_, ctx.get(), "two_tank.csv",
                                                   read_file(kData + "/two_tank.csv"), {"F1", "F2"}, {"h1", "h2"}, &info);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return info.id();
  }

  TempDir dir_;
  std::unique_ptr<DaemonProcess> daemon_;
  std::unique_ptr<v1::ModelService::Stub> models_;
  std::unique_ptr<v1::DatasetService::Stub> datasets_;
  std::unique_ptr<v1::JobService::Stub> jobs_;
  std::unique_ptr<v1::SessionService::Stub> sessions_;
};

TEST_F(TokensTest, MissingOrWrongTokensAreUnauthenticatedAndNothingIsProcessed) {
  v1::ListModelsResponse models;
  grpc::Status s = models_->ListModels(as("").get(), {}, &models);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_NE(s.error_message().find("Bearer"), std::string::npos) << s.error_message();
  s = models_->ListModels(as("not-a-token").get(), {}, &models);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  {
    auto ctx = std::make_unique<grpc::ClientContext>();
    ctx->AddMetadata("authorization", kAlpha);  // no scheme
    EXPECT_EQ(models_->ListModels(ctx.get(), {}, &models).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  }
  // An unauthenticated submission stores nothing: the tenant's list stays empty.
  v1::Job job;
  EXPECT_EQ(jobs_->SubmitIdentification(as("").get(), testing::hensen_spec("ds-x"), &job).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
  v1::SessionInfo session;
  EXPECT_EQ(sessions_->CreateSession(as(kBeta + "x").get(), testing::two_tank_session(), &session).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
  v1::ListSessionsResponse listed;
  ASSERT_TRUE(sessions_->ListSessions(as(kBeta).get(), {}, &listed).ok());
  EXPECT_EQ(listed.sessions_size(), 0);
  // A valid token works.
  s = models_->ListModels(as(kAlpha).get(), {}, &models);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(models.models_size(), 4);
}

TEST_F(TokensTest, HealthChecksNeedNoToken) {
  // grpc.health.v1.Health/Check with an empty request: what load balancers
  // and orchestrators send, without any token.
  grpc::GenericStub stub(daemon_->channel());
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  grpc::Slice empty("");
  const grpc::ByteBuffer request(&empty, 1);  // an empty HealthCheckRequest
  grpc::ByteBuffer response;
  std::promise<grpc::Status> done;
  stub.UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&](grpc::Status st) { done.set_value(st); });
  const grpc::Status s = done.get_future().get();
  ASSERT_TRUE(s.ok()) << s.error_message();
  std::vector<grpc::Slice> slices;
  ASSERT_TRUE(response.Dump(&slices).ok());
  std::string bytes;
  for (const auto& slice : slices) bytes.append(reinterpret_cast<const char*>(slice.begin()), slice.size());
  EXPECT_EQ(bytes, std::string("\x08\x01", 2));  // status: SERVING
}

TEST_F(TokensTest, TenantsNeverSeeEachOthersObjects) {
  const std::string dataset = upload_two_tank(kAlpha);
  v1::Job job;
  ASSERT_TRUE(jobs_->SubmitIdentification(as(kAlpha).get(), testing::hensen_spec(dataset, 1), &job).ok());
  v1::SessionInfo session;
  ASSERT_TRUE(sessions_->CreateSession(as(kAlpha).get(), testing::two_tank_session(), &session).ok());

  // Beta gets NOT_FOUND, with the message an id that never existed gets.
  auto expect_not_found = [](const grpc::Status& s, const std::string& what) {
    EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << what << ": " << s.error_message();
  };
  v1::GetDatasetRequest get_dataset;
  get_dataset.set_id(dataset);
  v1::DatasetInfo dataset_info;
  const grpc::Status theirs = datasets_->GetDataset(as(kBeta).get(), get_dataset, &dataset_info);
  expect_not_found(theirs, "GetDataset");
  get_dataset.set_id("ds-0000000000000000");
  const grpc::Status nobodys = datasets_->GetDataset(as(kBeta).get(), get_dataset, &dataset_info);
  EXPECT_EQ(theirs.error_message().find(dataset), nobodys.error_message().find("ds-0000000000000000"));
  v1::DatasetData data;
  get_dataset.set_id(dataset);
  expect_not_found(datasets_->GetDatasetData(as(kBeta).get(), get_dataset, &data), "GetDatasetData");
  v1::DeleteDatasetRequest del;
  del.set_id(dataset);
  v1::DeleteDatasetResponse deleted;
  expect_not_found(datasets_->DeleteDataset(as(kBeta).get(), del, &deleted), "DeleteDataset");
  v1::Job other;
  expect_not_found(jobs_->SubmitIdentification(as(kBeta).get(), testing::hensen_spec(dataset, 1), &other),
                   "SubmitIdentification on another tenant's dataset");
  v1::GetJobRequest get_job;
  get_job.set_id(job.id());
  expect_not_found(jobs_->GetJob(as(kBeta).get(), get_job, &other), "GetJob");
  v1::CancelJobRequest cancel;
  cancel.set_id(job.id());
  expect_not_found(jobs_->CancelJob(as(kBeta).get(), cancel, &other), "CancelJob");
  v1::GetResultRequest get_result;
  get_result.set_job_id(job.id());
  v1::JobResult result;
  expect_not_found(jobs_->GetResult(as(kBeta).get(), get_result, &result), "GetResult");
  {
    auto ctx = as(kBeta);
    v1::WatchJobRequest watch;
    watch.set_id(job.id());
    auto reader = jobs_->WatchJob(ctx.get(), watch);
    while (reader->Read(&other)) {
      ADD_FAILURE() << "beta watched alpha's job";
    }
    expect_not_found(reader->Finish(), "WatchJob");
  }
  v1::GetSessionRequest get_session;
  get_session.set_id(session.id());
  v1::SessionInfo info;
  expect_not_found(sessions_->GetSession(as(kBeta).get(), get_session, &info), "GetSession");
  v1::CloseSessionRequest close;
  close.set_id(session.id());
  v1::CloseSessionResponse closed;
  expect_not_found(sessions_->CloseSession(as(kBeta).get(), close, &closed), "CloseSession");
  {
    auto ctx = as(kBeta);
    auto stream = sessions_->Stream(ctx.get());
    v1::StreamRequest open;
    open.mutable_open()->set_session_id(session.id());
    stream->Write(open);
    stream->WritesDone();
    v1::StreamResponse response;
    EXPECT_FALSE(stream->Read(&response));
    expect_not_found(stream->Finish(), "Stream into another tenant's session");
  }
  // Lists show only one's own.
  v1::ListDatasetsResponse beta_datasets;
  ASSERT_TRUE(datasets_->ListDatasets(as(kBeta).get(), {}, &beta_datasets).ok());
  EXPECT_EQ(beta_datasets.datasets_size(), 0);
  v1::ListJobsResponse beta_jobs;
  ASSERT_TRUE(jobs_->ListJobs(as(kBeta).get(), {}, &beta_jobs).ok());
  EXPECT_EQ(beta_jobs.jobs_size(), 0);
  v1::ListSessionsResponse beta_sessions;
  ASSERT_TRUE(sessions_->ListSessions(as(kBeta).get(), {}, &beta_sessions).ok());
  EXPECT_EQ(beta_sessions.sessions_size(), 0);

  // Alpha still has everything.
  get_job.set_id(job.id());
  EXPECT_TRUE(jobs_->GetJob(as(kAlpha).get(), get_job, &other).ok());
  EXPECT_TRUE(sessions_->GetSession(as(kAlpha).get(), get_session, &info).ok());
  v1::ListDatasetsResponse alpha_datasets;
  ASSERT_TRUE(datasets_->ListDatasets(as(kAlpha).get(), {}, &alpha_datasets).ok());
  EXPECT_EQ(alpha_datasets.datasets_size(), 1);
}

// ---------------------------------------------------------------------------
// TLS

std::shared_ptr<grpc::ChannelCredentials> tls_client(const std::string& cert = "", const std::string& key = "") {
  grpc::SslCredentialsOptions options;
  options.pem_root_certs = read_file(kTls + "/ca.pem");
  if (!cert.empty()) {
    options.pem_cert_chain = read_file(cert);
    options.pem_private_key = read_file(key);
  }
  return grpc::SslCredentials(options);
}

grpc::Status list_models(const std::shared_ptr<grpc::Channel>& channel, const std::string& token = "") {
  auto stub = v1::ModelService::NewStub(channel);
  auto ctx = as(token);
  ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  v1::ListModelsResponse models;
  return stub->ListModels(ctx.get(), {}, &models);
}

TEST(Tls, ServesTlsClientsThatTrustItsCaAndOnlyThose) {
  TempDir dir;
  DaemonProcess daemon(dir.path() / "data", {"--tls-cert", kTls + "/server.pem", "--tls-key", kTls + "/server.key"});
  daemon.start();
  const grpc::Status tls = list_models(daemon.channel(tls_client()));
  EXPECT_TRUE(tls.ok()) << tls.error_message();
  // A plain-text client cannot talk to a TLS port.
  EXPECT_FALSE(list_models(daemon.channel()).ok());
  // Nor a client that does not trust the server's CA.
  grpc::SslCredentialsOptions untrusting;
  untrusting.pem_root_certs = read_file(kTls + "/stranger.pem");
  EXPECT_FALSE(list_models(daemon.channel(grpc::SslCredentials(untrusting))).ok());
}

TEST(Tls, MutualTlsRequiresAClientCertificateFromItsCa) {
  TempDir dir;
  DaemonProcess daemon(dir.path() / "data", {"--tls-cert", kTls + "/server.pem", "--tls-key", kTls + "/server.key",
                                             "--tls-client-ca", kTls + "/ca.pem", "--tokens-file",
                                             write_tokens(dir.path())});
  daemon.start();
  const grpc::Status mutual = list_models(daemon.channel(tls_client(kTls + "/client.pem", kTls + "/client.key")), kAlpha);
  EXPECT_TRUE(mutual.ok()) << mutual.error_message();
  EXPECT_FALSE(list_models(daemon.channel(tls_client()), kAlpha).ok()) << "no client certificate";
  EXPECT_FALSE(list_models(daemon.channel(tls_client(kTls + "/stranger.pem", kTls + "/stranger.key")), kAlpha).ok())
      << "a client certificate from an unknown CA";
  // The certificate does not replace the token.
  EXPECT_EQ(list_models(daemon.channel(tls_client(kTls + "/client.pem", kTls + "/client.key"))).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
}

// ---------------------------------------------------------------------------
// Refusals at start

using testing::Outcome;
using testing::riccatid;

TEST(Startup, RefusesPlainTcpOrNoAuthenticationOffLoopback) {
  TempDir dir;
  const std::string common = "--data-dir " + (dir.path() / "data").string() + " --models-dir " RICCATI_TEST_PLUGIN_DIR;
  Outcome r = riccatid("--listen 0.0.0.0:0 " + common + " --tokens-file " + write_tokens(dir.path()));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("needs TLS"), std::string::npos) << r.output;
  r = riccatid("--listen 0.0.0.0:0 " + common + " --tls-cert " + kTls + "/server.pem --tls-key " + kTls +
               "/server.key");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("needs a tokens file"), std::string::npos) << r.output;
}

// TLS files gRPC would refuse only when binding ("cannot listen on ...
// (address in use or invalid?)"): the error names the file and the fault.
TEST(Startup, RefusesBadTlsFilesNamingTheFileAndTheFault) {
  TempDir dir;
  const auto junk = dir.path() / "junk.pem";
  const auto empty = dir.path() / "empty.key";
  std::ofstream(junk) << "this is not a certificate\n";
  std::ofstream(empty).flush();
  std::filesystem::permissions(empty, std::filesystem::perms::owner_read | std::filesystem::perms::owner_write);
  const std::string common = "--listen 127.0.0.1:0 --data-dir " + (dir.path() / "data").string() +
                             " --models-dir " RICCATI_TEST_PLUGIN_DIR;
  struct Case {
    std::string args, expected;
  };
  const Case cases[] = {
      {"--tls-cert " + junk.string() + " --tls-key " + kTls + "/server.key",
       "tls_cert " + junk.string() + " holds no PEM certificate"},
      {"--tls-cert " + kTls + "/server.pem --tls-key " + empty.string(), "tls_key " + empty.string() + " is empty"},
      {"--tls-cert " + kTls + "/server.pem --tls-key " + kTls + "/stranger.key",
       "tls_key " + kTls + "/stranger.key is not the key of the certificate in tls_cert " + kTls + "/server.pem"},
      {"--tls-cert " + kTls + "/server.pem --tls-key " + kTls + "/server.key --tls-client-ca " + junk.string(),
       "tls_client_ca " + junk.string() + " holds no PEM certificate"},
  };
  for (const Case& c : cases) {
    const Outcome r = riccatid(common + " " + c.args);
    EXPECT_NE(r.exit_code, 0) << c.args;
    EXPECT_NE(r.output.find(c.expected), std::string::npos) << c.args << "\n" << r.output;
    EXPECT_EQ(r.output.find("address in use"), std::string::npos) << r.output;
  }
  // A models "directory" that is a file is said to be one.
  const Outcome r = riccatid("--listen 127.0.0.1:0 --data-dir " + (dir.path() / "data").string() + " --models-dir " +
                             junk.string());
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find(junk.string() + " is a file, not a directory"), std::string::npos) << r.output;
}

// /metrics has neither TLS nor tokens: off loopback only when asked for.
TEST(Startup, RefusesMetricsOffLoopbackUnlessAskedFor) {
  TempDir dir;
  const std::string common = "--listen 127.0.0.1:0 --data-dir " + (dir.path() / "data").string() +
                             " --models-dir " RICCATI_TEST_PLUGIN_DIR " --metrics-listen 0.0.0.0:0";
  const Outcome r = riccatid(common);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("metrics_listen 0.0.0.0:0 is not a loopback address"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("metrics_public: true (--metrics-public)"), std::string::npos) << r.output;

  DaemonProcess daemon(dir.path() / "data", {"--metrics-listen", "0.0.0.0:0", "--metrics-public"});
  daemon.start();  // throws if it refuses
  EXPECT_TRUE(list_models(daemon.channel()).ok());
}

// Whoever can write the tokens file can add a token for any tenant.
TEST(Startup, RefusesATokensFileOthersCanWrite) {
  TempDir dir;
  const std::string tokens = write_tokens(dir.path());
  using std::filesystem::perms;
  for (const perms mode : {perms::group_write, perms::others_write}) {
    std::filesystem::permissions(tokens, perms::owner_read | perms::owner_write | mode);
    const Outcome r = riccatid("--listen 127.0.0.1:0 --data-dir " + (dir.path() / "data").string() +
                               " --models-dir " RICCATI_TEST_PLUGIN_DIR " --tokens-file " + tokens);
    EXPECT_NE(r.exit_code, 0);
    EXPECT_NE(r.output.find("tokens file " + tokens + " is writable by its group or others"), std::string::npos)
        << r.output;
    EXPECT_NE(r.output.find("chmod go-w " + tokens), std::string::npos) << r.output;
  }
}

TEST(Startup, RefusesATlsKeyOthersCanReadOrWrite) {
  TempDir dir;
  const auto key = dir.path() / "server.key";
  std::filesystem::copy_file(kTls + "/server.key", key);
  using std::filesystem::perms;
  for (const perms mode : {perms::others_read, perms::group_write, perms::others_write}) {
    std::filesystem::permissions(key, perms::owner_read | perms::owner_write | mode);
    const Outcome r = riccatid("--listen 127.0.0.1:0 --data-dir " + (dir.path() / "data").string() +
                               " --models-dir " RICCATI_TEST_PLUGIN_DIR " --tls-cert " + kTls + "/server.pem --tls-key " +
                               key.string());
    EXPECT_NE(r.exit_code, 0);
    EXPECT_NE(r.output.find("tls_key " + key.string() + " has mode 0"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("chmod 600 " + key.string()), std::string::npos) << r.output;
  }
}

TEST(Startup, RefusesATokensFileWithATokenInClear) {
  TempDir dir;
  const auto tokens = dir.path() / "tokens";
  std::ofstream(tokens) << "alpha " << kAlpha << "\n";
  const Outcome r = riccatid("--listen 127.0.0.1:0 --data-dir " + (dir.path() / "data").string() + " --tokens-file " +
                         tokens.string());
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("line 1"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("never in clear"), std::string::npos) << r.output;
}

TEST(Startup, HashTokenPrintsTheTokensFileLine) {
  const std::string command = "echo " + kAlpha + " | " + std::string(RICCATI_DAEMON_BIN) + " --hash-token --tenant alpha";
  std::FILE* pipe = ::popen(command.c_str(), "r");
  std::array<char, 256> line{};
  ASSERT_NE(std::fgets(line.data(), line.size(), pipe), nullptr);
  ::pclose(pipe);
  EXPECT_EQ(std::string(line.data()), "alpha " + digest(kAlpha) + "\n");
}

}  // namespace
}  // namespace riccati
