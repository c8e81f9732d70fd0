// Integrators against closed-form solutions, used the way filters use them:
// one integrator object advanced over many successive sample intervals.
#include "engine/integrators/integrator.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <thread>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

namespace riccati {
namespace {

constexpr double kRtol = 1e-8;
constexpr double kAtol = 1e-10;
constexpr int kSubsteps = 10;

// y_i' = -k_i y_i, so y_i(t) = y_i(t0) exp(-k_i (t - t0)).
class Decay final : public OdeRhs {
 public:
  explicit Decay(std::vector<double> rates) : rates_(std::move(rates)) {}
  Status eval(double /*t*/, const double* y, double* ydot) override {
    for (std::size_t i = 0; i < rates_.size(); ++i) ydot[i] = -rates_[i] * y[i];
    ++evaluations_;
    return Status::ok();
  }
  long evaluations() const { return evaluations_; }

 private:
  std::vector<double> rates_;
  long evaluations_ = 0;
};

// x'' = -omega^2 x as (x, v); from (1, 0): x = cos(omega t), v = -omega sin(omega t).
class Oscillator final : public OdeRhs {
 public:
  explicit Oscillator(double omega) : omega_(omega) {}
  Status eval(double /*t*/, const double* y, double* ydot) override {
    ydot[0] = y[1];
    ydot[1] = -omega_ * omega_ * y[0];
    return Status::ok();
  }

 private:
  double omega_;
};

// y' = -lambda (y - cos t): for large lambda the solution relaxes within
// 1/lambda onto a slow curve near cos t, and explicit methods are held to
// steps below ~3/lambda by stability alone.
class StiffRelaxation final : public OdeRhs {
 public:
  explicit StiffRelaxation(double lambda) : lambda_(lambda) {}
  Status eval(double t, const double* y, double* ydot) override {
    ydot[0] = -lambda_ * (y[0] - std::cos(t));
    ++evaluations_;
    return Status::ok();
  }
  // Closed form from y(0) = y0.
  double exact(double t, double y0) const {
    const double l2 = lambda_ * lambda_;
    const double slow = (l2 * std::cos(t) + lambda_ * std::sin(t)) / (l2 + 1.0);
    return slow + (y0 - l2 / (l2 + 1.0)) * std::exp(-lambda_ * t);
  }
  long evaluations() const { return evaluations_; }

 private:
  double lambda_;
  long evaluations_ = 0;
};

// y' = -y until t_fail, then the given failure, as a model whose f turns NaN
// (kFailedPrecondition) or whose plugin breaks (kInternal) would report it.
class FailsAfter final : public OdeRhs {
 public:
  FailsAfter(double t_fail, Status failure) : t_fail_(t_fail), failure_(std::move(failure)) {}
  Status eval(double t, const double* y, double* ydot) override {
    if (t >= t_fail_) {
      ++failed_evaluations_;
      return failure_;
    }
    ydot[0] = -y[0];
    return Status::ok();
  }
  long failed_evaluations() const { return failed_evaluations_; }

 private:
  double t_fail_;
  Status failure_;
  long failed_evaluations_ = 0;
};

// y' = -y, but the first evaluation past t_glitch reports a NaN; every later
// one is fine. An adaptive solver should retry with a smaller step and succeed.
class GlitchesOnce final : public OdeRhs {
 public:
  explicit GlitchesOnce(double t_glitch) : t_glitch_(t_glitch) {}
  Status eval(double t, const double* y, double* ydot) override {
    if (!glitched_ && t > t_glitch_) {
      glitched_ = true;
      return failed_precondition("model glitch: f returned NaN at t = " + std::to_string(t));
    }
    ydot[0] = -y[0];
    return Status::ok();
  }
  bool glitched() const { return glitched_; }

 private:
  double t_glitch_;
  bool glitched_ = false;
};

// Writes a NaN derivative after t_nan but still reports success: an RHS that
// forgot its own check.
class SilentNan final : public OdeRhs {
 public:
  explicit SilentNan(double t_nan) : t_nan_(t_nan) {}
  Status eval(double t, const double* y, double* ydot) override {
    ydot[0] = t >= t_nan_ ? std::numeric_limits<double>::quiet_NaN() : -y[0];
    return Status::ok();
  }

 private:
  double t_nan_;
};

int order_of(IntegratorKind kind) {
  switch (kind) {
    case IntegratorKind::kRk4: return 4;
    case IntegratorKind::kRk3: return 3;
    case IntegratorKind::kDop853: return 8;
    default: return 0;
  }
}

IntegratorSettings settings_for(IntegratorKind kind) {
  IntegratorSettings settings;
  settings.kind = kind;
  settings.substeps = kSubsteps;
  settings.rtol = kRtol;
  settings.atol = kAtol;
  return settings;
}

// How far `kind` may end from the exact solution of a linear mode with
// eigenvalue magnitude `rate` and size `magnitude`, after `intervals` sample
// intervals of length dt.
//
// Fixed step: explicit RK of order p multiplies y by R(z) = sum_{j<=p} z^j/j!
// per step (z = lambda h), whose relative error against exp(z) is
// |z|^(p+1)/(p+1)! to leading order. Over t/h steps these add up to
// t |lambda| |lambda h|^p / (p+1)!; the factor 2 covers higher-order terms
// (|z| <= 0.2 here). For the 8th-order method that is far below rounding,
// which adds up to a few eps per step: 4 eps per step is allowed on top.
//
// Adaptive: each step's local error is held near rtol |y| + atol. Every
// interval restarts the solver (order 1, fresh step size) and adds a few such
// tolerances of global error (up to ~10 for BDF on the undamped oscillator,
// where nothing damps earlier errors away, so they add up across intervals).
// 20 per interval leaves margin and is still a small multiple of the request.
double error_bound(IntegratorKind kind, double rate, double dt, int intervals, double magnitude) {
  if (is_fixed_step(kind)) {
    const int order = order_of(kind);
    const double factorial = std::tgamma(order + 2.0);  // (p + 1)!
    const double h = dt / kSubsteps;
    const double rounding = 4.0 * std::numeric_limits<double>::epsilon() * intervals * kSubsteps;
    return (2.0 * intervals * dt * rate * std::pow(rate * h, order) / factorial + rounding) * magnitude;
  }
  return 20.0 * intervals * (kRtol * magnitude + kAtol);
}

class IntegratorTest : public testing::TestWithParam<IntegratorKind> {
 protected:
  std::unique_ptr<Integrator> make() {
    auto integrator = make_integrator(settings_for(GetParam()));
    EXPECT_TRUE(integrator.is_ok()) << integrator.status().to_string();
    return std::move(integrator).value();
  }
};

TEST_P(IntegratorTest, ExponentialDecayOverSuccessiveIntervals) {
  auto integrator = make();
  const double k = 0.7;
  Decay rhs({k});
  const double dt = 0.25;
  std::vector<double> y = {2.0};
  for (int sample = 0; sample < 20; ++sample) {
    const double t0 = sample * dt;
    const double t1 = t0 + dt;
    ASSERT_TRUE(integrator->integrate(rhs, t0, t1, y).is_ok()) << "sample " << sample;
    EXPECT_NEAR(y[0], 2.0 * std::exp(-k * t1), error_bound(GetParam(), k, dt, sample + 1, 2.0)) << "t = " << t1;
  }
}

TEST_P(IntegratorTest, HarmonicOscillatorOverSuccessiveIntervals) {
  auto integrator = make();
  const double omega = 2.0;
  Oscillator rhs(omega);
  const double dt = 0.1;
  std::vector<double> y = {1.0, 0.0};
  for (int sample = 0; sample < 50; ++sample) {
    const double t0 = sample * dt;
    const double t1 = t0 + dt;
    ASSERT_TRUE(integrator->integrate(rhs, t0, t1, y).is_ok()) << "sample " << sample;
    // In the variable x + i v / omega the flow is a rotation with
    // eigenvalue i omega and amplitude 1: the decay bound applies with
    // rate omega, and v's error is omega times x's.
    const double bound = error_bound(GetParam(), omega, dt, sample + 1, 1.0);
    EXPECT_NEAR(y[0], std::cos(omega * t1), bound) << "t = " << t1;
    EXPECT_NEAR(y[1], -omega * std::sin(omega * t1), omega * bound) << "t = " << t1;
  }
}

TEST_P(IntegratorTest, ModelFailureStatusIsPropagatedWithItsMessage) {
  auto integrator = make();
  FailsAfter rhs(0.5, failed_precondition("model two_tank: f returned NaN in x[0]"));
  std::vector<double> y = {1.0};
  const Status status = integrator->integrate(rhs, 0.0, 1.0, y);
  ASSERT_FALSE(status.is_ok());
  EXPECT_EQ(status.code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(status.message().find("model two_tank: f returned NaN in x[0]"), std::string::npos)
      << status.message();

  // The failure leaves the integrator usable: the next interval starts afresh.
  Decay decay({1.0});
  y = {1.0};
  ASSERT_TRUE(integrator->integrate(decay, 1.0, 2.0, y).is_ok());
  EXPECT_NEAR(y[0], std::exp(-1.0), error_bound(GetParam(), 1.0, 1.0, 1, 1.0));
}

TEST_P(IntegratorTest, InternalErrorFromModelIsPropagated) {
  auto integrator = make();
  FailsAfter rhs(0.5, internal_error("plugin pendulum: evaluation crashed"));
  std::vector<double> y = {1.0};
  const Status status = integrator->integrate(rhs, 0.0, 1.0, y);
  ASSERT_FALSE(status.is_ok());
  EXPECT_EQ(status.code(), StatusCode::kInternal);
  EXPECT_NE(status.message().find("plugin pendulum: evaluation crashed"), std::string::npos) << status.message();
  // Unlike a NaN, an internal error is not retried: the model is not probed again.
  EXPECT_EQ(rhs.failed_evaluations(), 1);
}

TEST_P(IntegratorTest, NanDerivativeIsNeverReportedAsSuccess) {
  auto integrator = make();
  SilentNan rhs(0.5);
  std::vector<double> y = {1.0};
  const Status status = integrator->integrate(rhs, 0.0, 1.0, y);
  EXPECT_FALSE(status.is_ok());
  EXPECT_EQ(status.code(), StatusCode::kFailedPrecondition) << status.to_string();
}

TEST_P(IntegratorTest, ChangingSystemSizeReallocates) {
  auto integrator = make();
  Decay one({1.0});
  Oscillator two(1.0);
  Decay three({0.5, 1.0, 2.0});
  // Every system here has rates <= 2 and magnitudes <= 3 over one unit interval.
  const double bound = error_bound(GetParam(), 2.0, 1.0, 1, 3.0);

  std::vector<double> y1 = {1.0};
  ASSERT_TRUE(integrator->integrate(one, 0.0, 1.0, y1).is_ok());
  EXPECT_NEAR(y1[0], std::exp(-1.0), bound);

  std::vector<double> y2 = {1.0, 0.0};
  ASSERT_TRUE(integrator->integrate(two, 0.0, 1.0, y2).is_ok());
  EXPECT_NEAR(y2[0], std::cos(1.0), bound);
  EXPECT_NEAR(y2[1], -std::sin(1.0), bound);

  std::vector<double> y3 = {1.0, 1.0, 1.0};
  ASSERT_TRUE(integrator->integrate(three, 0.0, 1.0, y3).is_ok());
  EXPECT_NEAR(y3[0], std::exp(-0.5), bound);
  EXPECT_NEAR(y3[1], std::exp(-1.0), bound);
  EXPECT_NEAR(y3[2], std::exp(-2.0), bound);

  y1 = {3.0};
  ASSERT_TRUE(integrator->integrate(one, 1.0, 2.0, y1).is_ok());
  EXPECT_NEAR(y1[0], 3.0 * std::exp(-1.0), bound);
}

TEST_P(IntegratorTest, RejectsIntervalsThatDoNotIncrease) {
  auto integrator = make();
  Decay rhs({1.0});
  std::vector<double> y = {1.0};
  EXPECT_EQ(integrator->integrate(rhs, 1.0, 1.0, y).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(integrator->integrate(rhs, 1.0, 0.5, y).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(integrator->integrate(rhs, 0.0, std::numeric_limits<double>::quiet_NaN(), y).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(rhs.evaluations(), 0);
}

std::string kind_test_name(const testing::TestParamInfo<IntegratorKind>& info) {
  std::string name = integrator_kind_name(info.param);
  std::replace(name.begin(), name.end(), '-', '_');
  return name;
}

INSTANTIATE_TEST_SUITE_P(AllKinds, IntegratorTest,
                         testing::Values(IntegratorKind::kRk4, IntegratorKind::kRk3, IntegratorKind::kDop853,
                                         IntegratorKind::kCvodeBdf, IntegratorKind::kCvodeAdams,
                                         IntegratorKind::kArkodeErk),
                         kind_test_name);

// The adaptive (SUNDIALS) kinds only.
class AdaptiveIntegratorTest : public IntegratorTest {};

TEST_P(AdaptiveIntegratorTest, RecoversFromASingleNanByRetryingWithASmallerStep) {
  if (GetParam() == IntegratorKind::kArkodeErk) {
    // SUNDIALS 6.4's ERKStep treats a recoverable RHS failure as fatal
    // (ARK_UNREC_RHSFUNC_ERR); the failure is still reported in the model's
    // words (ModelFailureStatusIsPropagatedWithItsMessage).
    GTEST_SKIP() << "ERKStep does not retry after a recoverable RHS failure";
  }
  auto integrator = make();
  GlitchesOnce rhs(0.3);
  std::vector<double> y = {1.0};
  const Status status = integrator->integrate(rhs, 0.0, 1.0, y);
  ASSERT_TRUE(status.is_ok()) << status.to_string();
  EXPECT_TRUE(rhs.glitched());
  EXPECT_NEAR(y[0], std::exp(-1.0), error_bound(GetParam(), 1.0, 1.0, 1, 1.0));
}

TEST_P(AdaptiveIntegratorTest, RejectsAnEmptyState) {
  auto integrator = make();
  Decay rhs({});
  std::vector<double> y;
  EXPECT_EQ(integrator->integrate(rhs, 0.0, 1.0, y).code(), StatusCode::kInvalidArgument);
}

TEST_P(AdaptiveIntegratorTest, ReportsTooMuchWorkWithTheFlagName) {
  IntegratorSettings settings = settings_for(GetParam());
  settings.max_steps = 5;  // far too few for 20 oscillations at rtol 1e-8
  auto integrator = make_integrator(settings);
  ASSERT_TRUE(integrator.is_ok());
  Oscillator rhs(2.0 * std::numbers::pi);
  std::vector<double> y = {1.0, 0.0};
  const Status status = (*integrator)->integrate(rhs, 0.0, 20.0, y);
  ASSERT_FALSE(status.is_ok());
  EXPECT_EQ(status.code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(status.message().find("TOO_MUCH_WORK"), std::string::npos) << status.message();
  EXPECT_NE(status.message().find(integrator_kind_name(GetParam())), std::string::npos) << status.message();
}

TEST_P(AdaptiveIntegratorTest, InvalidSettingsAreReportedByIntegrate) {
  // make_cvode_integrator / make_arkode_integrator skip make_integrator's
  // validation; the integrator must still refuse to run with them.
  IntegratorSettings settings = settings_for(GetParam());
  settings.rtol = -1.0;
  auto integrator = GetParam() == IntegratorKind::kArkodeErk ? make_arkode_integrator(settings)
                                                             : make_cvode_integrator(settings);
  Decay rhs({1.0});
  std::vector<double> y = {1.0};
  EXPECT_EQ(integrator->integrate(rhs, 0.0, 1.0, y).code(), StatusCode::kInvalidArgument);
}

INSTANTIATE_TEST_SUITE_P(SundialsKinds, AdaptiveIntegratorTest,
                         testing::Values(IntegratorKind::kCvodeBdf, IntegratorKind::kCvodeAdams,
                                         IntegratorKind::kArkodeErk),
                         kind_test_name);

// Global error of an order-p method is C h^p: halving h divides it by 2^p.
// At h = 0.1 and 0.05 on y' = -y the next term changes the ratio by under
// 3%, so 10% around 2^p separates the orders clearly.
TEST(FixedStepConvergenceTest, HalvingTheStepDividesTheErrorByTwoToTheOrder) {
  for (IntegratorKind kind : {IntegratorKind::kRk4, IntegratorKind::kRk3, IntegratorKind::kDop853}) {
    SCOPED_TRACE(integrator_kind_name(kind));
    // The 8th-order method at h = 0.1 is at rounding already: h = 0.5 and 0.25
    // (errors ~1e-8 and ~4e-11), where the next term moves the ratio by ~5 %.
    const int coarse_substeps = kind == IntegratorKind::kDop853 ? 2 : 10;
    auto error_with_substeps = [kind](int substeps) {
      IntegratorSettings settings = settings_for(kind);
      settings.substeps = substeps;
      auto integrator = make_integrator(settings);
      EXPECT_TRUE(integrator.is_ok());
      Decay rhs({1.0});
      std::vector<double> y = {1.0};
      EXPECT_TRUE((*integrator)->integrate(rhs, 0.0, 1.0, y).is_ok());
      return std::abs(y[0] - std::exp(-1.0));
    };
    const double coarse = error_with_substeps(coarse_substeps);
    const double fine = error_with_substeps(2 * coarse_substeps);
    const double expected_ratio = std::pow(2.0, order_of(kind));
    EXPECT_NEAR(coarse / fine, expected_ratio, 0.1 * expected_ratio);
  }
}

// y' = -1000 (y - cos t) over ten one-second samples: BDF follows the slow
// solution with steps far beyond the explicit stability limit (~3e-3 s).
TEST(StiffIntegrationTest, CvodeBdfSolvesStiffRelaxationAccuratelyAndCheaply) {
  auto bdf = make_integrator(settings_for(IntegratorKind::kCvodeBdf));
  ASSERT_TRUE(bdf.is_ok());
  StiffRelaxation rhs(1000.0);
  const double y0 = 0.0;
  std::vector<double> y = {y0};
  for (int sample = 0; sample < 10; ++sample) {
    const double t1 = sample + 1.0;
    ASSERT_TRUE((*bdf)->integrate(rhs, sample, t1, y).is_ok()) << "sample " << sample;
    EXPECT_NEAR(y[0], rhs.exact(t1, y0), error_bound(IntegratorKind::kCvodeBdf, 1.0, 1.0, sample + 1, 1.0))
        << "t = " << t1;
  }

  // The same problem through adaptive explicit RK, which stability alone
  // holds to thousands of steps (measured: ~900 evaluations for BDF, ~100000
  // for ERK).
  auto erk = make_integrator(settings_for(IntegratorKind::kArkodeErk));
  ASSERT_TRUE(erk.is_ok());
  StiffRelaxation explicit_rhs(1000.0);
  std::vector<double> y_explicit = {y0};
  for (int sample = 0; sample < 10; ++sample) {
    ASSERT_TRUE((*erk)->integrate(explicit_rhs, sample, sample + 1.0, y_explicit).is_ok());
  }
  EXPECT_LT(rhs.evaluations() * 10, explicit_rhs.evaluations())
      << "BDF: " << rhs.evaluations() << " evaluations, ERK: " << explicit_rhs.evaluations();
}

// The Interrupt a caller installs (InterruptScope): a budget of steps and a
// cancellation polled within an interval, for every kind.

// x'' = -omega^2 x whose every evaluation also spins a while (about a
// microsecond): an interval of many steps takes seconds, as a stiff text
// model's sample did.
class BusyOscillator final : public OdeRhs {
 public:
  Status eval(double /*t*/, const double* y, double* ydot) override {
    volatile double sink = 0.0;
    for (int i = 0; i < 300; ++i) sink = sink + 1e-9 * i;
    ydot[0] = y[1];
    ydot[1] = -39.47841760435743 * y[0];  // (2 pi)^2
    evaluations.fetch_add(1, std::memory_order_relaxed);
    return Status::ok();
  }
  std::atomic<long> evaluations{0};
};

TEST_P(IntegratorTest, AStepBudgetStopsEveryKindWithinIt) {
  auto integrator = make();
  Oscillator rhs(2.0 * std::numbers::pi);
  Interrupt interrupt;
  interrupt.max_steps_total = 1000;
  std::int64_t reported = -1;
  interrupt.exhausted = [&](std::int64_t steps) {
    reported = steps;
    return Status(StatusCode::kResourceExhausted, "budget of 1000 steps: " + std::to_string(steps));
  };
  InterruptScope under(interrupt);
  std::vector<double> y = {1.0, 0.0};
  Status status;
  int intervals = 0;
  // An oscillation an interval: every kind needs far more than 1000 steps
  // for 1000 intervals (the fixed ones 10 an interval).
  for (; intervals < 1000 && status.is_ok(); ++intervals) {
    status = integrator->integrate(rhs, intervals, intervals + 1.0, y);
  }
  ASSERT_EQ(status.code(), StatusCode::kResourceExhausted) << status.to_string();
  EXPECT_LE(interrupt.steps, 1000);
  EXPECT_GT(interrupt.steps, 900) << "stopped near the budget, not long before it";
  EXPECT_GE(reported, interrupt.steps);
  EXPECT_NE(status.message().find("budget of 1000 steps"), std::string::npos) << status.message();
}

TEST_P(IntegratorTest, APerIntervalBudgetBoundsOneInterval) {
  IntegratorSettings settings = settings_for(GetParam());
  settings.substeps = 1000;
  auto integrator = make_integrator(settings);
  ASSERT_TRUE(integrator.is_ok());
  Oscillator rhs(2.0 * std::numbers::pi);
  Interrupt interrupt;
  interrupt.max_steps_per_interval = 100;
  InterruptScope under(interrupt);
  std::vector<double> y = {1.0, 0.0};
  const Status status = (*integrator)->integrate(rhs, 0.0, 1000.0, y);
  ASSERT_EQ(status.code(), StatusCode::kResourceExhausted) << status.to_string();
  EXPECT_LE(interrupt.steps, 100);
  // The next interval is bounded on its own, not by what the first took.
  std::vector<double> y2 = {1.0, 0.0};
  settings.substeps = 10;
  auto small = make_integrator(settings);
  ASSERT_TRUE(small.is_ok());
  EXPECT_TRUE((*small)->integrate(rhs, 0.0, 0.01, y2).is_ok());
}

TEST_P(IntegratorTest, ACancelFromAnotherThreadStopsItWithinAnInterval) {
  IntegratorSettings settings = settings_for(GetParam());
  settings.substeps = 1000000;   // fixed kinds: 4e6 to 1.2e7 evaluations, seconds
  settings.max_steps = 1000000000;  // adaptive kinds: 1e6 oscillations need ~1e7 steps
  auto integrator = make_integrator(settings);
  ASSERT_TRUE(integrator.is_ok());
  BusyOscillator rhs;
  std::atomic<bool> cancel{false};
  Interrupt interrupt;
  interrupt.poll = [&]() -> Status {
    return cancel.load() ? cancelled("cancelled by the test") : Status::ok();
  };
  using Clock = std::chrono::steady_clock;
  std::atomic<Clock::rep> cancelled_at{0};
  std::thread canceller([&] {
    // Once the integration is well under way (no sleep as synchronisation).
    const auto give_up = Clock::now() + std::chrono::seconds(20);
    while (rhs.evaluations.load() < 20000 && Clock::now() < give_up) std::this_thread::yield();
    cancelled_at = Clock::now().time_since_epoch().count();
    cancel = true;
  });
  Status status;
  {
    InterruptScope under(interrupt);
    std::vector<double> y = {1.0, 0.0};
    status = (*integrator)->integrate(rhs, 0.0, 1.0e6, y);
  }
  const auto returned = Clock::now();
  canceller.join();
  ASSERT_EQ(status.code(), StatusCode::kCancelled) << status.to_string();
  EXPECT_NE(status.message().find("cancelled by the test"), std::string::npos) << status.message();
  const auto late = returned - Clock::time_point(Clock::duration(cancelled_at.load()));
  EXPECT_LT(late, std::chrono::seconds(1)) << "returned "
                                            << std::chrono::duration_cast<std::chrono::milliseconds>(late).count()
                                            << " ms after the cancel";
}

TEST_P(IntegratorTest, ADeadlineFromThePollIsReportedAsSuch) {
  auto integrator = make();
  Oscillator rhs(2.0 * std::numbers::pi);
  Interrupt interrupt;
  interrupt.poll = [] { return deadline_exceeded("past the deadline"); };
  InterruptScope under(interrupt);
  std::vector<double> y = {1.0, 0.0};
  const Status status = integrator->integrate(rhs, 0.0, 1.0, y);
  EXPECT_EQ(status.code(), StatusCode::kDeadlineExceeded) << status.to_string();
  EXPECT_TRUE(is_interruption(status));
}

TEST(InterruptScopeTest, ScopesNestAndEndWithTheirBlock) {
  EXPECT_EQ(current_interrupt(), nullptr);
  Interrupt outer, inner;
  {
    InterruptScope a(outer);
    EXPECT_EQ(current_interrupt(), &outer);
    {
      InterruptScope b(inner);
      EXPECT_EQ(current_interrupt(), &inner);
    }
    EXPECT_EQ(current_interrupt(), &outer);
    std::thread([] { EXPECT_EQ(current_interrupt(), nullptr) << "per thread"; }).join();
  }
  EXPECT_EQ(current_interrupt(), nullptr);
}

}  // namespace
}  // namespace riccati
