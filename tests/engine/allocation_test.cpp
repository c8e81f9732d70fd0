// No filter allocates memory per sample: after the first step has sized its
// work space, a step (predict and update) runs without a call to malloc. Counted by
// interposing malloc, calloc and realloc for this test binary (they forward
// to glibc's own), per thread, so nothing else in the process interferes.
#include <gtest/gtest.h>

#include <cstddef>
#include <ostream>

#include "engine/data/dataset.hpp"
#include "engine/filters/filter.hpp"
#include "engine/models/plugin_loader.hpp"

extern "C" {
void* __libc_malloc(std::size_t size);
void* __libc_calloc(std::size_t count, std::size_t size);
void* __libc_realloc(void* p, std::size_t size);
}

namespace {
thread_local std::size_t allocations = 0;
}  // namespace

extern "C" {
void* malloc(std::size_t size) {
  ++allocations;
  return __libc_malloc(size);
}
void* calloc(std::size_t count, std::size_t size) {
  ++allocations;
  return __libc_calloc(count, size);
}
void* realloc(void* p, std::size_t size) {
  ++allocations;
  return __libc_realloc(p, size);
}
}

namespace riccati {
namespace {

struct Case {
  const char* name;
  const char* model;
  const char* csv;
  std::vector<std::string> inputs, outputs;
  FilterSettings settings;
  Eigen::VectorXd z0;
  Eigen::MatrixXd P0;
};

Eigen::VectorXd vec(std::initializer_list<double> v) {
  Eigen::VectorXd out(static_cast<Eigen::Index>(v.size()));
  Eigen::Index i = 0;
  for (double x : v) out[i++] = x;
  return out;
}

std::vector<Case> cases() {
  std::vector<Case> out;
  for (OptimalForm form : {OptimalForm::kContinuous, OptimalForm::kSplitStep}) {
    Case c{form == OptimalForm::kContinuous ? "optimal_continuous" : "optimal_split_step",
           "flexible_manipulator", "flexible_manipulator.csv", {"T"}, {"s1", "s2"}, {}, {}, {}};
    c.settings.kind = FilterKind::kOptimal;
    c.settings.integrator.substeps = 1;
    c.settings.optimal.form = form;
    c.settings.optimal.V = vec({1e6, 1e6, 1e4, 1e6, 1e6}).asDiagonal();
    c.settings.optimal.W = vec({1e4, 1e4, 1e4, 1e4, 1e10, 1e10, 1e10, 1e10, 1e10, 1e10}).asDiagonal();
    c.z0 = vec({0, 0, 0, 0, .001, .001, 6.5, .01, .005, .0025});
    c.P0 = vec({1e12, 1e12, 1e12, 1e12, 1e1, 1e2, 5e-4, 1e1, 5e3, 5e3}).cwiseInverse().asDiagonal();
    out.push_back(c);
  }
  return out;
}

void PrintTo(const Case& c, std::ostream* os) { *os << c.name; }

class NoAllocation : public ::testing::TestWithParam<Case> {};

TEST_P(NoAllocation, PerSampleSteps) {
  const Case& c = GetParam();
  static const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  const Dataset d =
      read_csv_file(std::string(RICCATI_TEST_DATA_DIR) + "/" + c.csv, ColumnMapping{"t", c.inputs, c.outputs}).value();
  auto filter = make_filter(registry.find(c.model), c.settings).value();
  Eigen::VectorXd z0 = c.z0;
  z0.head(d.y.rows()) = d.y.col(0);  // both models' outputs are their first states
  ASSERT_TRUE(filter->reset(d.t[0], z0, c.P0).is_ok());
  ASSERT_TRUE(filter->update(d.y.col(0).data(), d.u.col(0).data()).is_ok());
  auto step = [&](Eigen::Index k) {
    return filter->step(d.t[k], d.u.col(k - 1).data(), d.u.col(k).data(), d.y.col(k).data());
  };
  ASSERT_TRUE(step(1).is_ok());  // sizes whatever is sized lazily
  const std::size_t before = allocations;
  for (Eigen::Index k = 2; k < 200; ++k) ASSERT_TRUE(step(k).is_ok());
  EXPECT_EQ(allocations - before, 0u) << "allocations in 198 steps of " << c.name;
}

INSTANTIATE_TEST_SUITE_P(EveryFilter, NoAllocation, ::testing::ValuesIn(cases()),
                         [](const ::testing::TestParamInfo<Case>& param) { return std::string(param.param.name); });

}  // namespace
}  // namespace riccati
