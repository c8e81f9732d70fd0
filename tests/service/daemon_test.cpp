// riccatid over gRPC on a loopback port: jobs, sessions, restarts, bad input.
// The daemon is the real binary in a child process; references are the
// engine run in-process on the same data.
#include <gtest/gtest.h>

#include <google/protobuf/util/message_differencer.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <functional>
#include <future>

#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "service/daemon_fixture.hpp"
#include "support/metrics.hpp"
#include "support/requests.hpp"
#include "support/postgres.hpp"
#include "support/two_tank_hensen.hpp"
#include "support/wait.hpp"
#include "engine/estimation/identification.hpp"
#include "engine/models/plugin_loader.hpp"
#include "riccati/v1/datasets.grpc.pb.h"
#include "riccati/v1/jobs.grpc.pb.h"
#include "riccati/v1/models.grpc.pb.h"
#include "riccati/v1/sessions.grpc.pb.h"

namespace riccati {
namespace {

using testing::DaemonProcess;
using testing::DaemonTest;
using testing::free_port;
using testing::http_get;
using testing::kWait;
using testing::read_file;
using testing::sample_value;
using testing::TempDir;
using testing::two_tank_session;

const std::string kData = RICCATI_TEST_DATA_DIR;

// The most passes whose result fits the max_result_bytes default (256 MiB;
// a pass's trace is 4 parameters x 2000 samples x 8 bytes): tens of
// seconds of work (a Hensen pass on two_tank.csv takes about 10 ms here),
// for a job that must still be running when a test looks, and that the
// test cancels or a stop interrupts.
constexpr int kEndlessPasses = 4'000;

// The same, with the daemon's metrics on a loopback port: there a test
// sees when the daemon has finished a call (riccati_rpc_total counts each
// call as its status goes out, after the handler has done all it does).
class DaemonWithMetricsTest : public DaemonTest {
 protected:
  void SetUp() override {
    metrics_port_ = free_port();
    ASSERT_GT(metrics_port_, 0);
    daemon_ = std::make_unique<DaemonProcess>(
        dir_.path() / "data", std::vector<std::string>{"--metrics-listen", "127.0.0.1:" + std::to_string(metrics_port_)});
    daemon_->start();
    connect();
  }

  // Calls of `method` ("/riccati.v1.DatasetService/UploadDataset") the
  // daemon has finished, whatever their status.
  double calls_finished(const std::string& method) {
    std::istringstream page(http_get(metrics_port_, "/metrics"));
    double total = 0;
    for (std::string line; std::getline(page, line);) {
      if (line.rfind("riccati_rpc_total{", 0) == 0 && line.find("method=\"" + method + "\"") != std::string::npos) {
        total += std::stod(line.substr(line.rfind(' ') + 1));
      }
    }
    return total;
  }

  int metrics_port_ = 0;
};

TEST_F(DaemonTest, ListsTheBuiltInModels) {
  grpc::ClientContext ctx;
  v1::ListModelsResponse list;
  ASSERT_TRUE(models_->ListModels(&ctx, {}, &list).ok());
  std::vector<std::string> names;
  for (const auto& m : list.models()) names.push_back(m.name());
  EXPECT_EQ(names, (std::vector<std::string>{"flexible_manipulator", "rotary_pendulum", "rotating_arm", "two_tank"}));
  grpc::ClientContext ctx2;
  v1::GetModelRequest get;
  get.set_name("two_tank");
  v1::ModelInfo info;
  ASSERT_TRUE(models_->GetModel(&ctx2, get, &info).ok());
  EXPECT_EQ(info.param_names_size(), 4);
  EXPECT_TRUE(info.exact_f_jacobian());
  EXPECT_TRUE(info.jacobian_check().checked()) << info.jacobian_check().detail();
  EXPECT_TRUE(info.jacobian_check().agrees()) << info.jacobian_check().detail();
  EXPECT_EQ(info.jacobian_check().disagreements_size(), 0);
}

TEST_F(DaemonTest, IdentificationJobEqualsTheEngineInProcess) {
  const std::string id = upload_two_tank();
  const v1::Job submitted = submit(hensen(id));
  EXPECT_EQ(submitted.state(), v1::JOB_STATE_QUEUED);
  const v1::Job done = wait_for(submitted.id());
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error().message();
  EXPECT_EQ(done.progress().pass_number(), 10u);
  const v1::JobResult result = result_of(submitted.id());
  ASSERT_TRUE(result.has_identification());

  // The same run in this process, on the same file.
  auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  auto data = read_csv_file(kData + "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
  auto local = identify(registry.find("two_tank"), data, testing::two_tank_hensen());
  ASSERT_TRUE(local.is_ok());
  const auto& remote = result.identification();
  ASSERT_EQ(remote.theta_mean_size(), 4);
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(remote.theta_mean(i), local.value().theta_mean[i]) << i;  // the same numbers, not close ones
    EXPECT_EQ(remote.theta_std(i), local.value().theta_std[i]) << i;
  }
  EXPECT_EQ(remote.passes_size(), 10);
  EXPECT_EQ(remote.y_model().cols(), 2000u);
}

TEST_F(DaemonTest, ValidationJobWithTrueParametersFitsAbove99Point9) {
  const std::string id = upload_two_tank();
  v1::ValidationSpec spec;
  spec.set_model("two_tank");
  spec.set_dataset_id(id);
  for (double v : {10.0, 5.0, 0.0791, 0.1342}) spec.mutable_theta()->add_values(v);
  spec.mutable_initial_state()->set_first_measurement(true);
  grpc::ClientContext ctx;
  v1::Job job;
  ASSERT_TRUE(jobs_->SubmitValidation(&ctx, spec, &job).ok());
  ASSERT_EQ(wait_for(job.id()).state(), v1::JOB_STATE_SUCCEEDED);
  const v1::JobResult result = result_of(job.id());
  ASSERT_TRUE(result.has_validation());
  ASSERT_EQ(result.validation().fits_size(), 2);
  for (const auto& fit : result.validation().fits()) EXPECT_GT(fit.fit_percent(), 99.9) << fit.name();
}

TEST_F(DaemonTest, StreamingASessionEqualsTheOfflineFilter) {
  // rotary_pendulum_noisy.csv through a UKF session, one measurement per
  // message, against one pass of the same filter offline.
  const auto data = read_csv_file(kData + "/rotary_pendulum_noisy.csv", ColumnMapping{"t", {"v"}, {"phi", "alpha"}})
                        .value();
  v1::CreateSessionRequest create;
  create.set_model("rotary_pendulum");
  create.mutable_filter()->set_kind(v1::FILTER_KIND_UKF);
  for (double r : {4e-6, 4e-6}) create.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(r);
  for (double x : {0.0, 0.0, 0.0, 0.0}) create.mutable_initial_state()->add_x0(x);
  for (double v : {0.06, 0.15, 0.22}) create.add_theta0(v);
  for (double v : {1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4}) create.mutable_p0()->mutable_diagonal()->add_values(v);
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions_->CreateSession(&ctx, create, &session).ok());
  }

  grpc::ClientContext ctx;
  auto stream = sessions_->Stream(&ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  ASSERT_TRUE(stream->Write(open));
  std::vector<v1::Estimate> estimates;
  for (Eigen::Index k = 0; k < data.size(); ++k) {
    v1::StreamRequest request;
    testing::add_sample(request, data, k);
    ASSERT_TRUE(stream->Write(request));
    v1::StreamResponse response;
    ASSERT_TRUE(stream->Read(&response));
    ASSERT_EQ(response.results_size(), 1);
    ASSERT_TRUE(response.results(0).has_estimate()) << response.results(0).error().message();
    estimates.push_back(response.results(0).estimate());
  }
  stream->WritesDone();
  ASSERT_TRUE(stream->Finish().ok());

  auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  IdentificationSettings s;
  s.filter.kind = FilterKind::kUkf;
  s.filter.R = Eigen::Vector2d(4e-6, 4e-6).asDiagonal();
  s.filter.Q = Eigen::MatrixXd::Zero(7, 7);
  s.initial.x0 = Eigen::VectorXd::Zero(4);
  s.initial.theta0 = Eigen::Vector3d(0.06, 0.15, 0.22);
  s.initial.P0 = Eigen::MatrixXd::Identity(7, 7) * 1e-4;
  auto offline = identify(registry.find("rotary_pendulum"), data, s);
  ASSERT_TRUE(offline.is_ok()) << offline.status().to_string();
  ASSERT_EQ(static_cast<Eigen::Index>(estimates.size()), data.size());
  double worst = 0.0;
  for (Eigen::Index k = 0; k < data.size(); ++k) {
    for (int i = 0; i < 4; ++i) worst = std::max(worst, std::abs(estimates[k].state(i) - offline.value().x_trace(i, k)));
    for (int j = 0; j < 3; ++j) {
      worst = std::max(worst, std::abs(estimates[k].state(4 + j) - offline.value().passes[0].theta_trace(j, k)));
    }
  }
  EXPECT_LT(worst, 1e-12);
}

TEST_F(DaemonTest, OptimalFilterSessionIdentifiesTheManipulator) {
  // flexible_manipulator.csv (400 Hz) streamed into an optimal filter session
  // with the weights of case C of the specification.
  const auto data =
      read_csv_file(kData + "/flexible_manipulator.csv", ColumnMapping{"t", {"T"}, {"s1", "s2"}}).value();
  const v1::CreateSessionRequest create = testing::manipulator_case_c_session();
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    const grpc::Status created = sessions_->CreateSession(&ctx, create, &session);
    ASSERT_TRUE(created.ok()) << created.error_message();
  }
  EXPECT_EQ(session.filter(), v1::FILTER_KIND_OPTIMAL);

  grpc::ClientContext ctx;
  auto stream = sessions_->Stream(&ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  ASSERT_TRUE(stream->Write(open));
  std::vector<v1::Estimate> estimates;
  constexpr Eigen::Index kBatch = 20;  // 50 ms of data a message
  for (Eigen::Index first = 0; first < data.size(); first += kBatch) {
    v1::StreamRequest request;
    for (Eigen::Index k = first; k < std::min(first + kBatch, data.size()); ++k) {
      testing::add_sample(request, data, k);
    }
    ASSERT_TRUE(stream->Write(request));
    v1::StreamResponse response;
    ASSERT_TRUE(stream->Read(&response));
    for (const auto& result : response.results()) {
      ASSERT_TRUE(result.has_estimate()) << result.error().message();
      estimates.push_back(result.estimate());
    }
  }
  stream->WritesDone();
  ASSERT_TRUE(stream->Finish().ok());
  ASSERT_EQ(static_cast<Eigen::Index>(estimates.size()), data.size());

  // Against the truth (the dataset's JSON): within 5 % after 5 s of data,
  // within 1 % after 30 s.
  std::ifstream json_file(kData + "/flexible_manipulator.json");
  const auto json = nlohmann::json::parse(json_file);
  auto worst_error = [&](const v1::Estimate& e) {
    double worst = 0.0;
    int j = 0;
    for (const auto& name : json["parameter_order"]) {
      const double truth = json["parameters"][name.get<std::string>()];
      worst = std::max(worst, std::abs(e.state(4 + j++) - truth) / truth);
    }
    return worst;
  };
  EXPECT_LT(worst_error(estimates[2000]), 0.05);
  EXPECT_LT(worst_error(estimates.back()), 0.01);
  // What the optimal filter adds to an estimate: the torque and the two
  // accelerations, and the residuals of its five equations.
  EXPECT_EQ(estimates.back().estimated_inputs_size(), 3);
  EXPECT_EQ(estimates.back().residuals_size(), 5);

  // The same as the filter offline, in this process, to rounding.
  auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  IdentificationSettings s;
  s.filter.kind = FilterKind::kOptimal;
  s.filter.integrator.substeps = 1;
  // The request's numbers, read back from it.
  auto vector_of = [](const google::protobuf::RepeatedField<double>& values) {
    return Eigen::Map<const Eigen::VectorXd>(values.data(), values.size()).eval();
  };
  const v1::OptimalSettings& weights = create.filter().optimal();
  s.filter.optimal.V = vector_of(weights.v().diagonal().values()).asDiagonal();
  s.filter.optimal.W = vector_of(weights.w().diagonal().values()).asDiagonal();
  s.initial.x0 = vector_of(create.initial_state().x0());
  s.initial.theta0 = vector_of(create.theta0());
  s.initial.P0 = vector_of(weights.r0().diagonal().values()).cwiseInverse().asDiagonal();
  auto offline = identify(registry.find("flexible_manipulator"), data, s);
  ASSERT_TRUE(offline.is_ok()) << offline.status().to_string();
  double gap = 0.0;
  for (int j = 0; j < 6; ++j) {
    const double theta = offline.value().theta[j];
    gap = std::max(gap, std::abs(estimates.back().state(4 + j) - theta) / std::abs(theta));
  }
  EXPECT_LT(gap, 1e-12);
}

TEST_F(DaemonTest, RestartKeepsDatasetsJobsAndResultsAndFinishesARunningJob) {
  const std::string dataset = upload_two_tank();
  const v1::Job quick = submit(hensen(dataset, 1));
  ASSERT_EQ(wait_for(quick.id()).state(), v1::JOB_STATE_SUCCEEDED);
  // A long job, stopped while it runs, after a pass (a checkpoint): the
  // 99 passes left take about a second, which the stop, a few
  // milliseconds after the look, cannot wait for.
  constexpr int kPasses = 100;
  const v1::Job slow = submit(hensen(dataset, kPasses));
  const v1::Job running = wait_running(slow.id(), 1);
  ASSERT_EQ(running.state(), v1::JOB_STATE_RUNNING) << "the job ended before the stop: " << running.ShortDebugString();
  const auto signalled = std::chrono::system_clock::now();
  EXPECT_EQ(daemon_->stop(), 0) << daemon_->exit_report();  // SIGTERM: a clean exit

  daemon_->start();
  connect();
  {
    grpc::ClientContext ctx;
    v1::GetDatasetRequest get;
    get.set_id(dataset);
    v1::DatasetInfo info;
    ASSERT_TRUE(datasets_->GetDataset(&ctx, get, &info).ok());
    EXPECT_EQ(info.samples(), 2000u);
  }
  {
    grpc::ClientContext ctx;
    v1::ListJobsResponse list;
    ASSERT_TRUE(jobs_->ListJobs(&ctx, {}, &list).ok());
    EXPECT_EQ(list.jobs_size(), 2);
  }
  EXPECT_TRUE(result_of(quick.id()).has_identification());
  const v1::Job resumed = wait_for(slow.id());
  EXPECT_EQ(resumed.state(), v1::JOB_STATE_SUCCEEDED) << resumed.error().message();
  EXPECT_EQ(result_of(slow.id()).identification().passes_size(), kPasses);
  // It was still running when SIGTERM went out: it ended after (the
  // daemon's clock is this machine's; its timestamps are in milliseconds).
  const auto signalled_ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(signalled.time_since_epoch()).count();
  const auto finished_ms = resumed.finished().seconds() * 1000 + resumed.finished().nanos() / 1'000'000;
  EXPECT_GT(finished_ms, signalled_ms) << "the job had ended before the stop";
}

// kill -9 in the middle of a job: after the restart the job goes on from its
// last completed pass (watchers never see it start over), and its result is
// the uninterrupted run's, to the bit; nothing accepted before is lost.
TEST_F(DaemonTest, KillDashNineMidJobResumesFromTheLastCompletedPass) {
  constexpr int kPasses = 100;
  const std::string dataset = upload_two_tank();
  const v1::Job quick = submit(hensen(dataset, 1));
  ASSERT_EQ(wait_for(quick.id()).state(), v1::JOB_STATE_SUCCEEDED);
  const v1::Job slow = submit(hensen(dataset, kPasses));
  std::uint32_t pass_at_kill = 0;
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    v1::WatchJobRequest watch;
    watch.set_id(slow.id());
    auto reader = jobs_->WatchJob(&ctx, watch);
    v1::Job job;
    while (reader->Read(&job)) {
      if (job.progress().pass_number() >= 10) break;
    }
    pass_at_kill = job.progress().pass_number();
    ASSERT_GE(pass_at_kill, 10u) << "the job ended before it could be killed: " << job.ShortDebugString();
    EXPECT_EQ(daemon_->kill_now(), 128 + SIGKILL);
    ctx.TryCancel();
  }

  daemon_->start();
  connect();
  EXPECT_TRUE(result_of(quick.id()).has_identification());
  std::uint32_t first_pass_after = 0;
  v1::Job done;
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    v1::WatchJobRequest watch;
    watch.set_id(slow.id());
    auto reader = jobs_->WatchJob(&ctx, watch);
    while (reader->Read(&done)) {
      if (first_pass_after == 0 && done.progress().pass_number() > 0) first_pass_after = done.progress().pass_number();
      EXPECT_GE(done.progress().pass_number() + 1, pass_at_kill) << "the job started over";
    }
    ASSERT_TRUE(reader->Finish().ok());
  }
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error().message();
  EXPECT_GE(first_pass_after + 1, pass_at_kill);

  const v1::JobResult result = result_of(slow.id());
  auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  auto data = read_csv_file(kData + "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
  auto uninterrupted = identify(registry.find("two_tank"), data, testing::two_tank_hensen(FilterKind::kEkf, kPasses));
  ASSERT_TRUE(uninterrupted.is_ok());
  const auto& remote = result.identification();
  ASSERT_EQ(remote.passes_size(), kPasses);
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(remote.theta(i), uninterrupted.value().theta[i]) << i;
    EXPECT_EQ(remote.theta_mean(i), uninterrupted.value().theta_mean[i]) << i;
  }
  for (int p : {0, 10, kPasses - 1}) {
    EXPECT_EQ(remote.passes(p).theta_final(0), uninterrupted.value().passes[static_cast<std::size_t>(p)].theta_final[0])
        << "pass " << p + 1;
  }
}

// SIGTERM with a stream open and a job being watched: both end with
// UNAVAILABLE and a message saying what to do (not cancelled when the grace
// period runs out), the daemon exits 0, and the job finishes after the
// restart.
TEST_F(DaemonTest, SigtermEndsStreamsAndWatchesWithUnavailableAndExitsCleanly) {
  const std::string dataset = upload_two_tank();
  const v1::Job slow = submit(hensen(dataset, 100));
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions_->CreateSession(&ctx, two_tank_session(), &session).ok());
  }
  grpc::ClientContext stream_ctx;
  auto stream = sessions_->Stream(&stream_ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  ASSERT_TRUE(stream->Write(open));
  grpc::ClientContext watch_ctx;
  v1::WatchJobRequest watch;
  watch.set_id(slow.id());
  auto watcher = jobs_->WatchJob(&watch_ctx, watch);
  v1::Job seen;
  ASSERT_TRUE(watcher->Read(&seen));  // the watch is in place
  // Clients blocked reading, as a rig and a watching user are.
  auto streamed = std::async(std::launch::async, [&] {
    v1::StreamResponse response;
    while (stream->Read(&response)) {
    }
    return stream->Finish();
  });
  auto watched = std::async(std::launch::async, [&] {
    while (watcher->Read(&seen)) {
    }
    return watcher->Finish();
  });

  EXPECT_EQ(daemon_->stop(), 0) << daemon_->exit_report();

  const grpc::Status stream_status = streamed.get();
  EXPECT_EQ(stream_status.error_code(), grpc::StatusCode::UNAVAILABLE) << stream_status.error_message();
  EXPECT_NE(stream_status.error_message().find("shutting down"), std::string::npos) << stream_status.error_message();
  EXPECT_NE(stream_status.error_message().find("open the stream again"), std::string::npos)
      << stream_status.error_message();
  const grpc::Status watch_status = watched.get();
  EXPECT_EQ(watch_status.error_code(), grpc::StatusCode::UNAVAILABLE) << watch_status.error_message();
  EXPECT_NE(watch_status.error_message().find("watch again"), std::string::npos) << watch_status.error_message();

  daemon_->start();
  connect();
  const v1::Job done = wait_for(slow.id());
  EXPECT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error().message();
  // The session came back with the restart, as the message said.
  grpc::ClientContext get_ctx;
  v1::GetSessionRequest get;
  get.set_id(session.id());
  const grpc::Status got = sessions_->GetSession(&get_ctx, get, &session);
  EXPECT_TRUE(got.ok()) << got.error_message();
  EXPECT_EQ(session.state(), v1::SESSION_STATE_IDLE);
}

// An optimal filter session (the manipulator, case C) streamed half way,
// riccatid restarted on its SQLite store, then the rest: every estimate
// after the restart is the uninterrupted session's, to the bit.
TEST_F(DaemonTest, AnOptimalFilterSessionContinuesBitForBitAfterARestart) {
  const auto data =
      read_csv_file(kData + "/flexible_manipulator.csv", ColumnMapping{"t", {"T"}, {"s1", "s2"}}).value();
  auto create = [&] {
    grpc::ClientContext ctx;
    v1::SessionInfo info;
    const grpc::Status s = sessions_->CreateSession(&ctx, testing::manipulator_case_c_session(), &info);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return info.id();
  };
  // Samples [from, to) in batches of 20 (50 ms of data); the estimates.
  auto stream = [&](const std::string& id, Eigen::Index from, Eigen::Index to) {
    grpc::ClientContext ctx;
    return testing::stream_samples(*sessions_, &ctx, id, data, from, to, 20);
  };
  const std::vector<v1::Estimate> reference = stream(create(), 0, data.size());
  ASSERT_EQ(static_cast<Eigen::Index>(reference.size()), data.size());

  const Eigen::Index half = data.size() / 2;
  const std::string id = create();
  ASSERT_EQ(static_cast<Eigen::Index>(stream(id, 0, half).size()), half);
  EXPECT_EQ(daemon_->stop(), 0) << daemon_->exit_report();
  daemon_->start();
  connect();

  v1::SessionInfo info;
  {
    grpc::ClientContext ctx;
    v1::GetSessionRequest get;
    get.set_id(id);
    const grpc::Status s = sessions_->GetSession(&ctx, get, &info);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  EXPECT_EQ(info.t(), data.t[half - 1]);
  EXPECT_EQ(info.measurements(), static_cast<std::uint64_t>(half));
  const std::vector<v1::Estimate> rest = stream(id, half, data.size());
  ASSERT_EQ(static_cast<Eigen::Index>(rest.size()), data.size() - half);
  for (Eigen::Index k = half; k < data.size(); ++k) {
    const v1::Estimate& e = rest[static_cast<std::size_t>(k - half)];
    const v1::Estimate& r = reference[static_cast<std::size_t>(k)];
    ASSERT_EQ(e.t(), r.t());
    for (int j = 0; j < r.state_size(); ++j) ASSERT_EQ(e.state(j), r.state(j)) << "sample " << k << " state " << j;
    for (int j = 0; j < r.std_size(); ++j) ASSERT_EQ(e.std(j), r.std(j)) << "sample " << k << " std " << j;
    for (int j = 0; j < r.estimated_inputs_size(); ++j) {
      ASSERT_EQ(e.estimated_inputs(j), r.estimated_inputs(j)) << "sample " << k << " input " << j;
    }
    for (int j = 0; j < r.residuals_size(); ++j) {
      ASSERT_EQ(e.residuals(j), r.residuals(j)) << "sample " << k << " residual " << j;
    }
    ASSERT_EQ(e.nis(), r.nis()) << "sample " << k;
  }
}

// A client that sends and never reads its responses: the daemon stops
// reading it (a response is written before the next message is read, and
// writes wait for the client), so the client's writes block instead of the
// daemon's memory growing; once it reads, every response arrives, in order.
TEST_F(DaemonTest, ASlowConsumerIsHeldBackNotBuffered) {
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions_->CreateSession(&ctx, two_tank_session(), &session).ok());
  }
  grpc::ClientContext ctx;
  auto stream = sessions_->Stream(&ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  open.mutable_open()->set_full_covariance(true);  // large responses: the buffers fill sooner
  ASSERT_TRUE(stream->Write(open));
  constexpr int kMessages = 5000, kPerMessage = 64;
  const long rss_before = daemon_->rss_kib();
  std::atomic<int> written{0};
  std::thread writer([&] {
    for (int m = 0; m < kMessages; ++m) {
      v1::StreamRequest batch;
      for (int k = 0; k < kPerMessage; ++k) {
        testing::add_measurement(batch, 0.1 * (m * kPerMessage + k + 1), {1e-5, 1e-5}, {0.5, 0.5});
      }
      if (!stream->Write(batch)) return;
      ++written;
    }
    stream->WritesDone();
  });
  // Unread, the daemon would get through all of them in well under a second.
  // Held back, it stops reading once the transport's buffers (a few MB,
  // sized by TCP and HTTP/2 flow control as they see fit) are full: the
  // count of accepted messages stalls short of the whole.
  int accepted_unread = 0;
  for (int still = 0, waited = 0; still < 10 && waited < 100; ++waited) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    const int now = written.load();
    still = now == accepted_unread ? still + 1 : 0;
    accepted_unread = now;
  }
  const long rss_held = daemon_->rss_kib();
  EXPECT_LT(accepted_unread, kMessages) << "the daemon kept reading a client that does not read";

  std::uint64_t expected_sequence = 0;
  int responses = 0;
  v1::StreamResponse response;
  while (stream->Read(&response)) {
    ++responses;
    for (const auto& r : response.results()) {
      EXPECT_EQ(r.sequence(), expected_sequence++);
      EXPECT_TRUE(r.has_estimate()) << r.ShortDebugString();
    }
  }
  writer.join();
  const grpc::Status s = stream->Finish();
  EXPECT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(responses, kMessages);
  EXPECT_EQ(expected_sequence, static_cast<std::uint64_t>(kMessages) * kPerMessage);
  // What the held-back client cost the daemon: bounded by the transport's
  // buffers, not by what the client sent (5000 x 30 kB of responses).
  std::printf("daemon RSS: %ld KiB before, %ld KiB while the client did not read (%d of %d messages accepted)\n",
              rss_before, rss_held, accepted_unread, kMessages);
  if (!testing::kSanitized) {
    EXPECT_LT(rss_held - rss_before, 32 * 1024);
  }
}

// Every field of a request is checked before it is used: each bad value is
// refused with INVALID_ARGUMENT naming the field, and nothing is stored.
// (docs/bad-inputs.md lists these cases.)
TEST_F(DaemonTest, RequestFieldsAreValidatedBeforeUse) {
  const std::string dataset = upload_two_tank();
  struct Case {
    const char* what;
    std::function<void(v1::IdentificationSpec&)> spoil;
    const char* named;  // in the message
  };
  const std::vector<Case> cases = {
      {"unknown filter kind", [](auto& s) { s.mutable_filter()->set_kind(static_cast<v1::FilterKind>(99)); }, "kind"},
      {"unknown integrator kind",
       [](auto& s) { s.mutable_filter()->mutable_integrator()->set_kind(static_cast<v1::IntegratorKind>(42)); },
       "integrator"},
      {"unknown hold order", [](auto& s) { s.mutable_filter()->set_hold(static_cast<v1::HoldOrder>(7)); }, "hold"},
      {"negative measurement variance", [](auto& s) { s.mutable_filter()->mutable_r()->mutable_diagonal()->set_values(0, -1e-3); }, "r"},
      {"NaN measurement variance",
       [](auto& s) { s.mutable_filter()->mutable_r()->mutable_diagonal()->set_values(1, std::nan("")); }, "r"},
      {"infinite theta0", [](auto& s) { s.set_theta0(0, std::numeric_limits<double>::infinity()); }, "theta0"},
      {"negative initial variance", [](auto& s) { s.mutable_p0()->mutable_diagonal()->set_values(2, -10.0); }, "P0"},
      {"indefinite initial covariance", [](auto& s) {
         s.mutable_p0()->clear_diagonal();
         auto* full = s.mutable_p0()->mutable_full();
         full->set_rows(6);
         full->set_cols(6);
         for (int i = 0; i < 36; ++i) full->add_values(i % 7 == 0 ? 1.0 : 0.0);
         full->set_values(2 * 6 + 3, 5.0);  // P(2,3) = P(3,2) = 5 > sqrt(P22 P33)
         full->set_values(3 * 6 + 2, 5.0);
       }, "positive semi-definite"},
      {"negative process noise", [](auto& s) {
         for (double q : {0.0, 0.0, 0.0, 0.0, 0.0, -1.0}) s.mutable_filter()->mutable_q()->mutable_diagonal()->add_values(q);
       }, "process noise Q"},
      {"negative tolerance", [](auto& s) {
         s.mutable_filter()->mutable_integrator()->set_kind(v1::INTEGRATOR_KIND_CVODE_BDF);
         s.mutable_filter()->mutable_integrator()->set_rtol(-1.0);
       }, "rtol"},
      {"huge substeps", [](auto& s) { s.mutable_filter()->mutable_integrator()->set_substeps(4'000'000'000u); }, "substeps"},
      {"full covariance of the wrong size", [](auto& s) {
         s.mutable_p0()->clear_diagonal();
         s.mutable_p0()->mutable_full()->set_rows(2);
         s.mutable_p0()->mutable_full()->set_cols(2);
         for (int i = 0; i < 4; ++i) s.mutable_p0()->mutable_full()->add_values(1.0);
       }, "p0"},
      {"a matrix whose values do not match its size", [](auto& s) {
         s.mutable_p0()->clear_diagonal();
         s.mutable_p0()->mutable_full()->set_rows(6);
         s.mutable_p0()->mutable_full()->set_cols(6);
         s.mutable_p0()->mutable_full()->add_values(1.0);
       }, "p0"},
  };
  for (const Case& c : cases) {
    v1::IdentificationSpec spec = hensen(dataset);
    c.spoil(spec);
    grpc::ClientContext ctx;
    v1::Job job;
    const grpc::Status s = jobs_->SubmitIdentification(&ctx, spec, &job);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.what << ": " << s.error_message();
    EXPECT_NE(s.error_message().find(c.named), std::string::npos) << c.what << ": " << s.error_message();
  }
  grpc::ClientContext ctx;
  v1::ListJobsResponse jobs;
  ASSERT_TRUE(jobs_->ListJobs(&ctx, {}, &jobs).ok());
  EXPECT_EQ(jobs.jobs_size(), 0) << "a refused job was stored";
  expect_serving();
}

// A model that returns NaN: the session streaming it ends with
// FAILED_PRECONDITION naming the state, a job on it fails the same way, and
// a session of another model on the same daemon streams on.
TEST(DaemonFaults, AFailingModelEndsOnlyItsOwnSessionAndJob) {
  TempDir dir;
  const auto models = dir.path() / "models";
  std::filesystem::create_directories(models);
  std::filesystem::copy_file(std::string(RICCATI_TEST_PLUGIN_DIR) + "/two_tank.so", models / "two_tank.so");
  std::filesystem::copy_file(std::string(RICCATI_TEST_BAD_PLUGIN_DIR) + "/nan_f.so", models / "nan_f.so");
  DaemonProcess daemon(dir.path() / "data", {"--models-dir", models.string()});
  daemon.start();
  auto sessions = v1::SessionService::NewStub(daemon.channel());
  auto datasets = v1::DatasetService::NewStub(daemon.channel());
  auto jobs = v1::JobService::NewStub(daemon.channel());

  auto open_stream = [&](const v1::CreateSessionRequest& create, grpc::ClientContext* ctx) {
    v1::SessionInfo info;
    grpc::ClientContext create_ctx;
    EXPECT_TRUE(sessions->CreateSession(&create_ctx, create, &info).ok());
    auto stream = sessions->Stream(ctx);
    v1::StreamRequest open;
    open.mutable_open()->set_session_id(info.id());
    stream->Write(open);
    return stream;
  };
  auto measurement = [](double t, std::vector<double> u, std::vector<double> y) {
    v1::StreamRequest r;
    v1::Measurement* m = r.mutable_batch()->add_measurements();
    m->set_t(t);
    for (double v : u) m->add_u(v);
    for (double v : y) m->add_y(v);
    return r;
  };

  grpc::ClientContext good_ctx;
  auto good = open_stream(testing::two_tank_session(), &good_ctx);
  v1::CreateSessionRequest nan_session;
  nan_session.set_model("nan_f");
  nan_session.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(1e-3);
  for (double x : {0.0, 0.0}) nan_session.mutable_initial_state()->add_x0(x);
  for (double p : {1e-2, 1e-2, 1e-2}) nan_session.mutable_p0()->mutable_diagonal()->add_values(p);
  grpc::ClientContext bad_ctx;
  auto bad = open_stream(nan_session, &bad_ctx);

  v1::StreamResponse response;
  ASSERT_TRUE(good->Write(measurement(0.0, {0.1, 0.03}, {0.4, 0.15})) && good->Read(&response));
  ASSERT_TRUE(bad->Write(measurement(0.0, {}, {0.0})) && bad->Read(&response));  // the first one only updates
  ASSERT_TRUE(bad->Write(measurement(0.1, {}, {0.0})));  // the prediction meets the NaN
  while (bad->Read(&response)) {
  }
  const grpc::Status failed = bad->Finish();
  EXPECT_EQ(failed.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << failed.error_message();
  EXPECT_NE(failed.error_message().find("velocity"), std::string::npos) << failed.error_message();

  // A job on the failing model fails with the same kind of message.
  {
    grpc::ClientContext ctx;
    v1::DatasetInfo info;
    auto writer = datasets->UploadDataset(&ctx, &info);
    writer->Write(testing::upload_header("nan.csv", {}, {"position"}));
    v1::UploadDatasetRequest part;
    part.set_chunk("t,position\n0,0\n0.1,0\n0.2,0\n");
    writer->Write(part);
    writer->WritesDone();
    ASSERT_TRUE(writer->Finish().ok());
    v1::IdentificationSpec spec;
    spec.set_model("nan_f");
    spec.set_dataset_id(info.id());
    spec.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(1e-3);
    for (double p : {1e-2, 1e-2, 1e-2}) spec.mutable_p0()->mutable_diagonal()->add_values(p);
    for (double x : {0.0, 0.0}) spec.mutable_initial_state()->add_x0(x);
    grpc::ClientContext submit_ctx;
    v1::Job job;
    ASSERT_TRUE(jobs->SubmitIdentification(&submit_ctx, spec, &job).ok());
    grpc::ClientContext watch_ctx;
    v1::WatchJobRequest watch;
    watch.set_id(job.id());
    auto reader = jobs->WatchJob(&watch_ctx, watch);
    while (reader->Read(&job)) {
    }
    EXPECT_EQ(job.state(), v1::JOB_STATE_FAILED);
    EXPECT_EQ(job.error().code(), static_cast<int>(grpc::StatusCode::FAILED_PRECONDITION));
    EXPECT_NE(job.error().message().find("velocity"), std::string::npos) << job.error().message();
    // Its progress stops where its error says it failed: one sample of pass 1 done.
    EXPECT_NE(job.error().message().find("pass 1, sample 2"), std::string::npos) << job.error().message();
    EXPECT_EQ(job.progress().pass_number(), 1u) << job.ShortDebugString();
    EXPECT_EQ(job.progress().sample(), 1u) << job.ShortDebugString();
  }

  // The other session goes on.
  ASSERT_TRUE(good->Write(measurement(1.0, {0.1, 0.03}, {0.41, 0.15})));
  ASSERT_TRUE(good->Read(&response));
  ASSERT_EQ(response.results_size(), 1);
  EXPECT_TRUE(response.results(0).has_estimate());
  good->WritesDone();
  EXPECT_TRUE(good->Finish().ok());
}

// An INTERNAL error (here a plugin that throws) is the daemon's or a
// plugin's fault, not the request's: the client gets an incident id to quote
// with the message, and the log has the same id.
TEST(DaemonFaults, AnInternalErrorGivesTheClientAnIncidentIdThatTheLogHas) {
  TempDir dir;
  const auto models = dir.path() / "models";
  std::filesystem::create_directories(models);
  std::filesystem::copy_file(std::string(RICCATI_TEST_BAD_PLUGIN_DIR) + "/throwing_f.so", models / "throwing_f.so");
  DaemonProcess daemon(dir.path() / "data", {"--models-dir", models.string(), "--log-level", "info"});
  const auto log = dir.path() / "riccatid.log";
  daemon.set_log_file(log);
  daemon.start();
  auto models_stub = v1::ModelService::NewStub(daemon.channel());
  v1::SimulateRequest request;
  request.set_model("throwing_f");
  request.add_x0(0.0);
  for (double t : {0.0, 0.1, 0.2}) request.add_t(t);
  request.mutable_u()->set_cols(3);  // no inputs, three samples
  grpc::ClientContext ctx;
  v1::SimulateResponse response;
  const grpc::Status s = models_stub->Simulate(&ctx, request, &response);
  ASSERT_EQ(s.error_code(), grpc::StatusCode::INTERNAL) << s.error_message();
  const auto at = s.error_message().find("incident-");
  ASSERT_NE(at, std::string::npos) << s.error_message();
  const std::string incident = s.error_message().substr(at, s.error_message().find(':', at) - at);
  EXPECT_NE(s.error_message().find("deliberate exception from throwing_f"), std::string::npos) << s.error_message();
  models_stub.reset();
  EXPECT_EQ(daemon.stop(), 0) << daemon.exit_report();
  const std::string logged = read_file(log);
  EXPECT_NE(logged.find("internal error incident=" + incident), std::string::npos) << incident << "\n" << logged;
}

// A model whose hand-written Jacobian has a sign wrong
// (bad_plugins/wrong_jacobian.cpp) loads and runs, as it must: only the check
// can tell. GetModel says which entry disagrees, and an identification job
// on it carries the same warning at its own start point.
TEST(DaemonFaults, AWrongJacobianIsReportedByTheModelAndAtJobStart) {
  TempDir dir;
  const auto models = dir.path() / "models";
  std::filesystem::create_directories(models);
  std::filesystem::copy_file(std::string(RICCATI_TEST_BAD_PLUGIN_DIR) + "/wrong_jacobian.so", models / "wrong_jacobian.so");
  DaemonProcess daemon(dir.path() / "data", {"--models-dir", models.string()});
  daemon.start();
  auto model_service = v1::ModelService::NewStub(daemon.channel());
  auto datasets = v1::DatasetService::NewStub(daemon.channel());
  auto jobs = v1::JobService::NewStub(daemon.channel());

  v1::ModelInfo info;
  {
    grpc::ClientContext ctx;
    v1::GetModelRequest get;
    get.set_name("wrong_jacobian");
    ASSERT_TRUE(model_service->GetModel(&ctx, get, &info).ok());
  }
  const v1::JacobianCheck& check = info.jacobian_check();
  EXPECT_TRUE(check.checked());
  EXPECT_FALSE(check.agrees());
  ASSERT_EQ(check.disagreements_size(), 1) << check.detail();
  EXPECT_NE(check.disagreements(0).find("d velocity' / d angle"), std::string::npos) << check.disagreements(0);

  // A short swing of the pendulum, simulated by the daemon (f itself is right).
  v1::SimulateRequest sim;
  sim.set_model("wrong_jacobian");
  for (double x : {0.5, 0.0}) sim.add_x0(x);
  std::string csv = "t,torque,angle\n";
  for (int k = 0; k < 40; ++k) sim.add_t(0.05 * k);
  sim.mutable_u()->set_rows(1);
  sim.mutable_u()->set_cols(40);
  for (int k = 0; k < 40; ++k) sim.mutable_u()->add_values(0.0);
  v1::SimulateResponse simulated;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(model_service->Simulate(&ctx, sim, &simulated).ok());
  }
  for (int k = 0; k < 40; ++k) csv += std::to_string(0.05 * k) + ",0," + std::to_string(simulated.y().values(k)) + "\n";
  v1::DatasetInfo uploaded;
  {
    grpc::ClientContext ctx;
    auto writer = datasets->UploadDataset(&ctx, &uploaded);
    writer->Write(testing::upload_header("swing.csv", {"torque"}, {"angle"}));
    v1::UploadDatasetRequest part;
    part.set_chunk(csv);
    writer->Write(part);
    writer->WritesDone();
    ASSERT_TRUE(writer->Finish().ok());
  }
  v1::IdentificationSpec spec;
  spec.set_model("wrong_jacobian");
  spec.set_dataset_id(uploaded.id());
  spec.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(1e-4);
  for (double p : {1e-4, 1e-4, 1e-2, 1e-2}) spec.mutable_p0()->mutable_diagonal()->add_values(p);
  for (double x : {0.5, 0.0}) spec.mutable_initial_state()->add_x0(x);
  spec.set_passes(1);
  v1::Job job;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(jobs->SubmitIdentification(&ctx, spec, &job).ok());
  }
  {
    grpc::ClientContext ctx;
    v1::WatchJobRequest watch;
    watch.set_id(job.id());
    auto reader = jobs->WatchJob(&ctx, watch);
    while (reader->Read(&job)) {
    }
  }
  ASSERT_EQ(job.state(), v1::JOB_STATE_SUCCEEDED) << job.error().message();
  v1::JobResult result;
  {
    grpc::ClientContext ctx;
    v1::GetResultRequest get;
    get.set_job_id(job.id());
    ASSERT_TRUE(jobs->GetResult(&ctx, get, &result).ok());
  }
  ASSERT_TRUE(result.has_identification());
  ASSERT_GE(result.identification().warnings_size(), 1);
  const std::string& warning = result.identification().warnings(0);
  EXPECT_NE(warning.find("Jacobian disagrees with finite differences at the start"), std::string::npos) << warning;
  EXPECT_NE(warning.find("d velocity' / d angle"), std::string::npos) << warning;
  EXPECT_NE(warning.find("x = [0.5, 0]"), std::string::npos) << warning;
}

TEST_F(DaemonTest, CancelStopsARunningJob) {
  const std::string dataset = upload_two_tank();
  const v1::Job slow = submit(hensen(dataset, kEndlessPasses));
  const v1::Job running = wait_running(slow.id());
  ASSERT_EQ(running.state(), v1::JOB_STATE_RUNNING) << running.ShortDebugString();
  grpc::ClientContext ctx;
  v1::CancelJobRequest cancel;
  cancel.set_id(slow.id());
  v1::Job job;
  ASSERT_TRUE(jobs_->CancelJob(&ctx, cancel, &job).ok());
  const v1::Job done = wait_for(slow.id());
  EXPECT_EQ(done.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_LT(done.progress().pass_number(), static_cast<std::uint32_t>(kEndlessPasses));
  grpc::ClientContext ctx2;
  v1::GetResultRequest get;
  get.set_job_id(slow.id());
  v1::JobResult result;
  EXPECT_EQ(jobs_->GetResult(&ctx2, get, &result).error_code(), grpc::StatusCode::FAILED_PRECONDITION);
}

TEST_F(DaemonTest, BadInputGetsClearErrorsAndTheDaemonKeepsServing) {
  v1::DatasetInfo info;
  // A CSV with a missing column.
  grpc::Status s = upload("two_tank.csv", read_file(kData + "/two_tank.csv"), {"F1", "F3"}, {"h1", "h2"}, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("missing column \"F3\""), std::string::npos) << s.error_message();
  // An empty upload.
  s = upload("empty.csv", "", {"F1"}, {"h1"}, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("empty"), std::string::npos) << s.error_message();
  // Time going backwards.
  s = upload("back.csv", "t,u,y\n0,1,2\n1,1,2\n0.5,1,2\n", {"u"}, {"y"}, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("backwards"), std::string::npos) << s.error_message();
  // A MAT file without T: the two-tank MAT file cut short is not a MAT file any more.
  const std::string mat = read_file(kData + "/two_tank.mat");
  s = upload("broken.mat", mat.substr(0, 200), {"F1", "F2"}, {"h1", "h2"}, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("broken.mat"), std::string::npos) << s.error_message();
  // Binary junk in a CSV header is quoted escaped, never raw (bytes that
  // would move a terminal's cursor, or are not UTF-8), and a name in UTF-8
  // as it is.
  s = upload("junk.csv", std::string("t,u,\x1b[2J\xff\xfe\x01,h\xc3\xb6he\n0,1,2,3\n1,1,2,3\n"), {"u"}, {"y"}, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_NE(s.error_message().find("\\x1b[2J\\xff\\xfe\\x01"), std::string::npos) << s.error_message();
  EXPECT_NE(s.error_message().find("h\xc3\xb6he"), std::string::npos) << s.error_message();
  for (const char raw : {'\x1b', '\xff', '\x01'}) {
    EXPECT_EQ(s.error_message().find(raw), std::string::npos) << "a raw byte " << int(raw) << " in the message";
  }
  // A message that is neither header nor chunk.
  {
    grpc::ClientContext ctx;
    auto writer = datasets_->UploadDataset(&ctx, &info);
    writer->Write(testing::upload_header("empty-message.csv", {"u"}, {"y"}));
    writer->Write(v1::UploadDatasetRequest());
    writer->WritesDone();
    s = writer->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
    EXPECT_NE(s.error_message().find("a message of the upload of empty-message.csv is empty"), std::string::npos)
        << s.error_message();
  }
  // A declared size the bytes do not match: more, or fewer (cut short).
  for (const std::uint64_t declared : {10ull, 1000ull}) {
    grpc::ClientContext ctx;
    auto writer = datasets_->UploadDataset(&ctx, &info);
    v1::UploadDatasetRequest header = testing::upload_header("sized.csv", {"u"}, {"y"});
    header.mutable_header()->set_size_bytes(declared);
    writer->Write(header);
    v1::UploadDatasetRequest chunk;
    chunk.set_chunk("t,u,y\n0,1,2\n1,1,2\n");
    writer->Write(chunk);
    writer->WritesDone();
    s = writer->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
    EXPECT_NE(s.error_message().find(declared == 10 ? "sends more than the 10 bytes" : "ended after 18 of the 1000 bytes"),
              std::string::npos)
        << s.error_message();
  }

  // Unknown model; wrong sizes.
  const std::string dataset = upload_two_tank();
  v1::IdentificationSpec spec = hensen(dataset);
  spec.set_model("no_such_model");
  {
    grpc::ClientContext ctx;
    v1::Job job;
    s = jobs_->SubmitIdentification(&ctx, spec, &job);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND);
    EXPECT_NE(s.error_message().find("no_such_model"), std::string::npos);
  }
  spec = hensen(dataset);
  spec.add_theta0(1.0);  // 5 parameters for a 4-parameter model
  {
    grpc::ClientContext ctx;
    v1::Job job;
    s = jobs_->SubmitIdentification(&ctx, spec, &job);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("theta0 needs 4 values, got 5"), std::string::npos) << s.error_message();
  }
  spec = hensen("ds-unknown");
  {
    grpc::ClientContext ctx;
    v1::Job job;
    EXPECT_EQ(jobs_->SubmitIdentification(&ctx, spec, &job).error_code(), grpc::StatusCode::NOT_FOUND);
  }
  expect_serving();
}

TEST_F(DaemonTest, StreamRefusesBadMeasurementsOneByOneAndGoesOn) {
  const v1::CreateSessionRequest create = two_tank_session();
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions_->CreateSession(&ctx, create, &session).ok());
  }
  grpc::ClientContext ctx;
  auto stream = sessions_->Stream(&ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  ASSERT_TRUE(stream->Write(open));
  v1::StreamRequest request;
  auto add = [&](double t, std::vector<double> u, std::vector<double> y) {
    v1::Measurement* m = request.mutable_batch()->add_measurements();
    m->set_t(t);
    for (double v : u) m->add_u(v);
    for (double v : y) m->add_y(v);
  };
  add(0.0, {0.1, 0.03}, {0.4, 0.15});
  add(1.0, {0.1, 0.03}, {std::nan(""), 0.15});  // NaN
  add(1.0, {0.1}, {0.4, 0.15});                 // wrong size
  add(1.0, {0.1, 0.03}, {0.4, 0.15});           // fine
  add(0.5, {0.1, 0.03}, {0.4, 0.15});           // time going backwards
  add(2.0, {0.1, 0.03}, {0.41, 0.15});          // fine
  add(1e308, {0.1, 0.03}, {0.41, 0.15});        // a clock's glitch: a step past max_time_step_s
  add(3.0, {0.1, 0.03}, {0.41, 0.15});          // fine: the session did not diverge
  ASSERT_TRUE(stream->Write(request));
  v1::StreamResponse response;
  ASSERT_TRUE(stream->Read(&response));
  ASSERT_EQ(response.results_size(), 8);
  EXPECT_TRUE(response.results(0).has_estimate());
  EXPECT_EQ(response.results(1).error().code(), static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT));
  EXPECT_NE(response.results(1).error().message().find("output h1 is not finite"), std::string::npos);
  EXPECT_NE(response.results(2).error().message().find("needs 2 inputs"), std::string::npos);
  EXPECT_TRUE(response.results(3).has_estimate());
  EXPECT_NE(response.results(4).error().message().find("backwards"), std::string::npos);
  EXPECT_TRUE(response.results(5).has_estimate());
  EXPECT_EQ(response.results(5).sequence(), 5u);
  EXPECT_EQ(response.results(6).error().code(), static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT));
  EXPECT_NE(response.results(6).error().message().find("more than the 3600 s a step may be"), std::string::npos)
      << response.results(6).error().message();
  EXPECT_TRUE(response.results(7).has_estimate()) << response.results(7).ShortDebugString();

  // The stream reuses its response's results from batch to batch: a result
  // that held an estimate now holds an error and the other way round, a
  // shorter batch gets only its own results, and an estimate's arrays are
  // refilled, not appended to.
  const int nz = response.results(0).estimate().state_size();
  ASSERT_GT(nz, 0);
  request.Clear();
  add(4.0, {0.1, 0.03}, {std::nan(""), 0.15});  // an error where an estimate was
  add(5.0, {0.1, 0.03}, {0.42, 0.15});          // an estimate where an error was
  add(6.0, {0.1, 0.03}, {0.42, 0.15});
  ASSERT_TRUE(stream->Write(request));
  ASSERT_TRUE(stream->Read(&response));
  ASSERT_EQ(response.results_size(), 3);
  EXPECT_TRUE(response.results(0).has_error());
  EXPECT_FALSE(response.results(0).has_estimate());
  EXPECT_EQ(response.results(0).sequence(), 8u);
  for (int i : {1, 2}) {
    const v1::MeasurementResult& r = response.results(i);
    ASSERT_TRUE(r.has_estimate()) << r.ShortDebugString();
    EXPECT_EQ(r.estimate().t(), 4.0 + i);
    EXPECT_EQ(r.estimate().state_size(), nz);
    EXPECT_EQ(r.estimate().std_size(), nz);
    EXPECT_EQ(r.estimate().y_predicted_size(), 2);
    EXPECT_EQ(r.estimate().innovation_size(), 2);
  }
  request.Clear();
  add(7.0, {0.1, 0.03}, {0.42, 0.15});
  ASSERT_TRUE(stream->Write(request));
  ASSERT_TRUE(stream->Read(&response));
  ASSERT_EQ(response.results_size(), 1);
  EXPECT_EQ(response.results(0).sequence(), 11u);
  EXPECT_EQ(response.results(0).estimate().state_size(), nz);

  // A second stream on the same session is refused while this one is open.
  {
    grpc::ClientContext ctx2;
    auto second = sessions_->Stream(&ctx2);
    ASSERT_TRUE(second->Write(open));
    second->WritesDone();
    v1::StreamResponse ignored;
    EXPECT_FALSE(second->Read(&ignored));
    EXPECT_EQ(second->Finish().error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  }
  stream->WritesDone();
  ASSERT_TRUE(stream->Finish().ok());

  // After a disconnect the session can be resumed, and remembers its state.
  grpc::ClientContext ctx3;
  auto resumed = sessions_->Stream(&ctx3);
  ASSERT_TRUE(resumed->Write(open));
  v1::StreamRequest next;
  testing::add_measurement(next, 6.5, {0.1, 0.03}, {0.4, 0.15});  // not after t = 7: refused, so the session kept its time
  ASSERT_TRUE(resumed->Write(next));
  ASSERT_TRUE(resumed->Read(&response));
  EXPECT_NE(response.results(0).error().message().find("after t = 7"), std::string::npos)
      << response.results(0).error().message();
  resumed->WritesDone();
  EXPECT_TRUE(resumed->Finish().ok());

  grpc::ClientContext close_ctx;
  v1::CloseSessionRequest close;
  close.set_id(session.id());
  v1::CloseSessionResponse closed;
  EXPECT_TRUE(sessions_->CloseSession(&close_ctx, close, &closed).ok());
  grpc::ClientContext get_ctx;
  v1::GetSessionRequest get;
  get.set_id(session.id());
  EXPECT_EQ(sessions_->GetSession(&get_ctx, get, &session).error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_F(DaemonTest, AStreamAndAJobDoNotBlockEachOther) {
  const std::string dataset = upload_two_tank();
  const v1::Job slow = submit(hensen(dataset, kEndlessPasses));
  const v1::Job running = wait_running(slow.id());
  ASSERT_EQ(running.state(), v1::JOB_STATE_RUNNING) << running.ShortDebugString();
  const v1::CreateSessionRequest create = two_tank_session();
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions_->CreateSession(&ctx, create, &session).ok());
  }
  grpc::ClientContext ctx;
  auto stream = sessions_->Stream(&ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  ASSERT_TRUE(stream->Write(open));
  for (int k = 0; k < 200; ++k) {
    v1::StreamRequest request;
    testing::add_measurement(request, k, {0.1, 0.03}, {0.4, 0.15});
    ASSERT_TRUE(stream->Write(request));
    v1::StreamResponse response;
    ASSERT_TRUE(stream->Read(&response));
    ASSERT_TRUE(response.results(0).has_estimate());
  }
  stream->WritesDone();
  ASSERT_TRUE(stream->Finish().ok());
  // All 200 round trips happened while the job (running before them, and
  // far from its last pass) was still running on the worker pool.
  const v1::Job job = get_job(slow.id());
  EXPECT_EQ(job.state(), v1::JOB_STATE_RUNNING);
  EXPECT_LT(job.progress().pass_number(), static_cast<std::uint32_t>(kEndlessPasses));
  grpc::ClientContext cancel_ctx;
  v1::CancelJobRequest cancel;
  cancel.set_id(slow.id());
  v1::Job cancelled;
  EXPECT_TRUE(jobs_->CancelJob(&cancel_ctx, cancel, &cancelled).ok());
}

// A client's deadline or cancellation ends that call, and only that call:
// the job a watch was watching runs on, a session whose stream timed out
// takes the next stream where the last one stopped, and an upload cut off
// mid-way stores nothing (what arrived could parse: it ends at a line).
TEST_F(DaemonWithMetricsTest, ClientDeadlinesAndCancellationEndOnlyTheirOwnCall) {
  const std::string dataset = upload_two_tank();
  const v1::Job slow = submit(hensen(dataset, kEndlessPasses));  // runs to the end of the test, unless touched
  const v1::Job running = wait_running(slow.id());
  ASSERT_EQ(running.state(), v1::JOB_STATE_RUNNING) << running.ShortDebugString();
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(300));
    v1::WatchJobRequest watch;
    watch.set_id(slow.id());
    auto reader = jobs_->WatchJob(&ctx, watch);
    v1::Job job;
    while (reader->Read(&job)) {
    }
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  }

  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions_->CreateSession(&ctx, two_tank_session(), &session).ok());
  }
  auto measurement_at = [](double t) {
    v1::StreamRequest request;
    testing::add_measurement(request, t, {0.1, 0.03}, {0.4, 0.15});
    return request;
  };
  auto open = [&](grpc::ClientContext* ctx) {
    auto stream = sessions_->Stream(ctx);
    v1::StreamRequest request;
    request.mutable_open()->set_session_id(session.id());
    EXPECT_TRUE(stream->Write(request));
    return stream;
  };
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(500));
    auto stream = open(&ctx);
    for (int k = 0; k < 3; ++k) {
      ASSERT_TRUE(stream->Write(measurement_at(k)));
      v1::StreamResponse response;
      ASSERT_TRUE(stream->Read(&response));
      ASSERT_TRUE(response.results(0).has_estimate());
    }
    v1::StreamResponse response;
    EXPECT_FALSE(stream->Read(&response));  // the deadline passes while the rig is silent
    EXPECT_EQ(stream->Finish().error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  }
  {
    std::vector<std::unique_ptr<grpc::ClientContext>> contexts;  // one per attempt, outliving its stream
    std::unique_ptr<grpc::ClientReaderWriter<v1::StreamRequest, v1::StreamResponse>> stream;
    v1::StreamResponse response;
    // The server notices the expired stream as soon as its deadline fires;
    // the new stream may race that by a moment, so it retries briefly.
    for (int attempt = 0;; ++attempt) {
      contexts.push_back(std::make_unique<grpc::ClientContext>());
      contexts.back()->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
      stream = open(contexts.back().get());
      ASSERT_TRUE(stream->Write(measurement_at(2)));  // not after the last accepted sample
      if (stream->Read(&response)) break;
      const grpc::Status s = stream->Finish();
      ASSERT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << s.error_message();
      ASSERT_LT(attempt, 50) << "the session stayed attached to the expired stream: " << s.error_message();
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    EXPECT_TRUE(response.results(0).has_error()) << "the filter forgot the samples of the expired stream";
    ASSERT_TRUE(stream->Write(measurement_at(3)));
    ASSERT_TRUE(stream->Read(&response));
    EXPECT_TRUE(response.results(0).has_estimate());
    stream->WritesDone();
    EXPECT_TRUE(stream->Finish().ok());
  }

  const std::string upload_method = "/riccati.v1.DatasetService/UploadDataset";
  const double uploads_before = calls_finished(upload_method);
  {
    grpc::ClientContext ctx;
    v1::DatasetInfo info;
    auto writer = datasets_->UploadDataset(&ctx, &info);
    ASSERT_TRUE(writer->Write(testing::upload_header("cut.csv", {"F1", "F2"}, {"h1", "h2"})));
    v1::UploadDatasetRequest chunk;
    const std::string csv = read_file(kData + "/two_tank.csv");
    chunk.set_chunk(csv.substr(0, csv.find('\n', 4096) + 1));  // whole lines: a parsable start
    ASSERT_TRUE(writer->Write(chunk));
    // Time for the chunk to reach the daemon before the cancellation, so
    // that a daemon which stored a cut upload would have something to
    // store. Not a synchronisation: nothing the daemon shows says it has
    // read a chunk, and the check below holds either way.
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    ctx.TryCancel();
    EXPECT_EQ(writer->Finish().error_code(), grpc::StatusCode::CANCELLED);
  }
  // The client hears CANCELLED at once; the daemon's handler may still be
  // running, and would store the cut upload (if it did) before its call
  // ends: wait until the daemon has finished the call.
  ASSERT_TRUE(testing::wait_until([&] { return calls_finished(upload_method) == uploads_before + 1; }, kWait,
                                  "the daemon has finished the cancelled upload"));
  {
    grpc::ClientContext ctx;
    v1::ListDatasetsResponse list;
    ASSERT_TRUE(datasets_->ListDatasets(&ctx, {}, &list).ok());
    ASSERT_EQ(list.datasets_size(), 1);
    EXPECT_EQ(list.datasets(0).id(), dataset);
  }

  const v1::Job job = get_job(slow.id());
  EXPECT_EQ(job.state(), v1::JOB_STATE_RUNNING) << "a watch's deadline must not touch the job";
  grpc::ClientContext cancel_ctx;
  v1::CancelJobRequest cancel;
  cancel.set_id(slow.id());
  v1::Job cancelled;
  EXPECT_TRUE(jobs_->CancelJob(&cancel_ctx, cancel, &cancelled).ok());
  expect_serving();
}

// The metrics operators read: calls by code, measurements estimated and
// refused with their step time, open sessions, jobs by state and duration;
// counted from what the test did, exactly.
TEST(DaemonMetrics, ThePrometheusEndpointCountsWhatHappened) {
  TempDir dir;
  const int port = free_port();
  ASSERT_GT(port, 0);
  DaemonProcess daemon(dir.path() / "data", {"--metrics-listen", "127.0.0.1:" + std::to_string(port)});
  daemon.start();
  auto datasets = v1::DatasetService::NewStub(daemon.channel());
  auto jobs = v1::JobService::NewStub(daemon.channel());
  auto sessions = v1::SessionService::NewStub(daemon.channel());

  v1::DatasetInfo info;
  ASSERT_TRUE(testing::upload_dataset(*datasets, "two_tank.csv", read_file(kData + "/two_tank.csv"), {"F1", "F2"},
                                      {"h1", "h2"}, &info)
                  .ok());
  v1::Job job;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(jobs->SubmitIdentification(&ctx, testing::hensen_spec(info.id(), 1), &job).ok());
  }
  for (int i = 0; i < 2; ++i) {
    grpc::ClientContext ctx;
    v1::GetJobRequest get;
    get.set_id("job-that-does-not-exist");
    v1::Job none;
    EXPECT_EQ(jobs->GetJob(&ctx, get, &none).error_code(), grpc::StatusCode::NOT_FOUND);
  }
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions->CreateSession(&ctx, testing::two_tank_session(), &session).ok());
  }
  {
    grpc::ClientContext ctx;
    auto stream = sessions->Stream(&ctx);
    v1::StreamRequest open;
    open.mutable_open()->set_session_id(session.id());
    ASSERT_TRUE(stream->Write(open));
    v1::StreamRequest request;
    for (int k = 0; k < 7; ++k) {
      testing::add_measurement(request, k == 5 ? 1.0 : k, {0.1, 0.03}, {0.4, 0.15});  // the sixth goes back: refused
    }
    ASSERT_TRUE(stream->Write(request));
    v1::StreamResponse response;
    ASSERT_TRUE(stream->Read(&response));
    ASSERT_EQ(response.results_size(), 7);
    stream->WritesDone();
    ASSERT_TRUE(stream->Finish().ok());
  }
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    v1::WatchJobRequest watch;
    watch.set_id(job.id());
    auto reader = jobs->WatchJob(&ctx, watch);
    v1::Job state;
    while (reader->Read(&state)) {
    }
    ASSERT_TRUE(reader->Finish().ok());
    ASSERT_EQ(state.state(), v1::JOB_STATE_SUCCEEDED);
  }

  // The session's snapshots: one at its creation (before the client heard
  // of it), one when its stream ended (by the writer thread: waited for).
  std::string page;
  EXPECT_TRUE(testing::wait_until(
      [&] {
        page = http_get(port, "/metrics");
        return sample_value(page, R"(riccati_session_snapshots_total{outcome="stored"})") >= 2;
      },
      kWait, "the session's two snapshots are stored", std::chrono::milliseconds(50)));
  ASSERT_FALSE(page.empty()) << "no metrics on port " << port;
  EXPECT_EQ(sample_value(page, R"(riccati_session_snapshots_total{outcome="stored"})"), 2) << page;
  EXPECT_EQ(sample_value(page, R"(riccati_session_snapshots_total{outcome="failed"})"), 0);
  EXPECT_EQ(sample_value(page, "riccati_sessions_resumed_total"), 0);
  EXPECT_EQ(sample_value(page, R"(riccati_measurements_total{outcome="estimated"})"), 6) << page;
  EXPECT_EQ(sample_value(page, R"(riccati_measurements_total{outcome="refused"})"), 1);
  EXPECT_EQ(sample_value(page, "riccati_measurement_seconds_count"), 7);
  EXPECT_GT(sample_value(page, "riccati_measurement_seconds_sum"), 0);
  EXPECT_EQ(sample_value(page, "riccati_sessions_open"), 1);
  EXPECT_EQ(sample_value(page, R"(riccati_jobs{state="queued"})"), 0);
  EXPECT_EQ(sample_value(page, R"(riccati_jobs{state="running"})"), 0);
  EXPECT_EQ(sample_value(page, R"(riccati_jobs_ended_total{kind="identification",state="succeeded"})"), 1);
  EXPECT_EQ(sample_value(page, R"(riccati_job_seconds_count{kind="identification"})"), 1);
  EXPECT_EQ(sample_value(page, R"(riccati_rpc_total{code="NOT_FOUND",method="/riccati.v1.JobService/GetJob"})"), 2);
  EXPECT_EQ(sample_value(page, R"(riccati_rpc_total{code="OK",method="/riccati.v1.SessionService/Stream"})"), 1);
  EXPECT_EQ(sample_value(page, R"(riccati_rpc_total{code="OK",method="/riccati.v1.DatasetService/UploadDataset"})"),
            1);
  EXPECT_EQ(daemon.stop(), 0) << daemon.exit_report();

  // Restarted, the daemon resumes the session from its snapshot when asked.
  daemon.start();
  sessions = v1::SessionService::NewStub(daemon.channel());
  {
    grpc::ClientContext ctx;
    v1::GetSessionRequest get;
    get.set_id(session.id());
    v1::SessionInfo resumed;
    ASSERT_TRUE(sessions->GetSession(&ctx, get, &resumed).ok());
    EXPECT_EQ(resumed.measurements(), 6u);
  }
  page = http_get(port, "/metrics");
  EXPECT_EQ(sample_value(page, "riccati_sessions_resumed_total"), 1) << page;
  EXPECT_EQ(daemon.stop(), 0) << daemon.exit_report();
}

// Jobs and results used to grow without end (3,066 small jobs made a 943 MB
// database in 75 s): DeleteJob, a quota on results, retention by count.
TEST(JobRetention, DeletedAndOldJobsGiveTheirRoomBackAndTheStoreSizeIsMeasured) {
  TempDir dir;
  const int port = free_port();
  ASSERT_GT(port, 0);
  const std::string metrics = "127.0.0.1:" + std::to_string(port);
  auto run_to_end = [](v1::JobService::Stub& jobs, const std::string& dataset, int passes) {
    grpc::ClientContext ctx;
    v1::Job job;
    const grpc::Status s = jobs.SubmitIdentification(&ctx, testing::hensen_spec(dataset, passes), &job);
    if (!s.ok()) return s;
    grpc::ClientContext watch_ctx;
    v1::WatchJobRequest watch;
    watch.set_id(job.id());
    auto reader = jobs.WatchJob(&watch_ctx, watch);
    v1::Job last;
    while (reader->Read(&last)) {
    }
    EXPECT_EQ(last.state(), v1::JOB_STATE_SUCCEEDED) << last.ShortDebugString();
    return grpc::Status(grpc::StatusCode::OK, job.id());  // the id, in the message
  };
  auto get = [](v1::JobService::Stub& jobs, const std::string& id) {
    grpc::ClientContext ctx;
    v1::GetJobRequest request;
    request.set_id(id);
    v1::Job job;
    return jobs.GetJob(&ctx, request, &job).error_code();
  };
  auto remove = [](v1::JobService::Stub& jobs, const std::string& id) {
    grpc::ClientContext ctx;
    v1::DeleteJobRequest request;
    request.set_id(id);
    v1::DeleteJobResponse response;
    return jobs.DeleteJob(&ctx, request, &response);
  };
  auto results_bytes = [&] {
    return sample_value(http_get(port, "/metrics"), R"(riccati_store_bytes{part="results"})");
  };

  // Retention by count: the two newest ended jobs stay.
  std::string dataset;
  double one_result = 0;
  {
    DaemonProcess daemon(dir.path() / "data", {"--metrics-listen", metrics, "--max-tenant-jobs-kept", "2"});
    daemon.start();
    auto datasets = v1::DatasetService::NewStub(daemon.channel());
    auto jobs = v1::JobService::NewStub(daemon.channel());
    v1::DatasetInfo info;
    ASSERT_TRUE(testing::upload_dataset(*datasets, "two_tank.csv", read_file(kData + "/two_tank.csv"), {"F1", "F2"},
                                        {"h1", "h2"}, &info)
                    .ok());
    dataset = info.id();
    EXPECT_EQ(sample_value(http_get(port, "/metrics"), R"(riccati_store_bytes{part="results"})"), 0);
    std::vector<std::string> ended;
    for (int i = 0; i < 3; ++i) {
      const grpc::Status s = run_to_end(*jobs, dataset, 1);
      ASSERT_TRUE(s.ok()) << s.error_message();
      ended.push_back(s.error_message());
      if (i == 0) one_result = results_bytes();
    }
    EXPECT_GT(one_result, 1000);
    // The oldest, past max_tenant_jobs_kept (deleted once the third's end is stored: soon after its watch hears it).
    EXPECT_TRUE(testing::wait_until([&] { return get(*jobs, ended[0]) == grpc::StatusCode::NOT_FOUND; }, kWait,
                                    "the oldest job deleted"));
    EXPECT_EQ(get(*jobs, ended[1]), grpc::StatusCode::OK);
    EXPECT_EQ(get(*jobs, ended[2]), grpc::StatusCode::OK);
    EXPECT_EQ(results_bytes(), 2 * one_result);
    const std::string page = http_get(port, "/metrics");
    EXPECT_GT(sample_value(page, R"(riccati_store_bytes{part="database"})"),
              sample_value(page, R"(riccati_store_bytes{part="datasets"})"));
    EXPECT_EQ(sample_value(page, R"(riccati_store_bytes{part="datasets"})"), info.size_bytes());

    // DeleteJob: an ended job goes with its result; a running one must be cancelled first.
    ASSERT_TRUE(remove(*jobs, ended[1]).ok());
    EXPECT_EQ(get(*jobs, ended[1]), grpc::StatusCode::NOT_FOUND);
    EXPECT_EQ(results_bytes(), one_result);
    EXPECT_EQ(remove(*jobs, ended[1]).error_code(), grpc::StatusCode::NOT_FOUND);
    grpc::ClientContext ctx;
    v1::Job running;
    ASSERT_TRUE(jobs->SubmitIdentification(&ctx, testing::hensen_spec(dataset, 2000), &running).ok());
    const grpc::Status refused = remove(*jobs, running.id());
    EXPECT_EQ(refused.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << refused.error_message();
    EXPECT_NE(refused.error_message().find("cancel it"), std::string::npos) << refused.error_message();
    grpc::ClientContext cancel_ctx;
    v1::CancelJobRequest cancel;
    cancel.set_id(running.id());
    ASSERT_TRUE(jobs->CancelJob(&cancel_ctx, cancel, &running).ok());
    EXPECT_TRUE(testing::wait_until([&] { return remove(*jobs, running.id()).ok(); }, kWait,
                                    "the cancelled job deleted once it has ended"));
    ASSERT_TRUE(remove(*jobs, ended[2]).ok());
    datasets.reset();
    jobs.reset();
  }

  // The quota on results: the stored ones and the new one's estimate. With
  // room for one and a half results, a second is refused until the first
  // is deleted.
  DaemonProcess daemon(dir.path() / "data",
                       {"--metrics-listen", metrics, "--max-tenant-result-bytes",
                        std::to_string(static_cast<std::int64_t>(1.5 * one_result))});
  daemon.start();
  auto jobs = v1::JobService::NewStub(daemon.channel());
  const grpc::Status first = run_to_end(*jobs, dataset, 1);
  ASSERT_TRUE(first.ok()) << first.error_message();
  grpc::ClientContext ctx;
  v1::Job job;
  const grpc::Status over = jobs->SubmitIdentification(&ctx, testing::hensen_spec(dataset, 1), &job);
  EXPECT_EQ(over.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << over.error_message();
  EXPECT_NE(over.error_message().find("max_tenant_result_bytes"), std::string::npos) << over.error_message();
  EXPECT_NE(over.error_message().find("DeleteJob"), std::string::npos) << over.error_message();
  ASSERT_TRUE(remove(*jobs, first.error_message()).ok());
  EXPECT_TRUE(run_to_end(*jobs, dataset, 1).ok());
  jobs.reset();
}

TEST(DaemonConfig, IdleSessionsExpireAndBadConfigFilesAreRefused) {
  TempDir dir;
  DaemonProcess daemon(dir.path() / "data", {"--session-idle-timeout", "1"});
  daemon.start();
  auto sessions = v1::SessionService::NewStub(daemon.channel());
  v1::CreateSessionRequest create;
  create.set_model("two_tank");
  create.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(1e-3);
  create.mutable_filter()->mutable_r()->mutable_diagonal()->add_values(1e-3);
  create.mutable_initial_state()->set_first_measurement(true);
  for (int i = 0; i < 6; ++i) create.mutable_p0()->mutable_diagonal()->add_values(1.0);
  v1::SessionInfo session;
  const auto created = std::chrono::steady_clock::now();  // before the daemon's clock starts for it
  {
    grpc::ClientContext ctx;
    ASSERT_TRUE(sessions->CreateSession(&ctx, create, &session).ok());
  }
  auto get_session = [&] {
    grpc::ClientContext ctx;
    v1::GetSessionRequest get;
    get.set_id(session.id());
    v1::SessionInfo info;
    return sessions->GetSession(&ctx, get, &info);
  };
  const grpc::Status found = get_session();
  ASSERT_TRUE(found.ok()) << "the session is not there to expire: " << found.error_message();
  // Idle for 1 s it expires (looking at it is no activity); the reaper
  // looks every 250 ms. Not before 1 s, and not much after.
  ASSERT_TRUE(testing::wait_until([&] { return get_session().error_code() == grpc::StatusCode::NOT_FOUND; }, kWait,
                                  "the idle session has expired", std::chrono::milliseconds(50)));
  EXPECT_GE(std::chrono::steady_clock::now() - created, std::chrono::seconds(1)) << "it expired before 1 s idle";

  // A config file with a typo stops the daemon at start, naming the key.
  const auto config = dir.path() / "riccatid.yaml";
  std::ofstream(config) << "listen: 127.0.0.1:0\nworkerz: 4\n";
  const std::string command = std::string(RICCATI_DAEMON_BIN) + " --config " + config.string() + " 2>" +
                              (dir.path() / "err").string();
  EXPECT_EQ(WEXITSTATUS(std::system(command.c_str())), 2);
  EXPECT_NE(read_file((dir.path() / "err").string()).find("unknown key \"workerz\""), std::string::npos);
}

// The daemon on PostgreSQL (--database), in a schema of the test's own.
class PostgresDaemonTest : public DaemonTest {
 protected:
  void SetUp() override {
    RICCATI_SKIP_WITHOUT_POSTGRES();
    schema_ = std::make_unique<testing::PostgresSchema>();
    daemon_ = std::make_unique<DaemonProcess>(dir_.path() / "data",
                                              std::vector<std::string>{"--database", schema_->url()});
    daemon_->start();
    connect();
  }
  // The daemon goes before its schema is dropped.
  void TearDown() override { daemon_.reset(); }

  std::unique_ptr<testing::PostgresSchema> schema_;
};

TEST_F(PostgresDaemonTest, AnIdentificationAndItsDataSurviveARestart) {
  const std::string dataset = upload_two_tank();
  const v1::Job job = submit(hensen(dataset, 2));
  const v1::Job done = wait_for(job.id());
  ASSERT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error().message();
  const v1::JobResult before = result_of(job.id());
  ASSERT_TRUE(before.has_identification());
  ASSERT_EQ(before.identification().passes_size(), 2);

  EXPECT_EQ(daemon_->stop(), 0) << daemon_->exit_report();
  daemon_->start();
  connect();
  {
    grpc::ClientContext ctx;
    v1::GetDatasetRequest get;
    get.set_id(dataset);
    v1::DatasetInfo info;
    ASSERT_TRUE(datasets_->GetDataset(&ctx, get, &info).ok());
    EXPECT_EQ(info.samples(), 2000u);
  }
  {
    grpc::ClientContext ctx;
    v1::GetJobRequest get;
    get.set_id(job.id());
    v1::Job again;
    ASSERT_TRUE(jobs_->GetJob(&ctx, get, &again).ok());
    EXPECT_EQ(again.state(), v1::JOB_STATE_SUCCEEDED);
  }
  const v1::JobResult after = result_of(job.id());
  EXPECT_TRUE(google::protobuf::util::MessageDifferencer::Equals(before, after));
  // It was all in PostgreSQL: no SQLite database, the job's row in the schema.
  EXPECT_FALSE(std::filesystem::exists(daemon_->data_dir() / "riccati.db"));
  EXPECT_EQ(schema_->exec("SELECT state FROM jobs WHERE id = '" + job.id() + "'")[0][0].as<std::string>(),
            "succeeded");
}

TEST(DaemonConfig, AnUnknownDatabaseIsRefusedWithoutEchoingItsPassword) {
  TempDir dir;
  const std::string command = std::string(RICCATI_DAEMON_BIN) + " --listen 127.0.0.1:0 --data-dir " +
                              (dir.path() / "data").string() + " --database mysql://u:s3cret@h/db 2>" +
                              (dir.path() / "err").string();
  EXPECT_EQ(WEXITSTATUS(std::system(command.c_str())), 1);
  const std::string err = read_file((dir.path() / "err").string());
  EXPECT_NE(err.find("database \"mysql://u:***@h/db\": expected sqlite (the default) or a postgresql:// URL"),
            std::string::npos)
      << err;
  EXPECT_EQ(err.find("s3cret"), std::string::npos) << err;
}

}  // namespace
}  // namespace riccati
