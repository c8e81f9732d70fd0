// The optimal filter's step on the flexible manipulator (10 augmented
// quantities, 3 estimated inputs and accelerations, 5 equations), with the
// weights of case C of the specification and RK4 with one step per sample,
// through the real plugin path. Target: >= 40,000 steps/s on one core, 100
// times real time at 400 Hz.
//
//   build/bin/engine_bench --benchmark_filter=OptimalFilterStep
#include <benchmark/benchmark.h>

#include <memory>
#include <vector>

#include "engine/data/dataset.hpp"
#include "engine/filters/filter.hpp"
#include "engine/models/plugin_loader.hpp"

namespace riccati {
namespace {

const Dataset& manipulator_data() {
  static const Dataset d =
      read_csv_file(RICCATI_TEST_DATA_DIR "/flexible_manipulator.csv", ColumnMapping{"t", {"T"}, {"s1", "s2"}})
          .value();
  return d;
}

// Filters of case C, each reset to the record's start and updated with its
// first sample, then stepped through the record in turn.
class CaseCFilters {
 public:
  CaseCFilters(OptimalForm form, int count) {
    static const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
    FilterSettings s;
    s.kind = FilterKind::kOptimal;
    s.integrator.substeps = 1;
    s.optimal.form = form;
    Eigen::VectorXd V(5), W(10), R0(10);
    V << 1e6, 1e6, 1e4, 1e6, 1e6;
    W << 1e4, 1e4, 1e4, 1e4, 1e10, 1e10, 1e10, 1e10, 1e10, 1e10;
    R0 << 1e12, 1e12, 1e12, 1e12, 1e1, 1e2, 5e-4, 1e1, 5e3, 5e3;
    z0_.resize(10);
    z0_ << 0, 0, 0, 0, .001, .001, 6.5, .01, .005, .0025;
    s.optimal.V = V.asDiagonal();
    s.optimal.W = W.asDiagonal();
    P0_ = R0.cwiseInverse().asDiagonal();
    for (int i = 0; i < count; ++i) filters_.push_back(make_filter(registry.find("flexible_manipulator"), s).value());
    restart();
  }

  // Each filter one sample on (back to the start at the record's end,
  // outside the timing); false with the error on the bench's state.
  bool step(benchmark::State& state) {
    const Dataset& d = manipulator_data();
    if (++k_ == d.size()) {
      state.PauseTiming();
      restart();
      k_ = 1;
      state.ResumeTiming();
    }
    for (auto& f : filters_) {
      const Status st = f->step(d.t[k_], d.u.col(k_ - 1).data(), d.u.col(k_).data(), d.y.col(k_).data());
      if (!st.is_ok()) {
        state.SkipWithError(st.to_string().c_str());
        return false;
      }
      benchmark::DoNotOptimize(f->state().data());
    }
    return true;
  }

 private:
  void restart() {
    const Dataset& d = manipulator_data();
    k_ = 0;  // the sample each filter was last updated with
    for (auto& f : filters_) {
      (void)f->reset(d.t[0], z0_, P0_);
      (void)f->update(d.y.col(0).data(), d.u.col(0).data());
    }
  }

  Eigen::VectorXd z0_;
  Eigen::MatrixXd P0_;
  std::vector<std::unique_ptr<Filter>> filters_;
  Eigen::Index k_ = 0;
};

void OptimalFilterStep(benchmark::State& state, OptimalForm form) {
  CaseCFilters filter(form, 1);
  for (auto _ : state) {
    if (!filter.step(state)) break;
  }
  state.SetItemsProcessed(state.iterations());  // steps
}

// The same step with `filters` filters stepped in turn, as a daemon steps
// its sessions: a filter's work space is no longer in the core's caches
// when its turn comes (64 filters' is about a MiB, the L2 of a core here).
// Per step of one filter.
void OptimalFilterStepInTurn(benchmark::State& state) {
  const int count = static_cast<int>(state.range(0));
  CaseCFilters filters(OptimalForm::kContinuous, count);
  for (auto _ : state) {
    if (!filters.step(state)) break;
  }
  state.SetItemsProcessed(state.iterations() * count);  // steps
}

BENCHMARK_CAPTURE(OptimalFilterStep, continuous, OptimalForm::kContinuous)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(OptimalFilterStep, split_step, OptimalForm::kSplitStep)->Unit(benchmark::kMicrosecond);
BENCHMARK(OptimalFilterStepInTurn)->ArgName("filters")->Arg(1)->Arg(16)->Arg(64)->Arg(256)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace riccati
