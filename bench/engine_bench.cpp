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

#include "engine/identification.hpp"
#include "engine/plugin_loader.hpp"

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

  IdentificationSettings hensen(FilterKind kind) const {
    IdentificationSettings s;
    s.filter.kind = kind;
    s.filter.integrator.kind = IntegratorKind::kRk4;
    s.filter.integrator.substeps = 10;
    s.filter.Q = Eigen::MatrixXd::Zero(6, 6);
    s.filter.R = Eigen::Vector2d(1e-3, 1e-3).asDiagonal();
    s.initial_state = InitialState::kFirstMeasurement;
    s.theta0 = Eigen::Vector4d(20, 20, 1, 1);
    Eigen::VectorXd p0(6);
    p0 << 0, 0, 10, 10, 10, 10;
    s.P0 = p0.asDiagonal();
    s.passes = 10;
    return s;
  }
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
  z0 << fixture.data.y.col(0), s.theta0;
  const Dataset& d = fixture.data;
  Eigen::Index k = 0;
  (void)filter->reset(d.t[0], z0, s.P0);
  for (auto _ : state) {
    if (++k == d.size()) {
      k = 1;
      (void)filter->reset(d.t[0], z0, s.P0);
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

BENCHMARK_MAIN();
