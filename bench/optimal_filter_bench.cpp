// The optimal filter's step on the flexible manipulator (10 augmented
// quantities, 3 estimated inputs and accelerations, 5 equations), with the
// weights of case C of the specification and RK4 with one step per sample,
// through the real plugin path. Target: >= 40,000 steps/s on one core, 100
// times real time at 400 Hz.
//
//   build/bin/engine_bench --benchmark_filter=OptimalFilterStep
#include <benchmark/benchmark.h>

#include "engine/data/dataset.hpp"
#include "engine/filters/filter.hpp"
#include "engine/models/plugin_loader.hpp"

namespace riccati {
namespace {

void OptimalFilterStep(benchmark::State& state, OptimalForm form) {
  static const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  static const Dataset d =
      read_csv_file(RICCATI_TEST_DATA_DIR "/flexible_manipulator.csv", ColumnMapping{"t", {"T"}, {"s1", "s2"}})
          .value();
  FilterSettings s;
  s.kind = FilterKind::kOptimal;
  s.integrator.substeps = 1;
  s.optimal.form = form;
  Eigen::VectorXd V(5), W(10), R0(10), z0(10);
  V << 1e6, 1e6, 1e4, 1e6, 1e6;
  W << 1e4, 1e4, 1e4, 1e4, 1e10, 1e10, 1e10, 1e10, 1e10, 1e10;
  R0 << 1e12, 1e12, 1e12, 1e12, 1e1, 1e2, 5e-4, 1e1, 5e3, 5e3;
  z0 << 0, 0, 0, 0, .001, .001, 6.5, .01, .005, .0025;
  s.optimal.V = V.asDiagonal();
  s.optimal.W = W.asDiagonal();
  auto filter = make_filter(registry.find("flexible_manipulator"), s).value();
  const Eigen::MatrixXd P0 = R0.cwiseInverse().asDiagonal();
  auto restart = [&] {
    (void)filter->reset(d.t[0], z0, P0);
    (void)filter->update(d.y.col(0).data(), d.u.col(0).data());
  };
  restart();
  Eigen::Index k = 0;
  for (auto _ : state) {
    if (++k == d.size()) {
      state.PauseTiming();
      k = 1;
      restart();
      state.ResumeTiming();
    }
    const Status st = filter->step(d.t[k], d.u.col(k - 1).data(), d.u.col(k).data(), d.y.col(k).data());
    if (!st.is_ok()) {
      state.SkipWithError(st.to_string().c_str());
      break;
    }
    benchmark::DoNotOptimize(filter->state().data());
  }
  state.SetItemsProcessed(state.iterations());  // steps
}
BENCHMARK_CAPTURE(OptimalFilterStep, continuous, OptimalForm::kContinuous)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(OptimalFilterStep, split_step, OptimalForm::kSplitStep)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace riccati
