// Limits of a real riccatid with two tenants: past each one the call gets
// RESOURCE_EXHAUSTED naming the limit, other tenants are not affected, and
// freeing the resource lets the tenant go on.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include "engine/sha256.hpp"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/models.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"
#include "service/daemon_fixture.hpp"
#include "support/mat_files.hpp"
#include "support/requests.hpp"

namespace riccati {
namespace {

using testing::DaemonProcess;
using testing::TempDir;

const std::string kData = RICCATI_TEST_DATA_DIR;

// A two-tank-shaped CSV of n samples (t, F1, F2, h1, h2).
std::string small_csv(int n) {
  std::ostringstream csv;
  csv << "t,F1,F2,h1,h2\n";
  for (int k = 0; k < n; ++k) csv << 0.1 * k << ",1,1," << 1 + 0.01 * std::sin(k) << ",1\n";
  return csv.str();
}

class LimitsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto tokens = dir_.path() / "tokens";
    std::ofstream(tokens) << "alpha sha256:" << sha256_hex("alpha-token") << "\n"
                          << "beta sha256:" << sha256_hex("beta-token") << "\n";
    csv_ = small_csv(500);
    const auto csv_bytes = static_cast<std::int64_t>(csv_.size());
    daemon_ = std::make_unique<DaemonProcess>(
        dir_.path() / "data",
        std::vector<std::string>{"--tokens-file", tokens.string(),
                                 "--max-tenant-sessions", "2", "--max-sessions", "3",
                                 "--max-tenant-jobs", "1", "--max-passes", "400",
                                 "--max-dataset-samples", "1000", "--max-dataset-bytes", "200000",
                                 "--max-tenant-dataset-bytes", std::to_string(csv_bytes * 5 / 2),
                                 "--max-batch", "4", "--max-message-bytes", std::to_string(256 << 10)});
    daemon_->start();
    datasets_ = v1::DatasetService::NewStub(daemon_->channel());
    jobs_ = v1::JobService::NewStub(daemon_->channel());
    sessions_ = v1::SessionService::NewStub(daemon_->channel());
  }

  static std::unique_ptr<grpc::ClientContext> as(const std::string& tenant) {
    auto ctx = std::make_unique<grpc::ClientContext>();
    ctx->AddMetadata("authorization", "Bearer " + tenant + "-token");
    ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    return ctx;
  }

  grpc::Status upload(const std::string& tenant, const std::string& bytes, v1::DatasetInfo* info,
                      std::size_t chunk_size = 64 << 10, const std::string& name = "data.csv") {
    auto ctx = as(tenant);
    return testing::upload_dataset(*datasets_, ctx.get(), name, bytes, {"F1", "F2"}, {"h1", "h2"}, info, chunk_size);
  }

  static void expect_limit(const grpc::Status& s, const std::string& limit) {
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << limit << ": " << s.error_message();
    EXPECT_NE(s.error_message().find(limit), std::string::npos) << s.error_message();
  }

  TempDir dir_;
  std::string csv_;
  std::unique_ptr<DaemonProcess> daemon_;
  std::unique_ptr<v1::DatasetService::Stub> datasets_;
  std::unique_ptr<v1::JobService::Stub> jobs_;
  std::unique_ptr<v1::SessionService::Stub> sessions_;
};

TEST_F(LimitsTest, SessionsPerTenantAndInAll) {
  std::vector<v1::SessionInfo> alpha(3);
  ASSERT_TRUE(sessions_->CreateSession(as("alpha").get(), testing::two_tank_session(), &alpha[0]).ok());
  ASSERT_TRUE(sessions_->CreateSession(as("alpha").get(), testing::two_tank_session(), &alpha[1]).ok());
  expect_limit(sessions_->CreateSession(as("alpha").get(), testing::two_tank_session(), &alpha[2]),
               "max_tenant_sessions = 2");
  v1::SessionInfo beta;
  ASSERT_TRUE(sessions_->CreateSession(as("beta").get(), testing::two_tank_session(), &beta).ok());
  expect_limit(sessions_->CreateSession(as("beta").get(), testing::two_tank_session(), &beta), "max_sessions = 3");
  // Closing one frees its place.
  v1::CloseSessionRequest close;
  close.set_id(alpha[0].id());
  v1::CloseSessionResponse closed;
  ASSERT_TRUE(sessions_->CloseSession(as("alpha").get(), close, &closed).ok());
  EXPECT_TRUE(sessions_->CreateSession(as("beta").get(), testing::two_tank_session(), &beta).ok());
}

TEST_F(LimitsTest, JobsPerTenantAndPassesPerJob) {
  v1::DatasetInfo data;
  ASSERT_TRUE(upload("alpha", csv_, &data).ok());
  v1::Job job;
  expect_limit(jobs_->SubmitIdentification(as("alpha").get(), testing::hensen_spec(data.id(), 401), &job),
               "max_passes = 400");
  v1::Job running;
  ASSERT_TRUE(jobs_->SubmitIdentification(as("alpha").get(), testing::hensen_spec(data.id(), 400), &running).ok());
  expect_limit(jobs_->SubmitIdentification(as("alpha").get(), testing::hensen_spec(data.id(), 1), &job),
               "max_tenant_jobs = 1");
  // Beta is not held back by alpha's job.
  v1::DatasetInfo beta_data;
  ASSERT_TRUE(upload("beta", csv_, &beta_data).ok());
  v1::Job beta_job;
  EXPECT_TRUE(jobs_->SubmitIdentification(as("beta").get(), testing::hensen_spec(beta_data.id(), 1), &beta_job).ok());
  // Once alpha's job has ended, alpha may submit again: its end (the
  // watch's last state) frees its place.
  v1::CancelJobRequest cancel;
  cancel.set_id(running.id());
  ASSERT_TRUE(jobs_->CancelJob(as("alpha").get(), cancel, &job).ok());
  {
    auto ctx = as("alpha");
    v1::WatchJobRequest watch;
    watch.set_id(running.id());
    auto reader = jobs_->WatchJob(ctx.get(), watch);
    v1::Job seen;
    while (reader->Read(&seen)) {
    }
    ASSERT_TRUE(reader->Finish().ok());
    ASSERT_EQ(seen.state(), v1::JOB_STATE_CANCELLED) << seen.ShortDebugString();
  }
  const grpc::Status again = jobs_->SubmitIdentification(as("alpha").get(), testing::hensen_spec(data.id(), 1), &job);
  EXPECT_TRUE(again.ok()) << again.error_message();
}

TEST_F(LimitsTest, DatasetSamplesTenantBytesAndMessageSize) {
  v1::DatasetInfo info;
  expect_limit(upload("alpha", small_csv(1001), &info), "max_dataset_samples = 1000");
  ASSERT_TRUE(upload("alpha", csv_, &info).ok());
  ASSERT_TRUE(upload("alpha", csv_, &info).ok());
  expect_limit(upload("alpha", csv_, &info), "max_tenant_dataset_bytes");
  EXPECT_TRUE(upload("beta", csv_, &info).ok()) << "another tenant's quota is its own";
  // A message over max_message_bytes: gRPC refuses it before any handler.
  const grpc::Status big = upload("beta", std::string(300 << 10, '1'), &info, 300 << 10);
  EXPECT_EQ(big.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << big.error_message();
  // Deleting frees the quota.
  v1::ListDatasetsResponse list;
  ASSERT_TRUE(datasets_->ListDatasets(as("alpha").get(), {}, &list).ok());
  v1::DeleteDatasetRequest del;
  del.set_id(list.datasets(0).id());
  v1::DeleteDatasetResponse deleted;
  ASSERT_TRUE(datasets_->DeleteDataset(as("alpha").get(), del, &deleted).ok());
  EXPECT_TRUE(upload("alpha", csv_, &info).ok());
}

// max_dataset_bytes bounds an upload and also what its values inflate to:
// a compressed MAT file of a few kilobytes may claim gigabytes.
TEST_F(LimitsTest, DatasetBytesBoundTheValuesOfACompressedMatFile) {
  std::vector<double> t(500), u(2 * 500, 1.0), y(2 * 500, 1.0);
  for (std::size_t k = 0; k < t.size(); ++k) t[k] = 0.1 * static_cast<double>(k);
  const std::string fits = testing::mat5_file({{"T", {1, 500}, t}, {"U", {2, 500}, u}, {"Y", {2, 500}, y}}, true);
  v1::DatasetInfo info;
  const grpc::Status ok = upload("alpha", fits, &info, 64 << 10, "rig.mat");
  ASSERT_TRUE(ok.ok()) << ok.error_message();
  EXPECT_EQ(info.samples(), 500u);

  const std::vector<double> zeros(20'000, 0.0);
  const std::string bomb = testing::mat5_file({{"T", {1, 20'000}, zeros}, {"Y", {1, 20'000}, zeros}}, true);
  ASSERT_LT(bomb.size(), 2'000u);
  expect_limit(upload("alpha", bomb, &info, 64 << 10, "bomb.mat"), "max_dataset_bytes = 200000");
}

TEST_F(LimitsTest, MeasurementsPerMessage) {
  v1::SessionInfo session;
  ASSERT_TRUE(sessions_->CreateSession(as("alpha").get(), testing::two_tank_session(), &session).ok());
  auto ctx = as("alpha");
  auto stream = sessions_->Stream(ctx.get());
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  ASSERT_TRUE(stream->Write(open));
  v1::StreamRequest batch;
  for (int k = 0; k < 5; ++k) {
    testing::add_measurement(batch, 0.1 * k, {1.0, 1.0}, {1.0, 1.0});
  }
  stream->Write(batch);
  stream->WritesDone();
  v1::StreamResponse response;
  while (stream->Read(&response)) {
  }
  expect_limit(stream->Finish(), "max_batch = 4");
}

// A job's result is estimated at submit: one over max_result_bytes used to
// be computed for minutes and then fail to be stored (a result over SQLite's
// 1 GB limit, run again and again). 500 samples of the two-tank model's 4
// parameters make 16000 bytes of trace a pass (and 112 of its summary),
// plus 28128 once and 70656 for what is not doubles (64 KiB, and 512 bytes
// for each of the model's 10 names).
TEST(ResultLimits, AJobWhoseResultWouldBeTooLargeIsRefusedAtSubmit) {
  TempDir dir;
  DaemonProcess daemon(dir.path() / "data", {"--max-result-bytes", "1000000"});
  daemon.start();
  auto datasets = v1::DatasetService::NewStub(daemon.channel());
  auto jobs = v1::JobService::NewStub(daemon.channel());
  v1::DatasetInfo data;
  ASSERT_TRUE(testing::upload_dataset(*datasets, "data.csv", small_csv(500), {"F1", "F2"}, {"h1", "h2"}, &data).ok());
  v1::Job job;
  {
    grpc::ClientContext ctx;
    const grpc::Status s = jobs->SubmitIdentification(&ctx, testing::hensen_spec(data.id(), 56), &job);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
    EXPECT_NE(s.error_message().find("limit max_result_bytes = 1000000 reached: the job's result would take about "
                                     "1001056 bytes (56 passes x 4 parameters x 500 samples of estimate traces"),
              std::string::npos)
        << s.error_message();
    EXPECT_NE(s.error_message().find("ask for fewer passes, or a shorter sample range (first_sample, end_sample)"),
              std::string::npos)
        << s.error_message();
  }
  {
    grpc::ClientContext ctx;
    const grpc::Status s = jobs->SubmitIdentification(&ctx, testing::hensen_spec(data.id(), 55), &job);
    EXPECT_TRUE(s.ok()) << "55 passes, 984944 bytes: " << s.error_message();
  }
  {
    v1::IdentificationSpec ranged = testing::hensen_spec(data.id(), 56);
    ranged.set_end_sample(250);
    grpc::ClientContext ctx;
    const grpc::Status s = jobs->SubmitIdentification(&ctx, ranged, &job);
    EXPECT_TRUE(s.ok()) << "56 passes over half the samples: " << s.error_message();
  }
  // Smoothing over 2000 samples: 1 + 4 x 6 + 2 x 2 values a sample fit;
  // with the covariance of z (36 more a sample) they do not.
  v1::DatasetInfo longer;
  ASSERT_TRUE(testing::upload_dataset(*datasets, "longer.csv", small_csv(2000), {"F1", "F2"}, {"h1", "h2"}, &longer).ok());
  v1::SmoothingSpec smoothing;
  smoothing.set_model("two_tank");
  smoothing.set_dataset_id(longer.id());
  for (double r : {1e-3, 1e-3}) smoothing.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(r);
  smoothing.mutable_initial_state()->set_first_measurement(true);
  for (double v : {20.0, 20.0, 1.0, 1.0}) smoothing.add_theta0(v);
  for (double v : {0.0, 0.0, 10.0, 10.0, 10.0, 10.0}) smoothing.mutable_p0()->mutable_diagonal()->add_values(v);
  {
    grpc::ClientContext ctx;
    const grpc::Status s = jobs->SubmitSmoothing(&ctx, smoothing, &job);
    EXPECT_TRUE(s.ok()) << "2000 x 29 values, 532608 bytes: " << s.error_message();
  }
  smoothing.set_full_covariance(true);
  {
    grpc::ClientContext ctx;
    const grpc::Status s = jobs->SubmitSmoothing(&ctx, smoothing, &job);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
    EXPECT_NE(s.error_message().find("limit max_result_bytes = 1000000 reached: the job's result would take about "
                                     "1108608 bytes (2000 samples x 65 values (6 states and parameters, with their "
                                     "full covariance)"),
              std::string::npos)
        << s.error_message();
    EXPECT_NE(s.error_message().find("or no full_covariance"), std::string::npos) << s.error_message();
  }
}

// A Simulate of the two-tank model: `samples` samples 0.1 s apart under a
// constant input, `substeps` RK4 steps each.
v1::SimulateRequest two_tank_simulation(int samples, int substeps) {
  v1::SimulateRequest r;
  r.set_model("two_tank");
  for (double x : {0.4, 0.15}) r.add_x0(x);
  for (int k = 0; k < samples; ++k) r.add_t(0.1 * k);
  r.mutable_u()->set_rows(2);
  r.mutable_u()->set_cols(static_cast<std::uint32_t>(samples));
  for (int k = 0; k < 2 * samples; ++k) r.mutable_u()->add_values(0.01);
  r.mutable_integrator()->set_substeps(static_cast<std::uint32_t>(substeps));
  return r;
}

// Simulate's work is bounded before it starts and stops when nobody waits:
// 1e8 RK4 steps are refused naming the limit; a long simulation whose
// deadline passed stops between samples (with one simulation allowed at a
// time, the next one is taken soon after, not after the ~20 s the first
// would have computed on), and one running keeps a second out.
TEST(SimulateLimits, WorkIsBoundedAtTheStartAndStopsAtTheDeadline) {
  TempDir dir;
  DaemonProcess daemon(dir.path() / "data", {"--max-simulations", "1", "--max-simulation-steps", "400000000"});
  daemon.start();
  auto models = v1::ModelService::NewStub(daemon.channel());
  const auto request = two_tank_simulation;
  v1::SimulateResponse response;
  {
    grpc::ClientContext ctx;
    const grpc::Status s = models->Simulate(&ctx, request(1001, 1'000'000), &response);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
    EXPECT_NE(s.error_message().find("limit max_simulation_steps = 400000000 reached: 1001 samples x 1000000 substeps"),
              std::string::npos)
        << s.error_message();
  }
  // About 3e8 steps: many seconds of work, with a deadline of half a second.
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(500));
    const grpc::Status s = models->Simulate(&ctx, request(3001, 100'000), &response);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << s.error_message();
  }
  const auto after_deadline = std::chrono::steady_clock::now();
  EXPECT_TRUE(testing::wait_until(
      [&] {
        grpc::ClientContext ctx;
        return models->Simulate(&ctx, request(10, 10), &response).ok();
      },
      testing::kWait, "a small simulation taken once the one past its deadline has stopped"));
  EXPECT_LT(std::chrono::steady_clock::now() - after_deadline, std::chrono::seconds(testing::kSanitized ? 60 : 5));

  // One running (cancelled by its client below) keeps a second out. The
  // long one tries again while a probe holds the only place.
  std::atomic<bool> done{false};
  std::unique_ptr<grpc::ClientContext> long_ctx;
  std::mutex long_mu;
  std::thread running([&] {
    while (!done) {
      {
        std::lock_guard lock(long_mu);
        long_ctx = std::make_unique<grpc::ClientContext>();
      }
      v1::SimulateResponse r;
      const grpc::Status s = models->Simulate(long_ctx.get(), request(3001, 100'000), &r);
      if (s.error_code() != grpc::StatusCode::RESOURCE_EXHAUSTED) break;
    }
  });
  grpc::Status refused;
  EXPECT_TRUE(testing::wait_until(
      [&] {
        grpc::ClientContext ctx;
        refused = models->Simulate(&ctx, request(10, 10), &response);
        return !refused.ok();
      },
      testing::kWait, "a second simulation refused while one runs"));
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << refused.error_message();
  EXPECT_NE(refused.error_message().find("max_simulations = 1"), std::string::npos) << refused.error_message();
  done = true;
  {
    std::lock_guard lock(long_mu);
    long_ctx->TryCancel();
  }
  running.join();
}


// A batch of slow measurements stops between two once its stream is
// cancelled (here: its deadline passed): the session is free for a new
// stream soon after, not after the minutes the batch would have taken.
TEST(StreamLimits, ABatchStopsWhenItsStreamIsCancelled) {
  TempDir dir;
  DaemonProcess daemon(dir.path() / "data");
  daemon.start();
  auto sessions = v1::SessionService::NewStub(daemon.channel());
  v1::CreateSessionRequest create = testing::two_tank_session();
  create.mutable_filter()->mutable_integrator()->set_substeps(100'000);  // tens of ms a measurement
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions->CreateSession(&ctx, create, &session).ok());
  }
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  v1::StreamRequest batch;
  for (int k = 0; k < 1000; ++k) testing::add_measurement(batch, k, {0.1, 0.03}, {0.4, 0.15});
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(500));
    auto stream = sessions->Stream(&ctx);
    ASSERT_TRUE(stream->Write(open));
    ASSERT_TRUE(stream->Write(batch));
    v1::StreamResponse response;
    while (stream->Read(&response)) {
    }
    EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  }
  const auto after_deadline = std::chrono::steady_clock::now();
  grpc::Status attached;
  EXPECT_TRUE(testing::wait_until(
      [&] {
        grpc::ClientContext ctx;
        auto stream = sessions->Stream(&ctx);
        stream->Write(open);
        v1::StreamRequest one;
        testing::add_measurement(one, 5000.0, {0.1, 0.03}, {0.4, 0.15});
        stream->Write(one);
        stream->WritesDone();
        v1::StreamResponse response;
        while (stream->Read(&response)) {
        }
        attached = stream->Finish();
        return attached.ok();
      },
      testing::kWait, "a new stream on the session once the cancelled batch has stopped"))
      << attached.error_message();
  EXPECT_LT(std::chrono::steady_clock::now() - after_deadline, std::chrono::seconds(testing::kSanitized ? 60 : 5));
}


// SIGTERM while a Simulate of many seconds and a batch of tens of seconds
// run, neither with a deadline (they once held riccatid 17-26 s against its
// 5 s grace): both stop within the grace period, between two steps, and
// riccatid exits 0 soon after it.
//
// The CPU time each thread of process `pid` has used, in ms, by thread id
// (/proc/PID/task/TID/stat: utime and stime, the 14th and 15th fields).
std::map<int, long> thread_cpu_ms(pid_t pid) {
  std::map<int, long> out;
  const long ticks = ::sysconf(_SC_CLK_TCK);
  std::error_code ec;
  for (const auto& task : std::filesystem::directory_iterator("/proc/" + std::to_string(pid) + "/task", ec)) {
    std::ifstream in(task.path() / "stat");
    std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const std::size_t end_of_name = stat.rfind(')');  // the name may hold spaces
    if (end_of_name == std::string::npos) continue;
    std::istringstream fields(stat.substr(end_of_name + 2));
    std::string field;
    long utime = 0, stime = 0;
    for (int i = 3; i <= 15 && fields >> field; ++i) {
      if (i == 14) utime = std::stol(field);
      if (i == 15) stime = std::stol(field);
    }
    out[std::stoi(task.path().filename().string())] = (utime + stime) * 1000 / ticks;
  }
  return out;
}

TEST(Shutdown, LongSimulationsAndBatchesStopWithinTheGracePeriod) {
  TempDir dir;
  DaemonProcess daemon(dir.path() / "data", {"--max-simulation-steps", "400000000"});
  daemon.start();
  auto models = v1::ModelService::NewStub(daemon.channel());
  auto sessions = v1::SessionService::NewStub(daemon.channel());
  const v1::SimulateRequest simulate = two_tank_simulation(3001, 100'000);  // 3e8 steps: far longer than the grace

  v1::CreateSessionRequest create = testing::two_tank_session();
  create.mutable_filter()->mutable_integrator()->set_substeps(100'000);  // tens of ms a measurement
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions->CreateSession(&ctx, create, &session).ok());
  }
  const std::map<int, long> idle_cpu = thread_cpu_ms(daemon.pid());
  std::atomic<int> answered{0};
  grpc::Status simulated, streamed;
  std::thread simulating([&] {
    grpc::ClientContext ctx;
    v1::SimulateResponse response;
    simulated = models->Simulate(&ctx, simulate, &response);
  });
  std::thread streaming([&] {
    grpc::ClientContext ctx;
    auto stream = sessions->Stream(&ctx);
    v1::StreamRequest open;
    open.mutable_open()->set_session_id(session.id());
    stream->Write(open);
    v1::StreamRequest batch;
    for (int k = 0; k < 1000; ++k) testing::add_measurement(batch, k, {0.1, 0.03}, {0.4, 0.15});
    stream->Write(batch);
    v1::StreamResponse response;
    while (stream->Read(&response)) answered += response.results_size();
    streamed = stream->Finish();
  });
  // Both well under way: two of riccatid's threads (the simulation's and the
  // session's) each computing for 300 ms of CPU time since the calls were
  // made. (The batch is answered at its end: nothing to see on the stream.)
  EXPECT_TRUE(testing::wait_until(
      [&] {
        int busy = 0;
        for (const auto& [tid, ms] : thread_cpu_ms(daemon.pid())) {
          const auto before = idle_cpu.find(tid);
          busy += ms - (before == idle_cpu.end() ? 0 : before->second) >= 300;
        }
        return busy >= 2;
      },
      testing::kWait, "the simulation and the batch both under way"));

  const auto signalled = std::chrono::steady_clock::now();
  const int status = daemon.stop();
  const auto took = std::chrono::steady_clock::now() - signalled;
  simulating.join();
  streaming.join();
  EXPECT_EQ(status, 0) << daemon.exit_report();
  // The grace (5 s) and the time a step and the store's close take.
  EXPECT_LT(took, std::chrono::seconds(testing::kSanitized ? 60 : 8))
      << std::chrono::duration_cast<std::chrono::milliseconds>(took).count() << " ms";
  EXPECT_FALSE(simulated.ok()) << "the simulation ran to its end: it was not long enough to test this";
  EXPECT_FALSE(streamed.ok()) << "the batch ran to its end: it was not long enough to test this";
  EXPECT_EQ(streamed.error_code(), grpc::StatusCode::UNAVAILABLE) << streamed.error_message();
  EXPECT_LT(answered.load(), 1000);
}

// The tenant's quota holds however many uploads run at once: room is
// reserved as the bytes arrive, with what is stored and every upload in
// flight (12 concurrent uploads against a 500 KB quota stored 691 KB).
// Uploads in flight are capped: a third past max_uploads = 2 is refused
// naming the limit, and taken once one has ended.
TEST(UploadLimits, TheQuotaHoldsForConcurrentUploadsAndUploadsInFlightAreCapped) {
  TempDir dir;
  constexpr std::int64_t kQuota = 500'000;
  DaemonProcess daemon(dir.path() / "data",
                       {"--max-tenant-dataset-bytes", std::to_string(kQuota), "--max-uploads", "12",
                        "--max-tenant-uploads", "12"});
  daemon.start();
  auto datasets = v1::DatasetService::NewStub(daemon.channel());
  const std::string csv = small_csv(3000);  // about 60 KB
  ASSERT_GT(csv.size(), 50'000u);
  std::vector<grpc::Status> outcomes(12);
  std::vector<std::thread> uploads;
  for (std::size_t i = 0; i < outcomes.size(); ++i) {
    uploads.emplace_back([&, i] {
      grpc::ClientContext ctx;
      v1::DatasetInfo info;
      // Sizes declared, as the CLI does: each reserves its whole size at once.
      outcomes[i] = testing::upload_dataset(*datasets, &ctx, "u" + std::to_string(i) + ".csv", csv, {"F1", "F2"},
                                            {"h1", "h2"}, &info, 2048, /*declare_size=*/true);
    });
  }
  for (std::thread& t : uploads) t.join();
  std::size_t stored = 0;
  for (const grpc::Status& s : outcomes) {
    if (s.ok()) {
      ++stored;
      continue;
    }
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
    EXPECT_NE(s.error_message().find("max_tenant_dataset_bytes"), std::string::npos) << s.error_message();
  }
  grpc::ClientContext list_ctx;
  v1::ListDatasetsResponse list;
  ASSERT_TRUE(datasets->ListDatasets(&list_ctx, {}, &list).ok());
  std::int64_t bytes = 0;
  for (const v1::DatasetInfo& d : list.datasets()) bytes += static_cast<std::int64_t>(d.size_bytes());
  EXPECT_LE(bytes, kQuota) << stored << " uploads stored";
  // Reserved whole, the uploads that fit are stored, however they interleave.
  EXPECT_EQ(stored, static_cast<std::size_t>(kQuota) / csv.size());
  // Without sizes, the quota holds as the bytes arrive (concurrent uploads
  // may then all run out part-way: none stored is right too).
  std::vector<std::thread> undeclared;
  for (std::size_t i = 0; i < outcomes.size(); ++i) {
    undeclared.emplace_back([&, i] {
      grpc::ClientContext ctx;
      v1::DatasetInfo info;
      outcomes[i] = testing::upload_dataset(*datasets, &ctx, "v" + std::to_string(i) + ".csv", csv, {"F1", "F2"},
                                            {"h1", "h2"}, &info, 2048);
    });
  }
  for (std::thread& t : undeclared) t.join();
  for (const grpc::Status& s : outcomes) {
    if (!s.ok()) {
      EXPECT_NE(s.error_message().find("max_tenant_dataset_bytes"), std::string::npos) << s.error_message();
    }
  }
  grpc::ClientContext relist_ctx;
  ASSERT_TRUE(datasets->ListDatasets(&relist_ctx, {}, &list).ok());
  bytes = 0;
  for (const v1::DatasetInfo& d : list.datasets()) bytes += static_cast<std::int64_t>(d.size_bytes());
  EXPECT_LE(bytes, kQuota);
  datasets.reset();
  ASSERT_EQ(daemon.stop(), 0);

  DaemonProcess capped(dir.path() / "data2", {"--max-uploads", "2"});
  capped.start();
  auto capped_datasets = v1::DatasetService::NewStub(capped.channel());
  std::vector<std::unique_ptr<grpc::ClientContext>> contexts(2);
  std::vector<std::unique_ptr<grpc::ClientWriter<v1::UploadDatasetRequest>>> open(2);
  v1::DatasetInfo info[2];
  v1::UploadDatasetRequest nothing;
  nothing.set_chunk("");
  // Two uploads held open. A probe may take a place before one of them is
  // read, which is then refused: it is opened again until both hold.
  auto hold_open = [&](std::size_t i) {
    if (open[i] != nullptr && open[i]->Write(nothing)) return;
    if (open[i] != nullptr) open[i]->Finish();
    contexts[i] = std::make_unique<grpc::ClientContext>();
    open[i] = capped_datasets->UploadDataset(contexts[i].get(), &info[i]);
    open[i]->Write(testing::upload_header("open.csv", {"F1", "F2"}, {"h1", "h2"}));
  };
  grpc::Status third;
  EXPECT_TRUE(testing::wait_until(
      [&] {
        hold_open(0);
        hold_open(1);
        v1::DatasetInfo ignored;
        third = testing::upload_dataset(*capped_datasets, "third.csv", csv, {"F1", "F2"}, {"h1", "h2"}, &ignored);
        return !third.ok();
      },
      testing::kWait, "a third upload refused while two are in flight"));
  EXPECT_EQ(third.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << third.error_message();
  EXPECT_NE(third.error_message().find("max_uploads = 2"), std::string::npos) << third.error_message();
  // One of the two ends (sent and stored): the next is taken.
  v1::UploadDatasetRequest chunk;
  chunk.set_chunk(csv);
  ASSERT_TRUE(open[0]->Write(chunk));
  open[0]->WritesDone();
  EXPECT_TRUE(open[0]->Finish().ok());
  v1::DatasetInfo next;
  const grpc::Status taken = testing::upload_dataset(*capped_datasets, "next.csv", csv, {"F1", "F2"}, {"h1", "h2"}, &next);
  EXPECT_TRUE(taken.ok()) << taken.error_message();
  contexts[1]->TryCancel();
  open[1]->Finish();
  open.clear();
  capped_datasets.reset();  // an open channel would hold the daemon's stop for its grace period
}

// Watches (like streams and uploads) are served by gRPC's callback API: an
// open watch holds no thread. Before, every watch held one, and a few
// hundred from one client took every thread the daemon could have.
TEST(StreamLimits, WatchesHoldNoThreadAndATenantAtItsCapLeavesTheOthersServed) {
  TempDir dir;
  const auto tokens = dir.path() / "tokens";
  std::ofstream(tokens) << "alpha sha256:" << sha256_hex("alpha-token") << "\n"
                        << "beta sha256:" << sha256_hex("beta-token") << "\n";
  constexpr int kTenantCap = 300;
  constexpr int kCap = 305;
  DaemonProcess daemon(dir.path() / "data", {"--tokens-file", tokens.string(), "--max-tenant-streams",
                                             std::to_string(kTenantCap), "--max-streams", std::to_string(kCap)});
  daemon.start();
  auto datasets = v1::DatasetService::NewStub(daemon.channel());
  auto jobs = v1::JobService::NewStub(daemon.channel());
  auto as = [](const std::string& tenant) {
    auto ctx = std::make_unique<grpc::ClientContext>();
    ctx->AddMetadata("authorization", "Bearer " + tenant + "-token");
    ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    return ctx;
  };
  // A job that runs for the whole test (cancelled at its end).
  auto submit = [&](const std::string& tenant) {
    v1::DatasetInfo data;
    auto upload_ctx = as(tenant);
    const grpc::Status uploaded = testing::upload_dataset(*datasets, upload_ctx.get(), "d.csv", small_csv(500),
                                                          {"F1", "F2"}, {"h1", "h2"}, &data);
    EXPECT_TRUE(uploaded.ok()) << uploaded.error_message();
    v1::Job job;
    const grpc::Status submitted =
        jobs->SubmitIdentification(as(tenant).get(), testing::hensen_spec(data.id(), 10'000), &job);
    EXPECT_TRUE(submitted.ok()) << submitted.error_message();
    return job.id();
  };
  const std::string alpha_job = submit("alpha");
  const std::string beta_job = submit("beta");
  const long threads_before = daemon.threads();

  struct Watch {
    std::unique_ptr<grpc::ClientContext> ctx;
    std::unique_ptr<grpc::ClientReader<v1::Job>> reader;
  };
  // A watch, open once its first message (the job as it is) has arrived.
  auto watch = [&](const std::string& tenant, const std::string& id, Watch* w) {
    w->ctx = as(tenant);
    v1::WatchJobRequest request;
    request.set_id(id);
    w->reader = jobs->WatchJob(w->ctx.get(), request);
    v1::Job first;
    return w->reader->Read(&first);
  };
  auto refused = [](Watch& w, const std::string& limit) {
    const grpc::Status s = w.reader->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
    EXPECT_NE(s.error_message().find(limit), std::string::npos) << s.error_message();
  };
  std::vector<Watch> alpha(kTenantCap);
  for (Watch& w : alpha) ASSERT_TRUE(watch("alpha", alpha_job, &w));
  const long threads_watching = daemon.threads();
  // Not a thread each (there were 300 more before): gRPC's pollers and
  // executors may grow a little with the connections' traffic.
  EXPECT_LT(threads_watching - threads_before, 40) << threads_before << " threads before, " << threads_watching
                                                  << " with " << kTenantCap << " watches";
  Watch over;
  EXPECT_FALSE(watch("alpha", alpha_job, &over));
  refused(over, "max_tenant_streams = " + std::to_string(kTenantCap));

  // Beta is served: its calls, and its watches up to the daemon's cap.
  v1::Job got;
  v1::GetJobRequest get;
  get.set_id(beta_job);
  EXPECT_TRUE(jobs->GetJob(as("beta").get(), get, &got).ok());
  v1::ListDatasetsResponse listed;
  EXPECT_TRUE(datasets->ListDatasets(as("beta").get(), {}, &listed).ok());
  std::vector<Watch> beta(kCap - kTenantCap);
  for (Watch& w : beta) ASSERT_TRUE(watch("beta", beta_job, &w));
  Watch beyond;
  EXPECT_FALSE(watch("beta", beta_job, &beyond));
  refused(beyond, "max_streams = " + std::to_string(kCap));

  // Closed watches give their places back.
  for (Watch& w : alpha) w.ctx->TryCancel();
  for (Watch& w : alpha) EXPECT_EQ(w.reader->Finish().error_code(), grpc::StatusCode::CANCELLED);
  Watch again;
  EXPECT_TRUE(testing::wait_until([&] { return watch("alpha", alpha_job, &again); }, testing::kWait,
                                  "a watch opened once the others closed"));
  again.ctx->TryCancel();
  again.reader->Finish();
  for (Watch& w : beta) w.ctx->TryCancel();
  for (Watch& w : beta) w.reader->Finish();
  for (const auto& [tenant, id] : {std::pair{"alpha", alpha_job}, std::pair{"beta", beta_job}}) {
    v1::CancelJobRequest cancel;
    cancel.set_id(id);
    EXPECT_TRUE(jobs->CancelJob(as(tenant).get(), cancel, &got).ok());
  }
  datasets.reset();
  jobs.reset();
}

}  // namespace
}  // namespace riccati
