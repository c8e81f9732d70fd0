// Engine benchmarks (Google Benchmark), on one core:
//
//   build/bin/engine_bench --benchmark_filter=TwoTank
//
// Filter step on the two-tank model (6 augmented states, RK4 with 10
// substeps) measured over Hensen's 10-pass identification (20,000 steps),
// through the real plugin path: the reported per_step is the whole
// identification's time divided by its steps (prediction + update + the
// bookkeeping of a pass). TwoTankOutputError (at the end) identifies the same
// model by output error; bench/oe_versus_scipy.sh runs it beside scipy.
#include <benchmark/benchmark.h>

#include <Eigen/Cholesky>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>

#include "engine/estimation/binding.hpp"
#include "engine/estimation/identification.hpp"
#include "engine/estimation/max_likelihood.hpp"
#include "engine/estimation/output_error.hpp"
#include "engine/estimation/sensitivity.hpp"
#include "engine/estimation/smoother.hpp"
#include "engine/models/plugin_loader.hpp"
#include "hand_written_two_tank_ekf.hpp"
#include "support/two_tank_hensen.hpp"

namespace riccati {
namespace {

struct TwoTankFixture {
  ModelRegistry registry;
  ModelPtr model;
  Dataset data;

  TwoTankFixture() {
    registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
    model = registry.find("two_tank");
    data = read_csv_file(RICCATI_TEST_DATA_DIR "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}})
               .value();
  }

  IdentificationSettings hensen(FilterKind kind) const { return testing::two_tank_hensen(kind); }
};

void TwoTankIdentification(benchmark::State& state, FilterKind kind) {
  static TwoTankFixture fixture;
  const IdentificationSettings settings = fixture.hensen(kind);
  for (auto _ : state) {
    auto r = identify(fixture.model, fixture.data, settings);
    if (!r.is_ok()) {
      state.SkipWithError(r.status().to_string().c_str());
      break;
    }
    benchmark::DoNotOptimize(r.value().theta.data());
  }
  const double steps = static_cast<double>(settings.passes) * fixture.data.size();
  // Printed as a time per filter step.
  state.counters["per_step"] =
      benchmark::Counter(steps, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

// The filter alone: predict + update over one pass, no identification
// bookkeeping; with `smoothing`, keeping what a smoother needs of each
// prediction (FilterSettings::smoothing).
void TwoTankFilterStep(benchmark::State& state, FilterKind kind, bool smoothing) {
  static TwoTankFixture fixture;
  IdentificationSettings s = fixture.hensen(kind);
  s.filter.smoothing = smoothing;
  auto filter = make_filter(fixture.model, s.filter).value();
  Eigen::VectorXd z0(6);
  z0 << fixture.data.y.col(0), s.initial.theta0;
  const Dataset& d = fixture.data;
  Eigen::Index k = 0;
  (void)filter->reset(d.t[0], z0, s.initial.P0);
  for (auto _ : state) {
    if (++k == d.size()) {
      k = 1;
      (void)filter->reset(d.t[0], z0, s.initial.P0);
    }
    Status st = filter->predict(d.t[k], d.u.col(k - 1).data(), d.u.col(k).data());
    if (st.is_ok()) st = filter->update(d.y.col(k).data(), d.u.col(k).data());
    if (!st.is_ok()) {
      state.SkipWithError(st.to_string().c_str());
      break;
    }
  }
}

// The fixed-interval smoother over the record (2000 samples), one pass of
// Hensen's settings: the filter forward, keeping what the backward pass
// needs, then the backward pass; per_sample is the whole run's time divided
// by the samples.
void TwoTankSmoother(benchmark::State& state, FilterKind kind) {
  static TwoTankFixture fixture;
  const IdentificationSettings hensen = fixture.hensen(kind);
  SmootherSettings settings;
  settings.filter = hensen.filter;
  settings.initial = hensen.initial;
  for (auto _ : state) {
    auto r = smooth(fixture.model, fixture.data, settings);
    if (!r.is_ok()) {
      state.SkipWithError(r.status().to_string().c_str());
      break;
    }
    benchmark::DoNotOptimize(r.value().z_smoothed.data());
  }
  state.counters["per_sample"] = benchmark::Counter(static_cast<double>(fixture.data.size()),
                                                    benchmark::Counter::kIsIterationInvariantRate |
                                                        benchmark::Counter::kInvert);
}

BENCHMARK_CAPTURE(TwoTankIdentification, ekf, FilterKind::kEkf)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(TwoTankIdentification, ukf, FilterKind::kUkf)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(TwoTankFilterStep, ekf, FilterKind::kEkf, false)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(TwoTankFilterStep, ukf, FilterKind::kUkf, false)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(TwoTankFilterStep, ekf_smoothing, FilterKind::kEkf, true)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(TwoTankFilterStep, ukf_smoothing, FilterKind::kUkf, true)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(TwoTankSmoother, ekf, FilterKind::kEkf)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(TwoTankSmoother, ukf, FilterKind::kUkf)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace riccati


namespace riccati {
namespace {
// One model evaluation through the plugin path: values, and values with the
// Jacobian by dual numbers.
void TwoTankModelCall(benchmark::State& state, bool jacobian) {
  static TwoTankFixture fixture;
  const double x[2] = {0.4, 0.15}, theta[4] = {10, 5, 0.0791, 0.1342}, u[2] = {0.1, 0.03};
  double out[2], jac[12];
  for (auto _ : state) {
    Status s = jacobian ? fixture.model->f_jacobian(0.0, u, x, theta, out, jac)
                        : fixture.model->f(0.0, u, 1, 1, x, theta, out);
    benchmark::DoNotOptimize(s);
    benchmark::DoNotOptimize(out);
  }
}
BENCHMARK_CAPTURE(TwoTankModelCall, f, false);
BENCHMARK_CAPTURE(TwoTankModelCall, f_jacobian, true);
}  // namespace
}  // namespace riccati


namespace riccati {
namespace {

using bench::HandWrittenTwoTankEkf;

void HandWrittenTwoTankEkfStep(benchmark::State& state, bool structured) {
  static TwoTankFixture fixture;
  const Dataset& d = fixture.data;
  HandWrittenTwoTankEkf ekf;
  auto reset = [&] {
    ekf.z << d.y.col(0), 20, 20, 1, 1;
    ekf.P = (HandWrittenTwoTankEkf::Vec6() << 0, 0, 10, 10, 10, 10).finished().asDiagonal();
  };
  reset();
  Eigen::Index k = 0;
  for (auto _ : state) {
    if (++k == d.size()) {
      k = 1;
      reset();
    }
    if (structured) {
      ekf.predict_structured(d.t[k] - d.t[k - 1], d.u.col(k - 1).data());
    } else {
      ekf.predict_full(d.t[k] - d.t[k - 1], d.u.col(k - 1).data());
    }
    ekf.update(d.y.col(k).data());
    benchmark::DoNotOptimize(ekf.z.data());
  }
}
BENCHMARK_CAPTURE(HandWrittenTwoTankEkfStep, structured, true)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(HandWrittenTwoTankEkfStep, full_covariance, false)->Unit(benchmark::kMicrosecond);

// A hand-written CD-UKF for the two-tank model only, the engine's algorithm
// (Julier's weights, kappa = 3 - n; the 13 sigma points integrated through
// RK4 with 10 substeps, theta constant; fresh points for the update; P - K C^T)
// written as one would by hand for speed: fixed sizes, the sigma points as
// a structure of arrays (one array per variable, one lane per point) so that
// every loop over the points is a loop the compiler vectorises; no plugin, no
// checks. The engine's UKF is measured against it (TwoTankFilterStep/ukf).
struct HandWrittenTwoTankUkf {
  static constexpr int n = 6, npts = 2 * n + 1;
  using Mat6 = Eigen::Matrix<double, 6, 6>;
  using Vec6 = Eigen::Matrix<double, 6, 1>;
  Vec6 z;
  Mat6 P;
  Eigen::Matrix2d R = Eigen::Vector2d(1e-3, 1e-3).asDiagonal();
  double spread = std::sqrt(3.0), wm[npts], wc[npts];
  alignas(64) double X[n][npts];  // X[i][p]: variable i of point p

  HandWrittenTwoTankUkf() {
    // kappa = 3 - n: lambda = -3, n + lambda = 3.
    for (int p = 0; p < npts; ++p) wm[p] = wc[p] = 0.5 / 3.0;
    wm[0] = wc[0] = -3.0 / 3.0;
  }

  // S S^T = P by Cholesky with diagonal pivoting, stopping at the numerical
  // rank (zero variances are normal at the start), as the engine does.
  static void psd_sqrt(const Mat6& P, Mat6& S) {
    Mat6 w = P;
    int perm[n] = {0, 1, 2, 3, 4, 5};
    S.setZero();
    double max_diag = w.diagonal().cwiseAbs().maxCoeff();
    const double negligible = n * std::numeric_limits<double>::epsilon() * max_diag;
    for (int k = 0; k < n; ++k) {
      int pivot = k;
      for (int j = k + 1; j < n; ++j) {
        if (w(j, j) > w(pivot, pivot)) pivot = j;
      }
      if (w(pivot, pivot) <= negligible) break;
      if (pivot != k) {
        w.row(k).swap(w.row(pivot));
        w.col(k).swap(w.col(pivot));
        std::swap(perm[k], perm[pivot]);
      }
      const double lkk = std::sqrt(w(k, k));
      for (int i = k; i < n; ++i) w(i, k) /= lkk;
      for (int j = k + 1; j < n; ++j) {
        for (int i = k + 1; i < n; ++i) w(i, j) -= w(i, k) * w(j, k);
      }
      for (int i = k; i < n; ++i) S(perm[i], k) = w(i, k);
    }
  }

  void draw() {
    Mat6 S;
    psd_sqrt(P, S);
    for (int i = 0; i < n; ++i) {
      X[i][0] = z[i];
      for (int j = 0; j < n; ++j) {
        X[i][1 + j] = z[i] + spread * S(i, j);
        X[i][1 + n + j] = z[i] - spread * S(i, j);
      }
    }
  }

  // f at every point: dh[p] from h1[p], h2[p] and the points' parameters.
  void f(const double* h1, const double* h2, const double* u, double* d1, double* d2) const {
    const double *A1 = X[2], *A2 = X[3], *k1 = X[4], *k2 = X[5];
    for (int p = 0; p < npts; ++p) {
      const double q1 = k1[p] * (h1[p] > 0.0 ? std::sqrt(h1[p]) : 0.0);
      const double q2 = k2[p] * (h2[p] > 0.0 ? std::sqrt(h2[p]) : 0.0);
      d1[p] = (u[0] - q1) / A1[p];
      d2[p] = (u[1] + q1 - q2) / A2[p];
    }
  }

  void mean_and_covariance() {
    for (int i = 0; i < n; ++i) {
      double m = 0.0;
      for (int p = 0; p < npts; ++p) m += wm[p] * X[i][p];
      z[i] = m;
    }
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j <= i; ++j) {
        double c = 0.0;
        for (int p = 0; p < npts; ++p) c += wc[p] * (X[i][p] - z[i]) * (X[j][p] - z[j]);
        P(i, j) = P(j, i) = c;
      }
    }
  }

  void predict(double dt, const double* u) {
    draw();
    const int substeps = 10;
    const double h = dt / substeps;
    alignas(64) double k1a[npts], k1b[npts], k2a[npts], k2b[npts], k3a[npts], k3b[npts], k4a[npts], k4b[npts];
    alignas(64) double ta[npts], tb[npts];
    double* h1 = X[0];
    double* h2 = X[1];
    for (int s = 0; s < substeps; ++s) {
      f(h1, h2, u, k1a, k1b);
      for (int p = 0; p < npts; ++p) ta[p] = h1[p] + 0.5 * h * k1a[p], tb[p] = h2[p] + 0.5 * h * k1b[p];
      f(ta, tb, u, k2a, k2b);
      for (int p = 0; p < npts; ++p) ta[p] = h1[p] + 0.5 * h * k2a[p], tb[p] = h2[p] + 0.5 * h * k2b[p];
      f(ta, tb, u, k3a, k3b);
      for (int p = 0; p < npts; ++p) ta[p] = h1[p] + h * k3a[p], tb[p] = h2[p] + h * k3b[p];
      f(ta, tb, u, k4a, k4b);
      for (int p = 0; p < npts; ++p) {
        h1[p] += h / 6.0 * (k1a[p] + 2.0 * (k2a[p] + k3a[p]) + k4a[p]);
        h2[p] += h / 6.0 * (k1b[p] + 2.0 * (k2b[p] + k3b[p]) + k4b[p]);
      }
    }
    mean_and_covariance();
  }

  void update(const double* y) {
    draw();
    // g = [h1, h2]: the outputs are the first two variables of each point.
    double yhat[2] = {0.0, 0.0};
    for (int o = 0; o < 2; ++o) {
      for (int p = 0; p < npts; ++p) yhat[o] += wm[p] * X[o][p];
    }
    Eigen::Matrix2d S = R;
    Eigen::Matrix<double, 6, 2> C;
    for (int i = 0; i < n; ++i) {
      for (int o = 0; o < 2; ++o) {
        double c = 0.0;
        for (int p = 0; p < npts; ++p) c += wc[p] * (X[i][p] - z[i]) * (X[o][p] - yhat[o]);
        C(i, o) = c;
        if (i < 2) S(i, o) += c;
      }
    }
    const Eigen::Matrix<double, 6, 2> K = Eigen::LLT<Eigen::Matrix2d>(S).solve(C.transpose()).transpose();
    z += K * Eigen::Vector2d(y[0] - yhat[0], y[1] - yhat[1]);
    const Mat6 Pnew = P - K * C.transpose();
    P = 0.5 * (Pnew + Pnew.transpose());
  }
};

void HandWrittenTwoTankUkfStep(benchmark::State& state) {
  static TwoTankFixture fixture;
  const Dataset& d = fixture.data;
  HandWrittenTwoTankUkf ukf;
  auto reset = [&] {
    ukf.z << d.y.col(0), 20, 20, 1, 1;
    ukf.P = (HandWrittenTwoTankUkf::Vec6() << 0, 0, 10, 10, 10, 10).finished().asDiagonal();
  };
  reset();
  Eigen::Index k = 0;
  for (auto _ : state) {
    if (++k == d.size()) {
      k = 1;
      reset();
    }
    ukf.predict(d.t[k] - d.t[k - 1], d.u.col(k - 1).data());
    ukf.update(d.y.col(k).data());
    benchmark::DoNotOptimize(ukf.z.data());
  }
}
BENCHMARK(HandWrittenTwoTankUkfStep)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace riccati

namespace riccati {
namespace {

// Output error on the two-tank record from Hensen's start [20 20 1 1], as
// OutputError.TwoTankFromHensensStartRecoversTheTruth runs it: the whole
// output_error() call (Ceres' Levenberg-Marquardt, Jacobians from forward
// sensitivities, zero-order hold, x0 the first measurement, bounds theta >= 0
// from the model, the default tolerances; then the covariance and residual
// diagnostics at the estimate), RK4 with `substeps` per sample (10, the
// default, is the benchmark; 4 and 2 show what fewer steps buy and cost).
// bench/oe_versus_scipy.sh runs it beside scipy.optimize.least_squares on the
// same problem (bench/oe_scipy.py). Counters: the estimate's worst relative
// error against the truth of two_tank.json, the simulations of the record
// (evaluations, of which jacobian_evaluations with sensitivities) and the
// iterations; the label is the estimate.
void TwoTankOutputErrorWith(benchmark::State& state, IntegratorKind integrator) {
  static TwoTankFixture fixture;
  Experiment e;
  e.data = bind_dataset(*fixture.model, fixture.data).value();
  e.x0 = e.data.y.col(0);
  OutputErrorSettings settings;
  settings.parameters = default_parameters(*fixture.model, Eigen::Vector4d(20, 20, 1, 1));
  settings.simulation.integrator.kind = integrator;
  settings.simulation.integrator.substeps = static_cast<int>(state.range(0));
  const std::vector<Experiment> experiments{e};
  EstimationResult last;
  for (auto _ : state) {
    auto r = output_error(fixture.model, experiments, settings);
    if (!r.is_ok()) {
      state.SkipWithError(r.status().to_string().c_str());
      return;
    }
    benchmark::DoNotOptimize(r.value().theta.data());
    last = std::move(r).value();
  }
  std::ifstream in(RICCATI_TEST_DATA_DIR "/two_tank.json");
  const nlohmann::json meta = nlohmann::json::parse(in);
  Eigen::VectorXd truth(4);
  for (int i = 0; i < 4; ++i) {
    truth[i] = meta["parameters"][meta["parameter_order"][static_cast<std::size_t>(i)].get<std::string>()];
  }
  state.counters["worst_rel_error"] = ((last.theta - truth).array() / truth.array()).abs().maxCoeff();
  state.counters["evaluations"] = last.evaluations;
  state.counters["jacobian_evaluations"] = last.jacobian_evaluations;
  state.counters["iterations"] = last.iterations;
  state.counters["converged"] = last.converged ? 1.0 : 0.0;
  char label[160];
  std::snprintf(label, sizeof label, "theta=[%.17g %.17g %.17g %.17g] ", last.theta[0], last.theta[1], last.theta[2],
                last.theta[3]);
  state.SetLabel(label + last.termination);
}
void TwoTankOutputError(benchmark::State& state) { TwoTankOutputErrorWith(state, IntegratorKind::kRk4); }
BENCHMARK(TwoTankOutputError)->ArgName("substeps")->Arg(10)->Arg(4)->Arg(2)->Unit(benchmark::kMillisecond);
// The same with Dormand and Prince's 8th-order method, one or two steps a
// sample (12 evaluations a step against RK4's 4): the two-tank model's time
// constants (minutes) are long against its 1 s samples.
void TwoTankOutputErrorDop853(benchmark::State& state) { TwoTankOutputErrorWith(state, IntegratorKind::kDop853); }
BENCHMARK(TwoTankOutputErrorDop853)->ArgName("substeps")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

// Maximum likelihood on the same record from the same start, as
// MaxLikelihood.TwoTankFromHensensStartRecoversTheTruth runs it: the EKF as
// predictor (RK4, 10 substeps), Q = 0, P0 = 0, R = 1e-3 I given, bounds
// theta >= 0; the whole max_likelihood() call (the fit, then the Hessian and
// the diagnostics at the estimate): arg 0 with the exact gradient (Fisher
// scoring), 1 with central differences of the filter's residuals (Ceres).
// Counters as for TwoTankOutputError; evaluations are filter runs over the
// record (with or without sensitivities).
void TwoTankMaximumLikelihood(benchmark::State& state) {
  static TwoTankFixture fixture;
  Experiment e;
  e.data = bind_dataset(*fixture.model, fixture.data).value();
  e.x0 = e.data.y.col(0);
  MaxLikelihoodSettings settings;
  settings.filter.Q = Eigen::MatrixXd::Zero(6, 6);
  settings.filter.R = Eigen::Matrix2d::Identity() * 1e-3;
  settings.P0x = Eigen::Matrix2d::Zero();
  settings.parameters = default_parameters(*fixture.model, Eigen::Vector4d(20, 20, 1, 1));
  settings.differenced_gradient = state.range(0) == 1;
  const std::vector<Experiment> experiments{e};
  EstimationResult last;
  for (auto _ : state) {
    auto r = max_likelihood(fixture.model, experiments, settings);
    if (!r.is_ok()) {
      state.SkipWithError(r.status().to_string().c_str());
      return;
    }
    benchmark::DoNotOptimize(r.value().estimate.theta.data());
    last = std::move(r).value().estimate;
  }
  const Eigen::VectorXd truth = fixture.model->theta_default();
  state.counters["worst_rel_error"] = ((last.theta - truth).array() / truth.array()).abs().maxCoeff();
  state.counters["evaluations"] = last.evaluations;
  state.counters["jacobian_evaluations"] = last.jacobian_evaluations;
  state.counters["iterations"] = last.iterations;
  state.counters["converged"] = last.converged ? 1.0 : 0.0;
}
BENCHMARK(TwoTankMaximumLikelihood)->ArgName("differenced")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// Output error beside maximum likelihood with Q and R estimated, on the noisy
// two-tank record (tests/data/two_tank_noisy.csv, sigma = 0.005) from
// Hensen's start, x0 the first measurement (given), in one run: arg 0 is
// output error (sigma estimated), 1 maximum likelihood with its exact
// gradient (likelihood_sensitivity.hpp), 2 the same with central differences
// of the filter's residuals (what it was before). Issue 32's target: 1 at
// most 3x the time of 0. ML: EKF (RK4, 10 substeps), P0 = 1e-4 I, Q from
// 1e-6 I and R from 1e-3 I, both estimated: 8 unknowns.
void TwoTankNoisyEstimation(benchmark::State& state) {
  static TwoTankFixture fixture;
  static const Dataset noisy =
      read_csv_file(RICCATI_TEST_DATA_DIR "/two_tank_noisy.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}})
          .value();
  Experiment e;
  e.data = bind_dataset(*fixture.model, noisy).value();
  e.x0 = e.data.y.col(0);
  const std::vector<Experiment> experiments{e};
  const ParameterSettings start = default_parameters(*fixture.model, Eigen::Vector4d(20, 20, 1, 1));
  OutputErrorSettings oe;
  oe.parameters = start;
  MaxLikelihoodSettings ml;
  ml.filter.Q = Eigen::MatrixXd::Zero(6, 6);
  ml.filter.Q.topLeftCorner(2, 2) = Eigen::Matrix2d::Identity() * 1e-6;
  ml.filter.R = Eigen::Matrix2d::Identity() * 1e-3;
  ml.P0x = Eigen::Matrix2d::Identity() * 1e-4;
  ml.parameters = start;
  ml.estimate_process_noise = true;
  ml.estimate_measurement_noise = true;
  ml.differenced_gradient = state.range(0) == 2;
  EstimationResult last;
  for (auto _ : state) {
    Result<EstimationResult> r = state.range(0) == 0
                                     ? output_error(fixture.model, experiments, oe)
                                     : Result<EstimationResult>([&]() -> Result<EstimationResult> {
                                         RICCATI_ASSIGN_OR_RETURN(MaxLikelihoodResult m,
                                                                  max_likelihood(fixture.model, experiments, ml));
                                         return std::move(m.estimate);
                                       }());
    if (!r.is_ok()) {
      state.SkipWithError(r.status().to_string().c_str());
      return;
    }
    last = std::move(r).value();
    benchmark::DoNotOptimize(last.theta.data());
  }
  const Eigen::VectorXd truth = fixture.model->theta_default();
  state.counters["worst_rel_error"] = ((last.theta - truth).array() / truth.array()).abs().maxCoeff();
  state.counters["evaluations"] = last.evaluations;
  state.counters["iterations"] = last.iterations;
  state.counters["converged"] = last.converged ? 1.0 : 0.0;
  state.SetLabel(state.range(0) == 0 ? "output error" : last.gradient);
}
BENCHMARK(TwoTankNoisyEstimation)->ArgName("method")->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

// One simulation of the two-tank record at the truth (RK4, 10 substeps, zero-
// order hold): the states alone (what a trial step of output error costs) and
// with the forward sensitivities to theta (what a Jacobian costs). Where the
// time of TwoTankOutputError goes.
void TwoTankSimulation(benchmark::State& state, bool sensitivities) {
  static TwoTankFixture fixture;
  const Dataset data = bind_dataset(*fixture.model, fixture.data).value();
  auto simulator = SensitivitySimulator::create(fixture.model, SimulationSettings{}, false).value();
  const Eigen::VectorXd x0 = data.y.col(0);
  const Eigen::VectorXd theta = Eigen::Vector4d(10, 5, 0.0791, 0.1342);
  SimulatedRecord record;
  for (auto _ : state) {
    const Status s = simulator.simulate(data.t, data.u, x0, theta, sensitivities, &record);
    if (!s.is_ok()) {
      state.SkipWithError(s.to_string().c_str());
      return;
    }
    benchmark::DoNotOptimize(record.y.data());
  }
  state.counters["per_sample"] = benchmark::Counter(static_cast<double>(data.size()),
                                                    benchmark::Counter::kIsIterationInvariantRate |
                                                        benchmark::Counter::kInvert);
}
BENCHMARK_CAPTURE(TwoTankSimulation, values, false)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(TwoTankSimulation, sensitivities, true)->Unit(benchmark::kMillisecond);

// The same simulation written by hand for the two-tank model only: fixed
// sizes, analytic Jacobians, no plugin, no checks; RK4 with 10 substeps, the
// sensitivities S' = f_x S + f_theta (2 x 4) beside the states. What a
// simulation of the record costs at least with this integrator: the floor
// for TwoTankSimulation.
struct HandWrittenTwoTank {
  static void rhs(const double* z, const double* th, double F1, double F2, double* d, bool sensitivities) {
    const double h1 = z[0], h2 = z[1], A1 = th[0], A2 = th[1], k1 = th[2], k2 = th[3];
    const double r1 = h1 > 0.0 ? std::sqrt(h1) : 0.0, r2 = h2 > 0.0 ? std::sqrt(h2) : 0.0;
    const double f1 = (F1 - k1 * r1) / A1, f2 = (F2 + k1 * r1 - k2 * r2) / A2;
    d[0] = f1;
    d[1] = f2;
    if (!sensitivities) return;
    const double d1 = h1 > 0.0 ? 0.5 / r1 : 0.0, d2 = h2 > 0.0 ? 0.5 / r2 : 0.0;
    const double a11 = -k1 * d1 / A1, a21 = k1 * d1 / A2, a22 = -k2 * d2 / A2;  // f_x, a12 = 0
    const double ft[8] = {-f1 / A1, 0.0, -r1 / A1, 0.0, 0.0, -f2 / A2, r1 / A2, -r2 / A2};  // f_theta, row-major
    const double* S = z + 2;  // row-major 2 x 4
    for (int j = 0; j < 4; ++j) {
      d[2 + j] = a11 * S[j] + ft[j];
      d[6 + j] = a21 * S[j] + a22 * S[4 + j] + ft[4 + j];
    }
  }
};

void HandWrittenTwoTankSimulation(benchmark::State& state, bool sensitivities) {
  static TwoTankFixture fixture;
  const Dataset& d = fixture.data;
  const double theta[4] = {10, 5, 0.0791, 0.1342};
  const int n = sensitivities ? 10 : 2;
  Eigen::MatrixXd y(2, d.size());
  for (auto _ : state) {
    double z[10] = {d.y(0, 0), d.y(1, 0), 0, 0, 0, 0, 0, 0, 0, 0};
    y.col(0) << z[0], z[1];
    for (Eigen::Index k = 1; k < d.size(); ++k) {
      const double h = (d.t[k] - d.t[k - 1]) / 10.0, F1 = d.u(0, k - 1), F2 = d.u(1, k - 1);
      for (int s = 0; s < 10; ++s) {
        double k1[10], k2[10], k3[10], k4[10], tmp[10];
        HandWrittenTwoTank::rhs(z, theta, F1, F2, k1, sensitivities);
        for (int i = 0; i < n; ++i) tmp[i] = z[i] + 0.5 * h * k1[i];
        HandWrittenTwoTank::rhs(tmp, theta, F1, F2, k2, sensitivities);
        for (int i = 0; i < n; ++i) tmp[i] = z[i] + 0.5 * h * k2[i];
        HandWrittenTwoTank::rhs(tmp, theta, F1, F2, k3, sensitivities);
        for (int i = 0; i < n; ++i) tmp[i] = z[i] + h * k3[i];
        HandWrittenTwoTank::rhs(tmp, theta, F1, F2, k4, sensitivities);
        for (int i = 0; i < n; ++i) z[i] += h / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
      }
      y.col(k) << z[0], z[1];
      benchmark::DoNotOptimize(z);
    }
    benchmark::DoNotOptimize(y.data());
  }
}
BENCHMARK_CAPTURE(HandWrittenTwoTankSimulation, values, false)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(HandWrittenTwoTankSimulation, sensitivities, true)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace riccati

BENCHMARK_MAIN();


// Text models (server/engine/models/text) against the compiled plugin, in
// the same run:
//
//   build/bin/engine_bench --benchmark_filter='TextModel|TwoTankModelCallText'
//
// TwoTankTextFilterStep: the filter step of TwoTankFilterStep with the
// two-tank model as a plugin and as text (models/text/two_tank.yaml); the
// target is text <= 1.5 x plugin. TextModelCompile: parsing, checking,
// differentiating and compiling to tapes a generated 200-line model
// (target < 100 ms).
#include <sstream>

#include "engine/models/text/text_model.hpp"

namespace riccati {
namespace {

ModelPtr two_tank_text_model() {
  std::ifstream in(RICCATI_TEXT_MODEL_DIR "/two_tank.yaml");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return compile_text_model(text, "two_tank.yaml").value().model;
}

void TwoTankTextFilterStep(benchmark::State& state, FilterKind kind, bool text) {
  static TwoTankFixture fixture;
  static const ModelPtr text_model = two_tank_text_model();
  const IdentificationSettings s = fixture.hensen(kind);
  auto filter = make_filter(text ? text_model : fixture.model, s.filter).value();
  Eigen::VectorXd z0(6);
  z0 << fixture.data.y.col(0), s.initial.theta0;
  const Dataset& d = fixture.data;
  Eigen::Index k = 0;
  (void)filter->reset(d.t[0], z0, s.initial.P0);
  for (auto _ : state) {
    if (++k == d.size()) {
      k = 1;
      (void)filter->reset(d.t[0], z0, s.initial.P0);
    }
    Status st = filter->predict(d.t[k], d.u.col(k - 1).data(), d.u.col(k).data());
    if (st.is_ok()) st = filter->update(d.y.col(k).data(), d.u.col(k).data());
    if (!st.is_ok()) {
      state.SkipWithError(st.to_string().c_str());
      break;
    }
  }
}
BENCHMARK_CAPTURE(TwoTankTextFilterStep, ekf_plugin, FilterKind::kEkf, false)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(TwoTankTextFilterStep, ekf_text, FilterKind::kEkf, true)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(TwoTankTextFilterStep, ukf_plugin, FilterKind::kUkf, false)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(TwoTankTextFilterStep, ukf_text, FilterKind::kUkf, true)->Unit(benchmark::kMicrosecond);

void TwoTankModelCallText(benchmark::State& state, bool jacobian) {
  static const ModelPtr model = two_tank_text_model();
  const double x[2] = {0.4, 0.15}, theta[4] = {10, 5, 0.0791, 0.1342}, u[2] = {0.1, 0.03};
  double out[2], jac[12];
  for (auto _ : state) {
    Status s = jacobian ? model->f_jacobian(0.0, u, x, theta, out, jac) : model->f(0.0, u, 1, 1, x, theta, out);
    benchmark::DoNotOptimize(s);
    benchmark::DoNotOptimize(out);
  }
}
BENCHMARK_CAPTURE(TwoTankModelCallText, f, false);
BENCHMARK_CAPTURE(TwoTankModelCallText, f_jacobian, true);

// A 200-line model: 10 states, 10 parameters, 2 inputs, 160 helpers each
// mixing two earlier names through a function, 10 derivatives, 10 outputs.
std::string generated_model(int helpers) {
  std::ostringstream s;
  s << "model: generated\nstates:\n";
  for (int i = 0; i < 10; ++i) s << "  x" << i << ": {unit: m}\n";
  s << "inputs: [u0, u1]\nparameters:\n";
  for (int j = 0; j < 10; ++j) s << "  p" << j << ": {value: " << 0.5 + 0.1 * j << ", min: 0}\n";
  s << "define:\n";
  const char* fns[] = {"sin", "cos", "tanh", "atan", "exp"};
  auto name = [](int k) {
    std::ostringstream n;
    if (k < 10) {
      n << "x" << k;
    } else if (k < 20) {
      n << "p" << k - 10;
    } else {
      n << "h" << k - 20;
    }
    return n.str();
  };
  for (int h = 0; h < helpers; ++h) {
    const int a = (h * 7 + 3) % (20 + h), b = (h * 13 + 5) % (20 + h);
    s << "  h" << h << ": " << fns[h % 5] << "(0.1 * " << name(a) << ") * " << name(b) << " + u" << h % 2
      << " / (1 + " << name(b) << " ^ 2)\n";
  }
  s << "der:\n";
  for (int i = 0; i < 10; ++i) s << "  x" << i << ": h" << helpers - 1 - i << " - p" << i << " * x" << i << "\n";
  s << "outputs:\n";
  for (int i = 0; i < 10; ++i) s << "  y" << i << ": x" << i << " + h" << i << "\n";
  return s.str();
}

void TextModelCompile(benchmark::State& state) {
  const std::string text = generated_model(160);
  std::size_t lines = 0;
  for (const char c : text) lines += c == '\n' ? 1 : 0;
  std::size_t tape = 0;
  for (auto _ : state) {
    auto m = compile_text_model(text, "generated.yaml");
    if (!m.is_ok()) {
      state.SkipWithError(m.status().to_string().c_str());
      break;
    }
    tape = m->summary.tape_length;
    benchmark::DoNotOptimize(m->model.get());
  }
  state.counters["lines"] = static_cast<double>(lines);
  state.counters["tape"] = static_cast<double>(tape);
}
BENCHMARK(TextModelCompile)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace riccati
