// Work a request starts is bounded, and stops within a bounded time once
// nobody waits for it (issue 30, items 1 and 7), against a real riccatid:
//
// - a one-state stiff text model, x' = -a x + sin t with a = 1e7, sampled
//   1000 s apart under an adaptive explicit integrator: one sample is ~1e9
//   internal steps. Simulate past its deadline, a session stream that
//   CloseSession ends, a job that CancelJob ends, SIGTERM: each stops within
//   about a second, not after the sample; and the steps count against
//   max_simulation_steps.
// - a mechanical text model with a dense n x n mass matrix, whose Jacobian
//   check costs ~n^5: CreateModel (validate_only, as the workbench's editor
//   sends after each key) refuses it naming max_model_check_operations,
//   promptly, while the daemon keeps answering others.
#include <fstream>
#include <future>
#include <grpcpp/generic/generic_stub.h>
#include <sstream>

#include "service/daemon_fixture.hpp"

namespace riccati {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using testing::DaemonProcess;
using testing::kWait;
using testing::TempDir;
using testing::wait_until;

constexpr char kStiffModel[] = R"(model: stiff
description: x' = -a x + sin(t) + u, a = 1e7 (a time constant of 0.1 us)
states:
  x: {}
inputs:
  u: {}
parameters:
  a: {value: 1e7, min: 0}
der:
  x: -a * x + sin(t) + u
outputs:
  y: x
)";

// The adaptive explicit integrator, allowed up to 1e9 internal steps a
// sample: stability alone holds it to steps of ~3e-7 s.
v1::IntegratorSettings explicit_adaptive() {
  v1::IntegratorSettings s;
  s.set_kind(v1::INTEGRATOR_KIND_ARKODE_ERK);
  s.set_max_steps(1000000000);
  return s;
}

// The daemon's CPU time so far (user + system), from /proc.
std::chrono::milliseconds cpu_time(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::istringstream fields(stat.substr(stat.rfind(')') + 2));
  std::string field;
  long utime = 0, stime = 0;
  for (int i = 3; i <= 15 && fields >> field; ++i) {
    if (i == 14) utime = std::stol(field);
    if (i == 15) stime = std::stol(field);
  }
  return std::chrono::milliseconds((utime + stime) * 1000 / sysconf(_SC_CLK_TCK));
}

class BoundedWork : public ::testing::Test {
 protected:
  void start(std::vector<std::string> args) {
    daemon_ = std::make_unique<DaemonProcess>(dir_.path() / "data", std::move(args));
    daemon_->start();
    models_ = v1::ModelService::NewStub(daemon_->channel());
    datasets_ = v1::DatasetService::NewStub(daemon_->channel());
    jobs_ = v1::JobService::NewStub(daemon_->channel());
    sessions_ = v1::SessionService::NewStub(daemon_->channel());
  }

  void add_stiff_model() {
    grpc::ClientContext ctx;
    v1::CreateModelRequest request;
    request.set_source(kStiffModel);
    v1::ModelInfo info;
    const grpc::Status s = models_->CreateModel(&ctx, request, &info);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }

  // Waits until the daemon has used `amount` more CPU than at the call: it
  // is computing.
  ::testing::AssertionResult busy_for(std::chrono::milliseconds amount) {
    const auto before = cpu_time(daemon_->pid());
    return wait_until([&] { return cpu_time(daemon_->pid()) - before >= amount; }, kWait,
                      "riccatid computes (CPU time rises)");
  }

  // Waits until the daemon uses (almost) no CPU for a 500 ms window, and
  // returns how long after the call that came: its work has stopped.
  std::chrono::milliseconds quiet_after() {
    const auto from = Clock::now();
    for (int i = 0; i < 60; ++i) {
      const auto before = cpu_time(daemon_->pid());
      std::this_thread::sleep_for(500ms);  // the window measured, not a synchronisation
      if (cpu_time(daemon_->pid()) - before < 100ms) {
        return std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - from - 500ms);
      }
    }
    return 30000ms;
  }

  // A short call another client makes meanwhile: answered, and how fast.
  std::chrono::milliseconds list_models_latency() {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + 10s);
    v1::ListModelsResponse list;
    const auto t0 = Clock::now();
    const grpc::Status s = models_->ListModels(&ctx, {}, &list);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - t0);
  }

  grpc::Status health_check() { return testing::health_check(daemon_->channel(), nullptr, 5s); }

  v1::SimulateRequest stiff_simulation(int samples) {
    v1::SimulateRequest request;
    request.set_model("stiff");
    for (int k = 0; k < samples; ++k) request.add_t(1000.0 * k);
    request.mutable_u()->set_rows(1);
    request.mutable_u()->set_cols(samples);
    for (int k = 0; k < samples; ++k) request.mutable_u()->add_values(0.0);
    request.add_x0(0.0);
    *request.mutable_integrator() = explicit_adaptive();
    return request;
  }

  TempDir dir_;
  std::unique_ptr<DaemonProcess> daemon_;
  std::unique_ptr<v1::ModelService::Stub> models_;
  std::unique_ptr<v1::DatasetService::Stub> datasets_;
  std::unique_ptr<v1::JobService::Stub> jobs_;
  std::unique_ptr<v1::SessionService::Stub> sessions_;
};

// A limit far above what the tests reach: only the deadline or a cancel stops them.
const std::vector<std::string> kNoStepLimit = {"--max-simulation-steps", "100000000000"};

TEST_F(BoundedWork, SimulateStopsComputingAtItsDeadlineWithinASample) {
  start(kNoStepLimit);
  add_stiff_model();
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + 3s);
  v1::SimulateResponse response;
  const grpc::Status s = models_->Simulate(&ctx, stiff_simulation(3), &response);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << s.error_message();
  // riccatid stops computing within about a second of the deadline (it
  // computed on for minutes, the whole sample).
  EXPECT_LT(quiet_after(), 1500ms);
  EXPECT_LT(list_models_latency(), 1000ms);
}

TEST_F(BoundedWork, AnAdaptiveIntegratorsInternalStepsCountAgainstMaxSimulationSteps) {
  start({"--max-simulation-steps", "1000000"});
  add_stiff_model();
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + 60s);
  v1::SimulateResponse response;
  const auto t0 = Clock::now();
  const grpc::Status s = models_->Simulate(&ctx, stiff_simulation(3), &response);
  ASSERT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << s.error_message();
  EXPECT_NE(s.error_message().find("limit max_simulation_steps = 1000000 reached"), std::string::npos)
      << s.error_message();
  EXPECT_NE(s.error_message().find("--max-simulation-steps"), std::string::npos) << s.error_message();
  EXPECT_LT(Clock::now() - t0, 20s) << "a million steps of a one-state model";
}

TEST_F(BoundedWork, CloseSessionEndsAMeasurementBeingIntegratedAndAnswersPromptly) {
  start(kNoStepLimit);
  add_stiff_model();
  v1::CreateSessionRequest create;
  create.set_model("stiff");
  create.mutable_filter()->set_kind(v1::FILTER_KIND_EKF);
  *create.mutable_filter()->mutable_integrator() = explicit_adaptive();
  create.mutable_filter()->mutable_r()->set_scalar(1e-3);
  create.mutable_initial_state()->add_x0(0.0);
  create.add_theta0(1e7);
  create.mutable_p0()->mutable_diagonal()->add_values(1.0);
  create.mutable_p0()->mutable_diagonal()->add_values(0.0);
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    const grpc::Status s = sessions_->CreateSession(&ctx, create, &session);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  grpc::ClientContext stream_ctx;
  auto rw = sessions_->Stream(&stream_ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  ASSERT_TRUE(rw->Write(open));
  v1::StreamRequest batch;
  testing::add_measurement(batch, 0.0, {0.0}, {0.0});
  testing::add_measurement(batch, 1000.0, {0.0}, {0.0});  // a sample of ~1e9 steps
  ASSERT_TRUE(rw->Write(batch));
  ASSERT_TRUE(busy_for(500ms));

  grpc::ClientContext close_ctx;
  close_ctx.set_deadline(std::chrono::system_clock::now() + 10s);
  v1::CloseSessionRequest close;
  close.set_id(session.id());
  v1::CloseSessionResponse closed;
  const auto t0 = Clock::now();
  const grpc::Status c = sessions_->CloseSession(&close_ctx, close, &closed);
  EXPECT_TRUE(c.ok()) << c.error_message();
  EXPECT_LT(Clock::now() - t0, 2s) << "CloseSession waited for the measurement";
  // The stream ends, its measurement not taken; riccatid stops computing.
  v1::StreamResponse response;
  while (rw->Read(&response)) {
  }
  const grpc::Status end = rw->Finish();
  EXPECT_FALSE(end.ok());
  EXPECT_LT(quiet_after(), 1500ms);
}

// A sample past the per-sample bound is refused on its own, as a bad
// measurement: the session has not diverged and takes the next one.
TEST_F(BoundedWork, ASampleOverItsStepBudgetIsRefusedAndTheSessionGoesOn) {
  start({"--max-simulation-steps", "100000"});
  add_stiff_model();
  v1::CreateSessionRequest create;
  create.set_model("stiff");
  *create.mutable_filter()->mutable_integrator() = explicit_adaptive();
  create.mutable_filter()->mutable_r()->set_scalar(1e-3);
  create.mutable_initial_state()->add_x0(0.0);
  create.add_theta0(1e7);
  create.mutable_p0()->mutable_diagonal()->add_values(1.0);
  create.mutable_p0()->mutable_diagonal()->add_values(0.0);
  v1::SessionInfo session;
  {
    grpc::ClientContext ctx;
    const grpc::Status s = sessions_->CreateSession(&ctx, create, &session);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + 60s);
  auto rw = sessions_->Stream(&ctx);
  v1::StreamRequest open;
  open.mutable_open()->set_session_id(session.id());
  ASSERT_TRUE(rw->Write(open));
  v1::StreamRequest batch;
  testing::add_measurement(batch, 0.0, {0.0}, {0.0});
  testing::add_measurement(batch, 1000.0, {0.0}, {0.0});  // ~1e9 steps: past 100,000
  testing::add_measurement(batch, 1e-6, {0.0}, {0.0});    // a few steps after t = 0
  ASSERT_TRUE(rw->Write(batch));
  v1::StreamResponse response;
  ASSERT_TRUE(rw->Read(&response));
  ASSERT_EQ(response.results_size(), 3);
  EXPECT_TRUE(response.results(0).has_estimate());
  ASSERT_TRUE(response.results(1).has_error());
  EXPECT_EQ(response.results(1).error().code(), static_cast<int>(grpc::StatusCode::RESOURCE_EXHAUSTED));
  EXPECT_NE(response.results(1).error().message().find("limit max_simulation_steps = 100000 reached"),
            std::string::npos)
      << response.results(1).error().message();
  EXPECT_TRUE(response.results(2).has_estimate()) << response.results(2).error().message();
  rw->WritesDone();
  const grpc::Status end = rw->Finish();
  EXPECT_TRUE(end.ok()) << end.error_message();
}

TEST_F(BoundedWork, CancelJobEndsAJobWithinASampleAndSigtermExitsPromptly) {
  start(kNoStepLimit);
  add_stiff_model();
  v1::DatasetInfo dataset;
  {
    grpc::ClientContext ctx;
    const grpc::Status s = testing::upload_dataset(*datasets_, &ctx, "stiff.csv",
                                                   "t,u,y\n0,0,0\n1000,0,0\n2000,0,0\n", {"u"}, {"y"}, &dataset);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  v1::IdentificationSpec spec;
  spec.set_model("stiff");
  spec.set_dataset_id(dataset.id());
  spec.mutable_filter()->set_kind(v1::FILTER_KIND_EKF);
  *spec.mutable_filter()->mutable_integrator() = explicit_adaptive();
  spec.mutable_filter()->mutable_r()->set_scalar(1e-3);
  spec.mutable_initial_state()->add_x0(0.0);
  spec.add_theta0(1e7);
  spec.mutable_p0()->mutable_diagonal()->add_values(1.0);
  spec.mutable_p0()->mutable_diagonal()->add_values(1.0);
  spec.set_passes(1);
  auto submit = [&] {
    grpc::ClientContext ctx;
    v1::Job job;
    const grpc::Status s = jobs_->SubmitIdentification(&ctx, spec, &job);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return job.id();
  };
  auto state_of = [&](const std::string& id) {
    grpc::ClientContext ctx;
    v1::GetJobRequest request;
    request.set_id(id);
    v1::Job job;
    EXPECT_TRUE(jobs_->GetJob(&ctx, request, &job).ok());
    return job.state();
  };

  const std::string cancelled = submit();
  ASSERT_TRUE(wait_until([&] { return state_of(cancelled) == v1::JOB_STATE_RUNNING; }, kWait, "the job runs"));
  ASSERT_TRUE(busy_for(500ms));
  {
    grpc::ClientContext ctx;
    v1::CancelJobRequest request;
    request.set_id(cancelled);
    v1::Job job;
    ASSERT_TRUE(jobs_->CancelJob(&ctx, request, &job).ok());
  }
  const auto t0 = Clock::now();
  EXPECT_TRUE(wait_until([&] { return state_of(cancelled) == v1::JOB_STATE_CANCELLED; }, 5s,
                         "the job is cancelled"));
  EXPECT_LT(Clock::now() - t0, 2s) << "CancelJob waited for the sample";
  EXPECT_LT(quiet_after(), 1500ms);

  // Another such job and a Simulate without a deadline, both in a sample of
  // ~1e9 steps: SIGTERM stops them within the grace period (5 s).
  const std::string running = submit();
  ASSERT_TRUE(wait_until([&] { return state_of(running) == v1::JOB_STATE_RUNNING; }, kWait, "the job runs"));
  std::promise<grpc::Status> simulated;
  grpc::ClientContext simulate_ctx;
  const v1::SimulateRequest simulation = stiff_simulation(3);
  v1::SimulateResponse response;
  models_->async()->Simulate(&simulate_ctx, &simulation, &response, [&](grpc::Status s) { simulated.set_value(s); });
  ASSERT_TRUE(busy_for(1000ms));
  EXPECT_TRUE(health_check().ok()) << "health answered while both compute";
  const auto stopping = Clock::now();
  const int status = daemon_->stop();
  EXPECT_EQ(status, 0) << daemon_->exit_report();
  EXPECT_LT(Clock::now() - stopping, 3s) << "SIGTERM: both stop within a sample, not at the grace period's end (5 s)";
  simulate_ctx.TryCancel();
  const grpc::Status s = simulated.get_future().get();  // the call's callback has run before its context goes
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE) << s.error_message();
}

// The checks cost nothing a cheap simulation would notice: 20,000 samples
// of the two-tank plugin, one RK4 step each (IsCancelled() waits on gRPC's
// completion queue, up to 1.5 ms a call: asked every sample or every 16
// evaluations, it would take most of the time).
TEST_F(BoundedWork, ACheapLongSimulationIsNotSlowedByItsChecks) {
  start({});
  v1::SimulateRequest r;
  r.set_model("two_tank");
  constexpr int kSamples = 20000;
  for (double x : {0.4, 0.15}) r.add_x0(x);
  for (int k = 0; k < kSamples; ++k) r.add_t(0.1 * k);
  r.mutable_u()->set_rows(2);
  r.mutable_u()->set_cols(kSamples);
  for (int k = 0; k < 2 * kSamples; ++k) r.mutable_u()->add_values(0.01);
  r.mutable_integrator()->set_substeps(1);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + 60s);
  v1::SimulateResponse response;
  const auto t0 = Clock::now();
  const grpc::Status s = models_->Simulate(&ctx, r, &response);
  const auto took = Clock::now() - t0;
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_LT(took, testing::kSanitized ? 60s : 2s);
  RecordProperty("ms", std::to_string(std::chrono::duration_cast<std::chrono::milliseconds>(took).count()));
}

// A mechanical model whose n x n mass matrix is dense: M = I + s s'
// (positive definite), h = k s, one output. Its Jacobian check costs ~n^5.
std::string dense_mass_model(int n) {
  std::ostringstream y;
  y << "model: dense" << n << "\nstates:\n";
  for (int i = 0; i < n; ++i) y << "  s" << i << ": {}\n";
  for (int i = 0; i < n; ++i) y << "  v" << i << ": {}\n";
  y << "parameters:\n  k: {value: 1}\nmechanical:\n  M:\n";
  for (int i = 0; i < n; ++i) {
    y << "    - [";
    for (int j = 0; j < n; ++j) {
      y << (j > 0 ? ", " : "");
      if (i == j) {
        y << "1+s" << i << "*s" << i;
      } else {
        y << "s" << i << "*s" << j;
      }
    }
    y << "]\n";
  }
  y << "  h:\n";
  for (int i = 0; i < n; ++i) y << "    - k*s" << i << "\n";
  y << "outputs:\n  y: s0\n";
  return y.str();
}

TEST_F(BoundedWork, AModelTooCostlyToCheckIsRefusedPromptlyNamingTheLimit) {
  start({});
  auto validate = [&](const std::string& source, v1::ModelInfo* info) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + 60s);
    v1::CreateModelRequest request;
    request.set_source(source);
    request.set_validate_only(true);
    return models_->CreateModel(&ctx, request, info);
  };
  // A small one is checked as before.
  {
    v1::ModelInfo info;
    const grpc::Status s = validate(dense_mass_model(8), &info);
    ASSERT_TRUE(s.ok()) << s.error_message();
    EXPECT_TRUE(info.jacobian_check().checked());
    EXPECT_TRUE(info.jacobian_check().agrees()) << info.jacobian_check().detail();
  }
  for (const int n : {64, 96, 128}) {
    const std::string source = dense_mass_model(n);
    ASSERT_LT(source.size(), 256u * 1024) << "inside the format's limits";
    // Another client meanwhile (the health check and a call).
    std::atomic<bool> done{false};
    std::chrono::milliseconds worst{0};
    int answered = 0;
    std::thread other([&] {
      while (!done) {
        EXPECT_TRUE(health_check().ok());
        worst = std::max(worst, list_models_latency());
        ++answered;
      }
    });
    v1::ModelInfo info;
    const auto t0 = Clock::now();
    const grpc::Status s = validate(source, &info);
    const auto took = Clock::now() - t0;
    done = true;
    other.join();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << "n = " << n << ": " << s.error_message();
    EXPECT_NE(s.error_message().find("limit max_model_check_operations = 1000000000 reached"), std::string::npos)
        << s.error_message();
    EXPECT_NE(s.error_message().find("--max-model-check-operations"), std::string::npos) << s.error_message();
    EXPECT_LT(took, testing::kSanitized ? 120s : 10s) << "n = " << n;
    EXPECT_GT(answered, 0);
    EXPECT_LT(worst, 2000ms) << "n = " << n << ": another call waited";
    RecordProperty("refused_ms_n" + std::to_string(n),
                   std::to_string(std::chrono::duration_cast<std::chrono::milliseconds>(took).count()));
  }
}

// Item 15's numbers: a matrix whose size overflows 64 signed bits is
// described with its true count (it was a signed overflow, undefined
// behaviour, printed as -2446744073709551616), and a covariance whose square
// overflows is refused naming the field and the entry (Q = 1e300 ran, with
// standard deviations of 2e134 and no divergence), for every filter kind.
TEST_F(BoundedWork, AbsurdSizesAndMagnitudesAreRefusedNamingThem) {
  start({});
  add_stiff_model();
  auto create = [&](const v1::CreateSessionRequest& request) {
    grpc::ClientContext ctx;
    v1::SessionInfo session;
    return sessions_->CreateSession(&ctx, request, &session);
  };
  v1::CreateSessionRequest base;
  base.set_model("stiff");
  base.mutable_filter()->mutable_r()->set_scalar(1e-3);
  base.mutable_initial_state()->add_x0(0.0);
  base.add_theta0(1e7);
  base.mutable_p0()->mutable_diagonal()->add_values(1.0);
  base.mutable_p0()->mutable_diagonal()->add_values(0.0);
  ASSERT_TRUE(create(base).ok());

  v1::CreateSessionRequest huge = base;
  v1::Matrix* full = huge.mutable_p0()->mutable_full();
  full->set_rows(4000000000u);
  full->set_cols(4000000000u);
  full->add_values(1.0);
  grpc::Status s = create(huge);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("a 4000000000 x 4000000000 matrix needs 16000000000000000000 values, got 1"),
            std::string::npos)
      << s.error_message();

  for (const v1::FilterKind kind : {v1::FILTER_KIND_EKF, v1::FILTER_KIND_UKF}) {
    v1::CreateSessionRequest absurd = base;
    absurd.mutable_filter()->set_kind(kind);
    absurd.mutable_filter()->mutable_q()->set_scalar(1e300);
    s = create(absurd);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << kind;
    EXPECT_NE(s.error_message().find("process noise Q[0, 0] = 1e+300 is too large"), std::string::npos)
        << s.error_message();
    absurd = base;
    absurd.mutable_filter()->set_kind(kind);
    absurd.mutable_filter()->mutable_r()->set_scalar(1e200);
    s = create(absurd);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << kind;
    EXPECT_NE(s.error_message().find("measurement noise R[0, 0] = 1e+200 is too large"), std::string::npos)
        << s.error_message();
    absurd = base;
    absurd.mutable_filter()->set_kind(kind);
    absurd.mutable_p0()->mutable_diagonal()->set_values(0, 1e300);
    s = create(absurd);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << kind;
    EXPECT_NE(s.error_message().find("P0[0, 0] = 1e+300 is too large"), std::string::npos) << s.error_message();
  }
}

}  // namespace
}  // namespace riccati
