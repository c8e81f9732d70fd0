// No filter of any kind allocates memory per measurement: after the first
// steps have sized its work space, a step runs without a call to malloc
// (counted per thread: support/counted_malloc.hpp).
#include <gtest/gtest.h>

#include <cstddef>
#include <ostream>

#include "engine/data/dataset.hpp"
#include "engine/estimation/identification.hpp"
#include "engine/estimation/online_runner.hpp"
#include "engine/estimation/smoother.hpp"
#include "engine/models/plugin_loader.hpp"
#include "support/counted_malloc.hpp"

namespace riccati {
namespace {

struct Case {
  const char* name;
  const char* model;
  const char* csv;
  std::vector<std::string> inputs, outputs;
  FilterSettings settings;
  InitialEstimate initial;
};

Eigen::VectorXd vec(std::initializer_list<double> v) {
  Eigen::VectorXd out(static_cast<Eigen::Index>(v.size()));
  Eigen::Index i = 0;
  for (double x : v) out[i++] = x;
  return out;
}

// Every filter kind (and each form of the optimal filter), with the settings
// of the project's examples: Hensen's two-tank for the EKF and the UKF, case
// C of the optimal filter's specification for the manipulator.
std::vector<Case> cases() {
  std::vector<Case> out;
  for (FilterKind kind : {FilterKind::kEkf, FilterKind::kUkf}) {
    Case c{kind == FilterKind::kEkf ? "ekf" : "ukf", "two_tank", "two_tank.csv", {"F1", "F2"}, {"h1", "h2"}, {}, {}};
    c.settings.kind = kind;
    c.settings.Q = Eigen::MatrixXd::Zero(6, 6);
    c.settings.R = Eigen::Matrix2d::Identity() * 1e-3;
    c.initial.mode = InitialState::kFirstMeasurement;
    c.initial.theta0 = vec({20, 20, 1, 1});
    c.initial.P0 = vec({0, 0, 10, 10, 10, 10}).asDiagonal();
    out.push_back(c);
  }
  // The EKF's other gain and covariance update.
  Case pinv = out.front();
  pinv.name = "ekf_pinv_short_update";
  pinv.settings.inversion = GainInversion::kPseudoInverse;
  pinv.settings.joseph = false;
  out.push_back(pinv);
  // Keeping what a smoother needs of each prediction (the EKF's transition
  // matrix, the UKF's cross covariance).
  for (int i = 0; i < 2; ++i) {
    Case smoothing = out[static_cast<std::size_t>(i)];
    smoothing.name = i == 0 ? "ekf_smoothing" : "ukf_smoothing";
    smoothing.settings.smoothing = true;
    out.push_back(smoothing);
  }
  for (OptimalForm form : {OptimalForm::kContinuous, OptimalForm::kSplitStep}) {
    Case c{form == OptimalForm::kContinuous ? "optimal_continuous" : "optimal_split_step",
           "flexible_manipulator", "flexible_manipulator.csv", {"T"}, {"s1", "s2"}, {}, {}};
    c.settings.kind = FilterKind::kOptimal;
    c.settings.integrator.substeps = 1;
    c.settings.optimal.form = form;
    c.settings.optimal.V = vec({1e6, 1e6, 1e4, 1e6, 1e6}).asDiagonal();
    c.settings.optimal.W = vec({1e4, 1e4, 1e4, 1e4, 1e10, 1e10, 1e10, 1e10, 1e10, 1e10}).asDiagonal();
    c.initial.mode = InitialState::kGiven;
    c.initial.x0 = vec({0, 0, 0, 0});
    c.initial.theta0 = vec({.001, .001, 6.5, .01, .005, .0025});
    c.initial.P0 = vec({1e12, 1e12, 1e12, 1e12, 1e1, 1e2, 5e-4, 1e1, 5e3, 5e3}).cwiseInverse().asDiagonal();
    out.push_back(c);
  }
  return out;
}

void PrintTo(const Case& c, std::ostream* os) { *os << c.name; }

class NoAllocation : public ::testing::TestWithParam<Case> {};

// The on-line runner is what sessions and identification passes step: after
// its first steps have sized whatever is sized lazily, a measurement (hold,
// predict, update) allocates nothing.
TEST_P(NoAllocation, PerMeasurement) {
  const Case& c = GetParam();
  static const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  const Dataset d =
      read_csv_file(std::string(RICCATI_TEST_DATA_DIR) + "/" + c.csv, ColumnMapping{"t", c.inputs, c.outputs}).value();
  auto runner = OnlineRunner::create(registry.find(c.model), c.settings, c.initial);
  ASSERT_TRUE(runner.is_ok()) << runner.status().to_string();
  auto advance = [&](Eigen::Index k) {
    return runner->advance(d.t[k], {d.u.col(k).data(), static_cast<std::size_t>(d.u.rows())},
                           {d.y.col(k).data(), static_cast<std::size_t>(d.y.rows())});
  };
  for (Eigen::Index k = 0; k < 2; ++k) ASSERT_TRUE(advance(k).is_ok());
  const std::size_t before = testing::allocations;
  for (Eigen::Index k = 2; k < 200; ++k) ASSERT_TRUE(advance(k).is_ok());
  EXPECT_EQ(testing::allocations - before, 0u) << "allocations in 198 measurements of " << c.name;
}

INSTANTIATE_TEST_SUITE_P(EveryFilterKind, NoAllocation, ::testing::ValuesIn(cases()),
                         [](const ::testing::TestParamInfo<Case>& param) { return std::string(param.param.name); });

// The smoother sizes its storage once for the whole record: smoothing 400
// samples allocates as often as smoothing 200 (nothing per sample, forward
// or backward).
TEST(NoAllocation, PerSmoothedSample) {
  static const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  const Dataset d =
      read_csv_file(std::string(RICCATI_TEST_DATA_DIR) + "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}})
          .value();
  for (const Case& c : cases()) {
    if (c.settings.kind == FilterKind::kOptimal || c.settings.smoothing) continue;
    SmootherSettings s;
    s.filter = c.settings;
    s.initial = c.initial;
    auto allocations_to_smooth = [&](Eigen::Index samples) {
      s.end_sample = samples;
      const std::size_t before = testing::allocations;
      const auto r = smooth(registry.find(c.model), d, s);
      const std::size_t count = testing::allocations - before;
      EXPECT_TRUE(r.is_ok()) << r.status().to_string();
      return count;
    };
    EXPECT_EQ(allocations_to_smooth(400), allocations_to_smooth(200)) << c.name;
  }
}

// A whole identification (the iterated filter of the 1999 toolbox, two
// passes) sizes what it keeps for the record once: filtering 400 samples
// allocates as often as filtering 200 (nothing per sample), for every
// filter kind that identification runs; but for a few: the uncertainty at
// the end words its covariance and warnings from what the data say (which
// covariance, which outputs are not white), so its strings differ.
TEST(NoAllocation, PerIdentifiedSample) {
  static const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  for (const Case& c : cases()) {
    if (c.settings.smoothing) continue;
    const Dataset d = read_csv_file(std::string(RICCATI_TEST_DATA_DIR) + "/" + c.csv,
                                    ColumnMapping{"t", c.inputs, c.outputs})
                          .value();
    IdentificationSettings s;
    s.filter = c.settings;
    s.initial = c.initial;
    s.passes = 2;
    auto allocations_to_identify = [&](Eigen::Index samples) {
      s.end_sample = samples;
      const std::size_t before = testing::allocations;
      const auto r = identify(registry.find(c.model), d, s);
      const std::size_t count = testing::allocations - before;
      EXPECT_TRUE(r.is_ok()) << c.name << ": " << r.status().to_string();
      return count;
    };
    const auto longer = static_cast<double>(allocations_to_identify(400));
    EXPECT_NEAR(longer, static_cast<double>(allocations_to_identify(200)), 8.0) << c.name;
  }
}

}  // namespace
}  // namespace riccati
