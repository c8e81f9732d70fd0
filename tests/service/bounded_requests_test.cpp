// What one client can make a real riccatid store, hold or send (issue 30):
// every string it stores has a size, a refused request stores nothing, the
// result size is bounded before the work from all the result will hold,
// uploads and result reads are shared out, a deleted model's revisions go,
// a stream's answer is bounded, no server path reaches a tenant, ReloadModels
// is an operator's, and files riccatid reads at start must be regular files.
// Each test reproduces the defect the issue reports and asserts its bound;
// the store's own rows are counted from the SQLite file after the daemon stops.
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/stat.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <fstream>
#include <future>
#include <sstream>
#include <thread>

#include "engine/sha256.hpp"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/models.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/daemon_fixture.hpp"
#include "support/metrics.hpp"
#include "support/requests.hpp"
#include "support/wait.hpp"

namespace riccati {
namespace {

using testing::DaemonProcess;
using testing::TempDir;
using namespace std::chrono_literals;

const std::string kData = RICCATI_TEST_DATA_DIR;

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// One number from the daemon's SQLite file (stopped, or not: WAL readers see commits).
std::int64_t count_rows(const std::filesystem::path& db, const std::string& sql) {
  sqlite3* handle = nullptr;
  EXPECT_EQ(sqlite3_open_v2(db.c_str(), &handle, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* q = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(handle, sql.c_str(), -1, &q, nullptr), SQLITE_OK) << sqlite3_errmsg(handle);
  std::int64_t n = -1;
  if (sqlite3_step(q) == SQLITE_ROW) n = sqlite3_column_int64(q, 0);
  sqlite3_finalize(q);
  sqlite3_close(handle);
  return n;
}

// A two-tenant riccatid (alpha, beta) with an operator's token (ops).
class BoundedRequests : public ::testing::Test {
 protected:
  void start(std::vector<std::string> flags = {}) {
    const auto tokens = dir_.path() / "tokens";
    std::ofstream(tokens) << "alpha sha256:" << sha256_hex("alpha-token") << "\n"
                          << "beta sha256:" << sha256_hex("beta-token") << "\n"
                          << "ops sha256:" << sha256_hex("ops-token") << " operator\n";
    flags.insert(flags.begin(), {"--tokens-file", tokens.string()});
    daemon_ = std::make_unique<DaemonProcess>(dir_.path() / "data", flags);
    daemon_->start();
    connect();
  }
  void connect() {
    datasets_ = v1::DatasetService::NewStub(daemon_->channel());
    jobs_ = v1::JobService::NewStub(daemon_->channel());
    models_ = v1::ModelService::NewStub(daemon_->channel());
    sessions_ = v1::SessionService::NewStub(daemon_->channel());
  }
  void stop() {
    datasets_.reset();
    jobs_.reset();
    models_.reset();
    sessions_.reset();
    ASSERT_EQ(daemon_->stop(), 0) << daemon_->exit_report();
  }
  std::filesystem::path database() const { return dir_.path() / "data" / "riccati.db"; }

  static std::unique_ptr<grpc::ClientContext> as(const std::string& tenant) {
    auto ctx = std::make_unique<grpc::ClientContext>();
    ctx->AddMetadata("authorization", "Bearer " + tenant + "-token");
    ctx->set_deadline(std::chrono::system_clock::now() + 60s);
    return ctx;
  }

  std::string upload(const std::string& tenant, const std::string& file) {
    v1::DatasetInfo info;
    const grpc::Status s = testing::upload_dataset(*datasets_, as(tenant).get(), file, read_text(kData + "/" + file),
                                                   {"F1", "F2"}, {"h1", "h2"}, &info);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return info.id();
  }

  grpc::Status submit(const std::string& tenant, const v1::IdentificationSpec& spec, v1::Job* job) {
    return jobs_->SubmitIdentification(as(tenant).get(), spec, job);
  }

  v1::Job wait_for_end(const std::string& tenant, const std::string& id) {
    v1::Job job;
    EXPECT_TRUE(testing::wait_until(
        [&] {
          v1::GetJobRequest get;
          get.set_id(id);
          const grpc::Status s = jobs_->GetJob(as(tenant).get(), get, &job);
          // Ended: not queued, running, or cancelling (a cancelled job that has not stopped yet).
          return s.ok() && (job.state() == v1::JOB_STATE_SUCCEEDED || job.state() == v1::JOB_STATE_FAILED ||
                            job.state() == v1::JOB_STATE_CANCELLED);
        },
        testing::kSanitized ? 600s : 120s, "job " + id + " ends"));
    return job;
  }

  TempDir dir_;
  std::unique_ptr<DaemonProcess> daemon_;
  std::unique_ptr<v1::DatasetService::Stub> datasets_;
  std::unique_ptr<v1::JobService::Stub> jobs_;
  std::unique_ptr<v1::ModelService::Stub> models_;
  std::unique_ptr<v1::SessionService::Stub> sessions_;
};

// Item 3: a request_id has a size, and a submit refused by a limit claims
// no request_id (10 refused submits with 20 MB ids stored 460 MB before).
TEST_F(BoundedRequests, RequestIdsAreBoundedAndARefusedSubmitStoresNothing) {
  start({"--max-tenant-jobs", "1"});
  const std::string ds = upload("alpha", "two_tank.csv");

  v1::IdentificationSpec long_id = testing::hensen_spec(ds, 1);
  long_id.set_request_id(std::string(20 << 20, 'r'));
  v1::Job job;
  grpc::Status s = submit("alpha", long_id, &job);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("request_id is 20971520 bytes long; it may be at most 128"), std::string::npos)
      << s.error_message();

  // One job holds the tenant's only place; the submits after it are refused.
  v1::IdentificationSpec running = testing::hensen_spec(ds, 400);
  running.set_request_id("holds-the-place");
  v1::Job first;
  ASSERT_TRUE(submit("alpha", running, &first).ok());
  for (int i = 0; i < 10; ++i) {
    v1::IdentificationSpec refused = testing::hensen_spec(ds, 1);
    refused.set_request_id("refused-" + std::to_string(i));
    s = submit("alpha", refused, &job);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
    EXPECT_NE(s.error_message().find("max_tenant_jobs"), std::string::npos) << s.error_message();
  }
  // A retry of the accepted one is answered with its job, limit or not.
  v1::Job again;
  s = submit("alpha", running, &again);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(again.id(), first.id());

  v1::CancelJobRequest cancel;
  cancel.set_id(first.id());
  v1::Job cancelled;
  ASSERT_TRUE(jobs_->CancelJob(as("alpha").get(), cancel, &cancelled).ok());
  wait_for_end("alpha", first.id());
  // Refused once, accepted now: a new job (its id was never claimed).
  v1::IdentificationSpec retried = testing::hensen_spec(ds, 1);
  retried.set_request_id("refused-0");
  s = submit("alpha", retried, &job);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_NE(job.id(), first.id());
  wait_for_end("alpha", job.id());
  stop();
  EXPECT_EQ(count_rows(database(), "SELECT count(*) FROM request_ids"), 2)
      << "only the two accepted submits' request ids are stored";
  EXPECT_EQ(count_rows(database(), "SELECT count(*) FROM request_ids WHERE request_id LIKE 'refused-%'"), 1);
}

// Item 3: names a client stores are bounded like request ids, and so is a
// job's spec as stored.
TEST_F(BoundedRequests, NamesAndStoredSpecsAreBounded) {
  start({"--max-stored-request-bytes", "4096"});
  v1::DatasetInfo info;
  grpc::Status s = testing::upload_dataset(*datasets_, as("alpha").get(), std::string(300, 'n') + ".csv",
                                           read_text(kData + "/two_tank.csv"), {"F1", "F2"}, {"h1", "h2"}, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("the dataset's name is 304 bytes long; it may be at most 256"), std::string::npos)
      << s.error_message();

  const std::string ds = upload("alpha", "two_tank.csv");
  v1::IdentificationSpec spec = testing::hensen_spec(ds, 1);
  for (int i = 0; i < 600; ++i) {  // 600 excluded ranges: about 5 KB encoded
    v1::SampleRange* range = spec.mutable_mask()->add_excluded();
    range->set_first(2 * i + 10);
    range->set_end(2 * i + 11);
  }
  v1::Job job;
  s = submit("alpha", spec, &job);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
  EXPECT_NE(s.error_message().find("limit max_stored_request_bytes = 4096 reached: the job's spec is"),
            std::string::npos)
      << s.error_message();

  v1::CreateSessionRequest session = testing::two_tank_session();
  session.set_request_id(std::string(129, 's'));
  v1::SessionInfo made;
  s = sessions_->CreateSession(as("alpha").get(), session, &made);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("request_id is 129 bytes long"), std::string::npos) << s.error_message();
}

// Item 5: the size a job's result will have, checked at submit, is an upper
// bound for every method and kind: with max_result_bytes one byte below
// what a job's result took, the same job is refused before it runs.
TEST_F(BoundedRequests, TheEstimatedResultSizeBoundsTheResultOfEveryMethod) {
  start();
  const std::string ds = upload("alpha", "two_tank.csv");
  const std::string noisy = upload("alpha", "two_tank_noisy.csv");
  v1::IdentificationSpec filter = testing::hensen_spec(ds, 3);
  v1::IdentificationSpec oe = testing::hensen_spec(ds, 1);
  oe.set_method(v1::IDENTIFICATION_METHOD_OE);
  oe.clear_passes();
  oe.clear_p0();
  oe.mutable_filter()->clear_r();
  oe.mutable_estimation()->set_max_iterations(5);
  v1::Experiment* second = oe.add_experiments();
  second->set_dataset_id(noisy);
  second->mutable_initial_state()->set_first_measurement(true);
  v1::IdentificationSpec ml = oe;
  ml.set_method(v1::IDENTIFICATION_METHOD_ML);
  ml.clear_experiments();
  for (double r : {1e-4, 1e-4}) ml.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(r);
  ml.mutable_estimation()->set_max_iterations(3);
  v1::SmoothingSpec smoothing;
  smoothing.set_model("two_tank");
  smoothing.set_dataset_id(ds);
  for (double r : {1e-3, 1e-3}) smoothing.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(r);
  smoothing.mutable_initial_state()->set_first_measurement(true);
  smoothing.set_full_covariance(true);
  v1::ValidationSpec validation;
  validation.set_model("two_tank");
  validation.set_dataset_id(ds);
  for (double v : {10.0, 5.0, 0.0791, 0.1342}) validation.mutable_theta()->add_values(v);
  validation.mutable_initial_state()->set_first_measurement(true);

  // Each kind submitted, run, and its result's size read.
  auto submit_any = [&](int which, v1::Job* job) {
    auto ctx = as("alpha");
    switch (which) {
      case 0: return jobs_->SubmitIdentification(ctx.get(), filter, job);
      case 1: return jobs_->SubmitIdentification(ctx.get(), oe, job);
      case 2: return jobs_->SubmitIdentification(ctx.get(), ml, job);
      case 3: return jobs_->SubmitSmoothing(ctx.get(), smoothing, job);
      default: return jobs_->SubmitValidation(ctx.get(), validation, job);
    }
  };
  const char* names[] = {"iterated filter", "output error", "maximum likelihood", "smoothing", "validation"};
  std::vector<std::size_t> sizes;
  for (int which = 0; which < 5; ++which) {
    v1::Job job;
    ASSERT_TRUE(submit_any(which, &job).ok()) << names[which];
    ASSERT_EQ(wait_for_end("alpha", job.id()).state(), v1::JOB_STATE_SUCCEEDED) << names[which];
    v1::GetResultRequest get;
    get.set_job_id(job.id());
    v1::JobResult result;
    ASSERT_TRUE(jobs_->GetResult(as("alpha").get(), get, &result).ok()) << names[which];
    sizes.push_back(result.ByteSizeLong());
  }
  stop();
  // Data and datasets are kept: the same jobs against a limit just below each result.
  for (int which = 0; which < 5; ++which) {
    daemon_ = std::make_unique<DaemonProcess>(
        dir_.path() / "data",
        std::vector<std::string>{"--tokens-file", (dir_.path() / "tokens").string(), "--max-result-bytes",
                                 std::to_string(sizes[static_cast<std::size_t>(which)] - 1)});
    daemon_->start();
    connect();
    v1::Job job;
    const grpc::Status s = submit_any(which, &job);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED)
        << names[which] << ": a result of " << sizes[static_cast<std::size_t>(which)]
        << " bytes was estimated at less at submit (" << s.error_message() << ")";
    EXPECT_NE(s.error_message().find("max_result_bytes"), std::string::npos) << s.error_message();
    stop();
  }
}

// Item 5, as reported: 256 inputs and 256 outputs, output error over 20
// experiments of 80 samples was estimated at 13 MB and produced 535 MB. Its
// residual diagnostics are counted now: refused at submit under 20 MB.
TEST_F(BoundedRequests, ResidualDiagnosticsCountInTheResultSize) {
  start({"--max-result-bytes", std::to_string(20 << 20)});
  constexpr int kWide = 256, kSamples = 80;
  std::ostringstream model;
  model << "model: wide\nversion: \"1\"\nstates:\n  x: {}\ninputs:\n";
  for (int i = 0; i < kWide; ++i) model << "  u" << i << ": {}\n";
  model << "parameters:\n  a: {value: 1, min: 0}\nder:\n  x: -a * x + u0\noutputs:\n";
  for (int i = 0; i < kWide; ++i) model << "  y" << i << ": x + u" << i << "\n";
  v1::CreateModelRequest create;
  create.set_source(model.str());
  v1::ModelInfo info;
  grpc::Status s = models_->CreateModel(as("alpha").get(), create, &info);
  ASSERT_TRUE(s.ok()) << s.error_message();

  std::ostringstream csv;
  csv << "t";
  for (int i = 0; i < kWide; ++i) csv << ",u" << i;
  for (int i = 0; i < kWide; ++i) csv << ",y" << i;
  csv << "\n";
  for (int k = 0; k < kSamples; ++k) {
    csv << k;
    for (int i = 0; i < 2 * kWide; ++i) csv << "," << std::sin(0.1 * k + i);
    csv << "\n";
  }
  std::vector<std::string> inputs, outputs;
  for (int i = 0; i < kWide; ++i) inputs.push_back("u" + std::to_string(i));
  for (int i = 0; i < kWide; ++i) outputs.push_back("y" + std::to_string(i));
  v1::DatasetInfo dataset;
  s = testing::upload_dataset(*datasets_, as("alpha").get(), "wide.csv", csv.str(), inputs, outputs, &dataset);
  ASSERT_TRUE(s.ok()) << s.error_message();

  v1::IdentificationSpec spec;
  spec.set_model("wide");
  spec.set_dataset_id(dataset.id());
  spec.set_method(v1::IDENTIFICATION_METHOD_OE);
  spec.mutable_initial_state()->add_x0(0.0);
  spec.mutable_estimation()->set_max_iterations(1);
  for (int e = 1; e < 20; ++e) {
    v1::Experiment* more = spec.add_experiments();
    more->set_dataset_id(dataset.id());
    more->mutable_initial_state()->add_x0(0.0);
  }
  v1::Job job;
  s = submit("alpha", spec, &job);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
  EXPECT_NE(s.error_message().find("residual diagnostics of 256 outputs x 256 inputs"), std::string::npos)
      << s.error_message();
  EXPECT_LT(daemon_->peak_rss_kib(), 400 * 1024) << "the refused job was computed anyway";
}

// Item 10: one tenant's uploads cannot hold every place, and an upload that
// sends nothing is ended, its place given back.
TEST_F(BoundedRequests, UploadsHaveAShareEachAndAnIdleOneEnds) {
  constexpr int kIdleSeconds = 10;
  const int metrics_port = testing::free_port();
  ASSERT_GT(metrics_port, 0);
  start({"--max-uploads", "4", "--max-tenant-uploads", "2", "--upload-idle-seconds", std::to_string(kIdleSeconds),
         "--metrics-listen", "127.0.0.1:" + std::to_string(metrics_port)});
  // Held by pointer: the writer keeps the addresses of the context and of
  // the response it fills at Finish, so neither may move.
  struct Open {
    std::unique_ptr<grpc::ClientContext> ctx;
    v1::DatasetInfo info;
    std::unique_ptr<grpc::ClientWriter<v1::UploadDatasetRequest>> writer;
    bool header_sent = false;
  };
  auto open = [&](const std::string& tenant) {
    auto o = std::make_unique<Open>();
    o->ctx = as(tenant);
    o->ctx->set_wait_for_ready(true);  // not failed by a channel still connecting
    o->writer = datasets_->UploadDataset(o->ctx.get(), &o->info);
    o->header_sent = o->writer->Write(testing::upload_header("slow.csv", {"F1", "F2"}, {"h1", "h2"}));
    return o;
  };
  // Two of alpha's hold its share (they send a header, then nothing) once
  // riccatid counts them: a Write returns when the header is on its way, and
  // on CI's loaded cores riccatid took seconds to read it. A third tried
  // before then would take a place itself.
  std::vector<std::unique_ptr<Open>> slow;
  slow.push_back(open("alpha"));
  slow.push_back(open("alpha"));
  ASSERT_TRUE(slow[0]->header_sent && slow[1]->header_sent);
  ASSERT_TRUE(testing::wait_until(
      [&] {
        return testing::sample_value(testing::http_get(metrics_port, "/metrics"), "riccati_uploads_in_flight") == 2;
      },
      testing::kWait, "riccatid holds both slow uploads (riccati_uploads_in_flight)"));
  // Alpha's third is refused by its share; beta's goes through.
  {
    const std::unique_ptr<Open> third = open("alpha");
    third->writer->WritesDone();
    const grpc::Status s = third->writer->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
    EXPECT_EQ(s.error_message(),
              "limit max_tenant_uploads = 2 reached: this tenant has as many uploads in flight; wait for one to end");
  }
  EXPECT_FALSE(upload("beta", "two_tank.csv").empty());
  // The slow ones end by themselves once idle ...
  // (finished by riccatid, not cancelled: the client hears why)
  for (const auto& o : slow) {
    const grpc::Status s = o->writer->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << s.error_message();
    EXPECT_EQ(s.error_message(), "the upload of slow.csv sent nothing for " + std::to_string(kIdleSeconds) +
                                     " s (upload_idle_seconds, --upload-idle-seconds): nothing stored");
  }
  slow.clear();  // the calls go, as a client's would (held, they hold riccatid's stop to its grace)
  // ... and alpha's share is free again.
  EXPECT_FALSE(upload("alpha", "two_tank.csv").empty());
  stop();
  EXPECT_EQ(count_rows(database(), "SELECT count(*) FROM datasets WHERE tenant = 'alpha'"), 1);
}

// Shutdown ends an upload still sending at once, and its client hears why
// (nothing of it is stored).
TEST_F(BoundedRequests, AnUploadStoppedByShutdownHearsWhy) {
  const int metrics_port = testing::free_port();
  ASSERT_GT(metrics_port, 0);
  start({"--metrics-listen", "127.0.0.1:" + std::to_string(metrics_port)});
  auto ctx = as("alpha");
  v1::DatasetInfo info;
  auto writer = datasets_->UploadDataset(ctx.get(), &info);
  ASSERT_TRUE(writer->Write(testing::upload_header("slow.csv", {"F1", "F2"}, {"h1", "h2"})));
  v1::UploadDatasetRequest chunk;
  chunk.set_chunk("t,F1,F2,h1,h2\n");
  ASSERT_TRUE(writer->Write(chunk));
  ASSERT_TRUE(testing::wait_until(
      [&] {
        return testing::sample_value(testing::http_get(metrics_port, "/metrics"), "riccati_uploads_in_flight") == 1;
      },
      testing::kWait, "riccatid holds the upload (riccati_uploads_in_flight)"));
  // The client hears the status as soon as riccatid ends the upload, and
  // lets the call go (a client holding a finished call holds riccatid's
  // connection open to its grace: gRPC's, not the upload's).
  grpc::Status s;
  std::thread client([&] {
    s = writer->Finish();
    writer.reset();
    ctx.reset();
  });
  const auto began = std::chrono::steady_clock::now();
  stop();
  EXPECT_LT(std::chrono::steady_clock::now() - began, 4s) << "the upload held the stop to its grace";
  client.join();
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE) << s.error_message();
  EXPECT_EQ(s.error_message(), "riccatid is shutting down: the upload of slow.csv was stopped, nothing stored");
  EXPECT_EQ(count_rows(database(), "SELECT count(*) FROM datasets"), 0);
}

// Item 12: a removed text model's revisions are deleted from the store once
// no job that may run names them (400 create-and-delete pairs grew the store
// by 100 MB outside every quota).
TEST_F(BoundedRequests, RemovedModelsArePurgedUnlessAQueuedJobNamesThem) {
  start({"--workers", "1"});
  const std::string source = read_text(std::string(RICCATI_SOURCE_DIR) + "/models/text/two_tank.yaml");
  for (int i = 0; i < 20; ++i) {
    v1::CreateModelRequest create;
    create.set_source(source + "# revision " + std::to_string(i) + "\n");
    v1::ModelInfo info;
    ASSERT_TRUE(models_->CreateModel(as("alpha").get(), create, &info).ok());
    v1::DeleteModelRequest remove;
    remove.set_name("two_tank_text");
    v1::DeleteModelResponse removed;
    ASSERT_TRUE(models_->DeleteModel(as("alpha").get(), remove, &removed).ok());
  }
  // One revision a queued job names: kept until the job ends.
  const std::string ds = upload("alpha", "two_tank.csv");
  v1::Job busy, queued;
  ASSERT_TRUE(submit("alpha", testing::hensen_spec(ds, 200), &busy).ok());  // holds the one worker
  v1::CreateModelRequest create;
  create.set_source(source);
  v1::ModelInfo info;
  ASSERT_TRUE(models_->CreateModel(as("alpha").get(), create, &info).ok());
  v1::IdentificationSpec on_text = testing::hensen_spec(ds, 1);
  on_text.set_model("two_tank_text");
  ASSERT_TRUE(submit("alpha", on_text, &queued).ok());
  v1::DeleteModelRequest remove;
  remove.set_name("two_tank_text");
  v1::DeleteModelResponse removed;
  ASSERT_TRUE(models_->DeleteModel(as("alpha").get(), remove, &removed).ok());
  EXPECT_EQ(count_rows(database(), "SELECT count(*) FROM models"), 1)
      << "the deleted revisions are purged but the one a queued job names";
  EXPECT_GT(count_rows(database(), "SELECT sum(length(source)) FROM models"), 0) << "the queued job's model was purged";
  v1::CancelJobRequest cancel;
  cancel.set_id(busy.id());
  v1::Job cancelled;
  ASSERT_TRUE(jobs_->CancelJob(as("alpha").get(), cancel, &cancelled).ok());
  EXPECT_EQ(wait_for_end("alpha", queued.id()).state(), v1::JOB_STATE_SUCCEEDED)
      << "the queued job lost its model";
  stop();
  // The name's newest revision stays, empty: its number is never given again.
  EXPECT_EQ(count_rows(database(), "SELECT count(*) FROM models"), 1);
  EXPECT_EQ(count_rows(database(), "SELECT sum(length(source)) FROM models"), 0);
  EXPECT_EQ(count_rows(database(), "SELECT max(revision) FROM models"), 21);
}

// Item 15: a CreateModel retried with the same source is the same revision,
// counted once.
TEST_F(BoundedRequests, ACreateModelRetriedIsOneRevision) {
  start();
  v1::CreateModelRequest create;
  create.set_source(read_text(std::string(RICCATI_SOURCE_DIR) + "/models/text/two_tank.yaml"));
  v1::ModelInfo first, second;
  ASSERT_TRUE(models_->CreateModel(as("alpha").get(), create, &first).ok());
  ASSERT_TRUE(models_->CreateModel(as("alpha").get(), create, &second).ok());
  EXPECT_EQ(first.text().revision(), second.text().revision());
  stop();
  EXPECT_EQ(count_rows(database(), "SELECT count(*) FROM models"), 1);
}

// Item 13: nothing a tenant reads names a server path; ReloadModels is an
// operator's, and what it reports names files within the models directory.
TEST_F(BoundedRequests, NoServerPathReachesATenantAndReloadIsAnOperators) {
  const auto models_dir = dir_.path() / "models";
  std::filesystem::create_directories(models_dir);
  for (const auto& entry : std::filesystem::directory_iterator(RICCATI_TEST_PLUGIN_DIR)) {
    if (entry.path().filename() == "two_tank.so" || entry.path().filename() == "libtwo_tank.so" ||
        entry.path().stem().string().find("two_tank") != std::string::npos) {
      std::filesystem::copy_file(entry.path(), models_dir / entry.path().filename());
    }
  }
  std::ofstream(models_dir / "broken.yaml") << "model: broken\nstates: [\n";
  start({"--models-dir", models_dir.string()});

  v1::CreateModelRequest create;
  create.set_source(read_text(std::string(RICCATI_SOURCE_DIR) + "/models/text/two_tank.yaml"));
  // Named as the built-in plugin.
  const std::string& text = create.source();
  create.set_source(text.substr(0, text.find("model: ")) + "model: two_tank\n" +
                    text.substr(text.find('\n', text.find("model: ")) + 1));
  v1::ModelInfo info;
  grpc::Status s = models_->CreateModel(as("alpha").get(), create, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::ALREADY_EXISTS) << s.error_message();
  EXPECT_EQ(s.error_message().find(dir_.path().string()), std::string::npos) << s.error_message();

  v1::ReloadModelsResponse report;
  s = models_->ReloadModels(as("alpha").get(), {}, &report);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::PERMISSION_DENIED) << s.error_message();
  EXPECT_NE(s.error_message().find("operator"), std::string::npos) << s.error_message();
  s = models_->ReloadModels(as("ops").get(), {}, &report);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_EQ(report.refused_size(), 1);
  EXPECT_EQ(report.refused(0).path(), "broken.yaml");
  EXPECT_EQ(report.refused(0).reason().find(dir_.path().string()), std::string::npos) << report.refused(0).reason();
  EXPECT_EQ(report.DebugString().find(dir_.path().string()), std::string::npos) << report.DebugString();
}

// Item 14: a stream's answer is one message too: a batch whose answer
// would pass max_message_bytes (the full covariance is nz^2 values a
// measurement) is refused before it is computed, saying how many fit.
TEST_F(BoundedRequests, AStreamBatchsAnswerIsBoundedBeforeItIsComputed) {
  start({"--max-message-bytes", std::to_string(256 << 10)});
  v1::SessionInfo session;
  ASSERT_TRUE(sessions_->CreateSession(as("alpha").get(), testing::two_tank_session(), &session).ok());
  auto ctx = as("alpha");
  auto stream = sessions_->Stream(ctx.get());
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  open.mutable_open()->set_full_covariance(true);
  ASSERT_TRUE(stream->Write(open));
  v1::StreamRequest batch;
  for (int k = 0; k < 2000; ++k) testing::add_measurement(batch, 1.0 + k, {0.0, 0.0}, {1.0, 1.0});
  ASSERT_LT(batch.ByteSizeLong(), 256u << 10);
  ASSERT_TRUE(stream->Write(batch));
  stream->WritesDone();
  v1::StreamResponse response;
  EXPECT_FALSE(stream->Read(&response)) << "the batch was answered";
  const grpc::Status s = stream->Finish();
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
  EXPECT_NE(s.error_message().find("max_message_bytes"), std::string::npos) << s.error_message();
  EXPECT_NE(s.error_message().find("or open the stream without full_covariance"), std::string::npos)
      << s.error_message();
}

// Item 15: the retunings a session keeps are its newest 32 (5,000 retunes
// grew every snapshot and SessionInfo by 288 KB).
TEST_F(BoundedRequests, ASessionKeepsItsNewestRetunings) {
  start();
  v1::SessionInfo session;
  ASSERT_TRUE(sessions_->CreateSession(as("alpha").get(), testing::two_tank_session(), &session).ok());
  v1::SessionInfo info;
  for (int i = 1; i <= 40; ++i) {
    v1::RetuneSessionRequest retune;
    retune.set_id(session.id());
    retune.mutable_r()->set_scalar(1e-3 * i);
    ASSERT_TRUE(sessions_->RetuneSession(as("alpha").get(), retune, &info).ok());
  }
  ASSERT_EQ(info.retunings_size(), 32);
  EXPECT_DOUBLE_EQ(info.retunings(31).r().scalar(), 40e-3);
  EXPECT_DOUBLE_EQ(info.retunings(0).r().scalar(), 9e-3);
}

// The target, for this file's attacks together: while tenant alpha
// sends 20 MB request ids, holds its upload share with idle uploads, creates
// and deletes models, asks for full-covariance batches past the message
// limit and reads a large result over and over, tenant beta's health check
// and one-pass identification stay within twice their idle time (and a
// second's slack on this 2-core machine, where the attack's client shares
// the daemon's cores), riccatid's memory stays bounded, and SIGTERM ends it
// within its 5 s grace.
TEST_F(BoundedRequests, AnotherTenantIsServedWhileOneAttacksAndSigtermEndsItAll) {
  start({"--max-tenant-uploads", "2", "--upload-idle-seconds", "30", "--max-message-bytes", std::to_string(32 << 20),
         "--max-result-read-bytes", std::to_string(4 << 20)});
  const std::string beta_ds = upload("beta", "two_tank.csv");
  const std::string alpha_ds = upload("alpha", "two_tank.csv");
  // A result of about 3 MB for alpha to read (20 passes of traces).
  v1::Job big;
  ASSERT_TRUE(submit("alpha", testing::hensen_spec(alpha_ds, 40), &big).ok());
  ASSERT_EQ(wait_for_end("alpha", big.id()).state(), v1::JOB_STATE_SUCCEEDED);

  // Beta is another client: a connection of its own (the attacker's calls
  // share the fixture's, whose 20 MB messages would hold beta's frames
  // behind them in one TCP stream: a client's queue, not the daemon's).
  grpc::ChannelArguments own;
  own.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  const auto beta_channel = grpc::CreateCustomChannel(daemon_->address(), grpc::InsecureChannelCredentials(), own);
  auto beta_jobs = v1::JobService::NewStub(beta_channel);
  auto health = [&] {
    double took = 0;
    EXPECT_TRUE(testing::health_check(beta_channel, &took).ok());
    return took;
  };
  auto one_pass = [&] {
    const auto began = std::chrono::steady_clock::now();
    v1::Job job;
    EXPECT_TRUE(beta_jobs->SubmitIdentification(as("beta").get(), testing::hensen_spec(beta_ds, 1), &job).ok());
    v1::GetJobRequest get;
    get.set_id(job.id());
    EXPECT_TRUE(testing::wait_until(
        [&] {
          return beta_jobs->GetJob(as("beta").get(), get, &job).ok() && job.state() == v1::JOB_STATE_SUCCEEDED;
        },
        120s, "beta's one-pass job succeeds", 2ms));
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - began).count();
  };
  // Medians of 5: the first call after a pause can take 50 ms with no
  // attack at all (measured on a 16-core machine with the attack off).
  auto median_of_5 = [](auto call) {
    std::vector<double> took;
    for (int i = 0; i < 5; ++i) took.push_back(call());
    std::sort(took.begin(), took.end());
    return took[2];
  };
  const double idle_health = median_of_5(health);
  const double idle_pass = median_of_5(one_pass);

  std::atomic<bool> attacking{true};
  std::vector<std::thread> attackers;
  attackers.emplace_back([&] {  // request ids of 20 MB
    v1::IdentificationSpec spec = testing::hensen_spec(alpha_ds, 1);
    spec.set_request_id(std::string(20 << 20, 'r'));
    while (attacking) {
      v1::Job job;
      (void)submit("alpha", spec, &job);
    }
  });
  attackers.emplace_back([&] {  // models created and deleted
    const std::string source = read_text(std::string(RICCATI_SOURCE_DIR) + "/models/text/two_tank.yaml");
    for (int i = 0; attacking; ++i) {
      v1::CreateModelRequest create;
      create.set_source(source + "# " + std::to_string(i) + std::string(100 << 10, '#') + "\n");
      v1::ModelInfo info;
      (void)models_->CreateModel(as("alpha").get(), create, &info);
      v1::DeleteModelRequest remove;
      remove.set_name("two_tank_text");
      v1::DeleteModelResponse removed;
      (void)models_->DeleteModel(as("alpha").get(), remove, &removed);
    }
  });
  for (int reader = 0; reader < 4; ++reader) {
    attackers.emplace_back([&] {  // the large result, read over and over
      while (attacking) {
        v1::GetResultRequest get;
        get.set_job_id(big.id());
        v1::JobResult result;
        (void)jobs_->GetResult(as("alpha").get(), get, &result);
      }
    });
  }
  attackers.emplace_back([&] {  // full-covariance batches past the message limit
    v1::SessionInfo session;
    ASSERT_TRUE(sessions_->CreateSession(as("alpha").get(), testing::two_tank_session(), &session).ok());
    v1::StreamRequest batch;
    for (int k = 0; k < 4096; ++k) testing::add_measurement(batch, 1.0 + k, {0.0, 0.0}, {1.0, 1.0});
    while (attacking) {
      auto ctx = as("alpha");
      auto stream = sessions_->Stream(ctx.get());
      v1::StreamRequest open;
      open.mutable_open()->set_session_id(session.id());
      open.mutable_open()->set_full_covariance(true);
      stream->Write(open);
      stream->Write(batch);
      stream->WritesDone();
      v1::StreamResponse response;
      while (stream->Read(&response)) {
      }
      (void)stream->Finish();
    }
  });
  // Alpha's upload share held by uploads that send nothing.
  std::vector<std::unique_ptr<grpc::ClientContext>> held_contexts;
  std::vector<std::unique_ptr<grpc::ClientWriter<v1::UploadDatasetRequest>>> held;
  std::vector<v1::DatasetInfo> held_info(2);
  for (int i = 0; i < 2; ++i) {
    held_contexts.push_back(as("alpha"));
    held.push_back(datasets_->UploadDataset(held_contexts.back().get(), &held_info[static_cast<std::size_t>(i)]));
    held.back()->Write(testing::upload_header("held.csv", {"F1", "F2"}, {"h1", "h2"}));
  }
  std::this_thread::sleep_for(1s);  // the attack under way

  const double worst_health = median_of_5(health);
  const double worst_pass = median_of_5(one_pass);
  EXPECT_FALSE(upload("beta", "two_tank_noisy.csv").empty()) << "another tenant's upload, while alpha holds its share";
  const long peak_kib = daemon_->peak_rss_kib();
  std::printf("medians idle: health %.4f s, one pass %.3f s; under attack: health %.4f s, one pass %.3f s; peak RSS "
              "%ld MiB\n",
              idle_health, idle_pass, worst_health, worst_pass, peak_kib / 1024);
  RecordProperty("idle_health_s", std::to_string(idle_health));
  RecordProperty("attacked_health_s", std::to_string(worst_health));
  RecordProperty("idle_one_pass_s", std::to_string(idle_pass));
  RecordProperty("attacked_one_pass_s", std::to_string(worst_pass));
  const double slack = testing::kSanitized ? 10.0 : 1.0;
  EXPECT_LT(worst_health, 2 * idle_health + slack);
  EXPECT_LT(worst_pass, 2 * idle_pass + slack);
  if (!testing::kSanitized) {
    // The limits it runs under: 32 MiB messages (several in flight), 4 MiB of
    // results read at once (a few times that while converted), the stores'
    // and gRPC's own: well under 1 GiB, where the reported attacks took several.
    EXPECT_LT(peak_kib, 1024 * 1024) << "riccatid's peak resident memory under the attack";
  }

  // SIGTERM while it all goes on: out within the grace period.
  const auto stopping = std::chrono::steady_clock::now();
  const int status = daemon_->stop();
  const double stop_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - stopping).count();
  std::printf("SIGTERM under the attack: exit after %.2f s\n", stop_s);
  RecordProperty("attacked_sigterm_s", std::to_string(stop_s));
  attacking = false;
  for (auto& w : held) {
    w->WritesDone();
    (void)w->Finish();
  }
  for (std::thread& t : attackers) t.join();
  EXPECT_EQ(status, 0) << daemon_->exit_report();
  // Within the 5 s grace and a little. (It took 10 s more in 3 of about 30
  // runs before riccatid kept gRPC initialised to its end: destroying the
  // server joined a gRPC executor thread polling with a 10 s timeout.)
  EXPECT_LT(stop_s, testing::kSanitized ? 30.0 : 6.5) << "SIGTERM under attack took " << stop_s << " s";
}

// Item 15: files read at start are regular files of bounded size. A FIFO
// as the tokens file hung the start (and SIGTERM); /dev/zero as the
// certificate was read without end.
TEST(BoundedStartFiles, AFifoOrADeviceIsRefusedAtStart) {
  TempDir dir;
  const auto fifo = dir.path() / "tokens";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const auto started = std::chrono::steady_clock::now();
  testing::Outcome out = testing::riccatid("--listen 127.0.0.1:0 --data-dir " + (dir.path() / "d").string() +
                                           " --tokens-file " + fifo.string());
  EXPECT_NE(out.exit_code, 0);
  EXPECT_NE(out.exit_code, 124) << "riccatid hung on a FIFO";
  EXPECT_NE(out.output.find("is not a regular file"), std::string::npos) << out.output;
  out = testing::riccatid("--listen 127.0.0.1:0 --data-dir " + (dir.path() / "d").string() +
                          " --tls-cert /dev/zero --tls-key /dev/zero");
  EXPECT_NE(out.exit_code, 0);
  EXPECT_NE(out.exit_code, 124) << "riccatid read /dev/zero without end";
  EXPECT_NE(out.output.find("/dev/zero is not a regular file"), std::string::npos) << out.output;
  EXPECT_LT(std::chrono::steady_clock::now() - started, 30s);
}

}  // namespace
}  // namespace riccati
