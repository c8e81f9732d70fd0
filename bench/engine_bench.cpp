// Engine benchmarks (Google Benchmark), on one core:
//
//   build/bin/engine_bench --benchmark_filter=TwoTank
//
// Filter step on the two-tank model (6 augmented states, RK4 with 10
// substeps) measured over Hensen's 10-pass identification (20,000 steps),
// through the real plugin path: the reported per_step is the whole
// identification's time divided by its steps (prediction + update + the
// bookkeeping of a pass).
#include <benchmark/benchmark.h>

#include <Eigen/Cholesky>
#include <cmath>

#include "engine/estimation/identification.hpp"
#include "engine/models/plugin_loader.hpp"
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

// The filter alone: predict + update over one pass, no identification bookkeeping.
void TwoTankFilterStep(benchmark::State& state, FilterKind kind) {
  static TwoTankFixture fixture;
  const IdentificationSettings s = fixture.hensen(kind);
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

BENCHMARK_CAPTURE(TwoTankIdentification, ekf, FilterKind::kEkf)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(TwoTankIdentification, ukf, FilterKind::kUkf)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(TwoTankFilterStep, ekf, FilterKind::kEkf)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(TwoTankFilterStep, ukf, FilterKind::kUkf)->Unit(benchmark::kMicrosecond);

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

// A hand-written CD-EKF for the two-tank model only: fixed sizes, analytic
// Jacobian, no plugin, no checks. The same algorithm as the engine's EKF
// (RK4 on [x; P] with 10 substeps, Joseph update), to measure side by side:
// what the general plugin path costs over code written for one model.
struct HandWrittenTwoTankEkf {
  using Vec6 = Eigen::Matrix<double, 6, 1>;
  using Mat6 = Eigen::Matrix<double, 6, 6>;
  using Mat26 = Eigen::Matrix<double, 2, 6>;
  Vec6 z;
  Mat6 P;
  Eigen::Matrix2d R = Eigen::Vector2d(1e-3, 1e-3).asDiagonal();

  // Derivatives of x (first 2) and P, with F from the analytic Jacobian.
  static void rhs(const Vec6& z, const Mat6& P, const double* u, Vec6& dz, Mat6& dP) {
    const double h1 = z[0], h2 = z[1], A1 = z[2], A2 = z[3], k1 = z[4], k2 = z[5];
    const double s1 = h1 > 0 ? std::sqrt(h1) : 0.0, s2 = h2 > 0 ? std::sqrt(h2) : 0.0;
    const double q1 = k1 * s1, q2 = k2 * s2;
    dz.setZero();
    dz[0] = (u[0] - q1) / A1;
    dz[1] = (u[1] + q1 - q2) / A2;
    Mat6 F = Mat6::Zero();
    const double d1 = s1 > 0 ? 0.5 * k1 / s1 : 0.0, d2 = s2 > 0 ? 0.5 * k2 / s2 : 0.0;
    F(0, 0) = -d1 / A1;
    F(0, 2) = -dz[0] / A1;
    F(0, 4) = -s1 / A1;
    F(1, 0) = d1 / A2;
    F(1, 1) = -d2 / A2;
    F(1, 3) = -dz[1] / A2;
    F(1, 4) = s1 / A2;
    F(1, 5) = -s2 / A2;
    const Mat6 FP = F * P;
    dP = FP + FP.transpose();
  }

  void predict(double dt, const double* u) {
    const int substeps = 10;
    const double h = dt / substeps;
    for (int s = 0; s < substeps; ++s) {
      Vec6 k1z, k2z, k3z, k4z;
      Mat6 k1P, k2P, k3P, k4P;
      rhs(z, P, u, k1z, k1P);
      rhs(z + 0.5 * h * k1z, P + 0.5 * h * k1P, u, k2z, k2P);
      rhs(z + 0.5 * h * k2z, P + 0.5 * h * k2P, u, k3z, k3P);
      rhs(z + h * k3z, P + h * k3P, u, k4z, k4P);
      z += h / 6.0 * (k1z + 2.0 * (k2z + k3z) + k4z);
      P += h / 6.0 * (k1P + 2.0 * (k2P + k3P) + k4P);
    }
    P = 0.5 * (P + P.transpose()).eval();
  }

  void update(const double* y) {
    Mat26 G = Mat26::Zero();
    G(0, 0) = 1.0;
    G(1, 1) = 1.0;
    const Eigen::Vector2d innovation(y[0] - z[0], y[1] - z[1]);
    const Eigen::Matrix<double, 6, 2> PGt = P * G.transpose();
    const Eigen::Matrix2d S = G * PGt + R;
    const Eigen::LLT<Eigen::Matrix2d> llt(S);
    const Eigen::Matrix<double, 6, 2> K = llt.solve(PGt.transpose()).transpose();
    z += K * innovation;
    const Mat6 IKG = Mat6::Identity() - K * G;
    P = IKG * P * IKG.transpose() + K * R * K.transpose();
    P = 0.5 * (P + P.transpose()).eval();
  }
};

void HandWrittenTwoTankEkfStep(benchmark::State& state) {
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
    ekf.predict(d.t[k] - d.t[k - 1], d.u.col(k - 1).data());
    ekf.update(d.y.col(k).data());
    benchmark::DoNotOptimize(ekf.z.data());
  }
}
BENCHMARK(HandWrittenTwoTankEkfStep)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace riccati

BENCHMARK_MAIN();
