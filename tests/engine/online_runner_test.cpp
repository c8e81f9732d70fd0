// The on-line runner: what sessions and identification passes share. A
// refused measurement leaves the run as it was; a divergence sticks; a run
// restored from its snapshot, or restarted, continues exactly as an
// uninterrupted one; the first pass of an identification is the runner over
// the samples. References are runs of the same runner without the event,
// and identify() for the last.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <set>
#include <string_view>

#include "engine/estimation/identification.hpp"
#include "engine/estimation/online_runner.hpp"
#include "engine/filters/filter_kinds.hpp"
#include "engine/models/plugin_loader.hpp"
#include "support/two_tank_hensen.hpp"

namespace riccati {
namespace {

struct TwoTank {
  ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  ModelPtr model = registry.find("two_tank");
  Dataset data = read_csv_file(RICCATI_TEST_DATA_DIR "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}})
                     .value();

  OnlineRunner runner(FilterKind kind) const {
    const IdentificationSettings s = testing::two_tank_hensen(kind);
    return OnlineRunner::create(model, s.filter, s.initial).value();
  }
  Status advance(OnlineRunner& r, Eigen::Index k) const {
    return r.advance(data.t[k], {data.u.col(k).data(), 2}, {data.y.col(k).data(), 2});
  }
};

const TwoTank& two_tank() {
  static const TwoTank fixture;
  return fixture;
}

void expect_same_estimate(const OnlineRunner& a, const OnlineRunner& b) {
  EXPECT_EQ(a.filter().time(), b.filter().time());
  EXPECT_TRUE((a.filter().state().array() == b.filter().state().array()).all());
  EXPECT_TRUE((a.filter().covariance().array() == b.filter().covariance().array()).all());
}

class RunnerPerKind : public ::testing::TestWithParam<FilterKind> {};

TEST_P(RunnerPerKind, ARefusedMeasurementChangesNothing) {
  const TwoTank& f = two_tank();
  OnlineRunner with_bad = f.runner(GetParam()), reference = f.runner(GetParam());
  with_bad.set_max_time_step(3600.0);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (Eigen::Index k = 0; k < 50; ++k) {
    ASSERT_TRUE(f.advance(reference, k).is_ok());
    ASSERT_TRUE(f.advance(with_bad, k).is_ok());
    if (k == 20) {
      const double y_nan[2] = {nan, 0.1}, u[2] = {0, 0}, y[2] = {0.1, 0.1};
      const double t = f.data.t[k];
      const Status refused[] = {
          with_bad.advance(t + 0.5, {u, 2}, {y_nan, 2}),          // an output not finite
          with_bad.advance(t, {u, 2}, {y, 2}),                    // time repeats
          with_bad.advance(t - 1.0, {u, 2}, {y, 2}),              // time goes backwards
          with_bad.advance(t + 0.5, {u, 1}, {y, 2}),              // one input short
          with_bad.advance(std::numeric_limits<double>::infinity(), {u, 2}, {y, 2}),
          with_bad.advance(1e308, {u, 2}, {y, 2}),                 // a step longer than the maximum
      };
      for (const Status& s : refused) EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << s.message();
      EXPECT_FALSE(with_bad.diverged());
    }
  }
  expect_same_estimate(with_bad, reference);
}

TEST_P(RunnerPerKind, ASnapshotRestoresTheRunBitForBit) {
  const TwoTank& f = two_tank();
  OnlineRunner original = f.runner(GetParam());
  for (Eigen::Index k = 0; k < 40; ++k) ASSERT_TRUE(f.advance(original, k).is_ok());
  OnlineRunner restored = f.runner(GetParam());
  ASSERT_TRUE(restored.restore(original.snapshot()).is_ok());
  for (Eigen::Index k = 40; k < 80; ++k) {
    ASSERT_TRUE(f.advance(original, k).is_ok());
    ASSERT_TRUE(f.advance(restored, k).is_ok());
  }
  expect_same_estimate(restored, original);
}

TEST_P(RunnerPerKind, ARestartedRunIsAFreshOne) {
  const TwoTank& f = two_tank();
  OnlineRunner used = f.runner(GetParam()), fresh = f.runner(GetParam());
  for (Eigen::Index k = 0; k < 30; ++k) ASSERT_TRUE(f.advance(used, k).is_ok());
  ASSERT_TRUE(used.restart(fresh.initial()).is_ok());
  EXPECT_FALSE(used.started());
  for (Eigen::Index k = 0; k < 30; ++k) {
    ASSERT_TRUE(f.advance(used, k).is_ok());
    ASSERT_TRUE(f.advance(fresh, k).is_ok());
  }
  expect_same_estimate(used, fresh);
}

TEST_P(RunnerPerKind, TheFirstPassOfAnIdentificationIsTheRunOverTheSamples) {
  const TwoTank& f = two_tank();
  OnlineRunner r = f.runner(GetParam());
  for (Eigen::Index k = 0; k < f.data.size(); ++k) ASSERT_TRUE(f.advance(r, k).is_ok());
  const auto one_pass = identify(f.model, f.data, testing::two_tank_hensen(GetParam(), 1));
  ASSERT_TRUE(one_pass.is_ok()) << one_pass.status().to_string();
  EXPECT_TRUE((one_pass.value().theta.array() == r.filter().state().tail(4).array()).all());
  EXPECT_TRUE((one_pass.value().covariance.array() == r.filter().covariance().array()).all());
}

INSTANTIATE_TEST_SUITE_P(EkfAndUkf, RunnerPerKind, ::testing::Values(FilterKind::kEkf, FilterKind::kUkf),
                         [](const auto& param) { return std::string(filter_kind_name(param.param)); });

TEST(OnlineRunner, ADivergenceSticksUntilARestart) {
  const TwoTank& f = two_tank();
  // A huge initial parameter variance with exact measurements (R tiny) sends
  // A1 negative: the model's sqrt then fails and the filter diverges.
  IdentificationSettings s = testing::two_tank_hensen();
  s.initial.theta0 = Eigen::Vector4d(1e-3, 20, 1, 1);
  s.initial.P0.diagonal() << 0, 0, 1e12, 10, 10, 10;
  s.filter.R = Eigen::Matrix2d::Identity() * 1e-12;
  auto r = OnlineRunner::create(f.model, s.filter, s.initial);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  Status first;
  Eigen::Index k = 0;
  for (; k < f.data.size() && first.is_ok(); ++k) first = f.advance(r.value(), k);
  ASSERT_FALSE(first.is_ok()) << "no divergence in " << k << " samples";
  EXPECT_NE(first.code(), StatusCode::kInvalidArgument) << first.message();
  EXPECT_TRUE(r->diverged());
  const Status again = f.advance(r.value(), k);
  EXPECT_EQ(again.code(), first.code());
  EXPECT_EQ(again.message(), first.message());
  ASSERT_TRUE(r->restart(testing::two_tank_hensen().initial).is_ok());
  EXPECT_FALSE(r->diverged());
  EXPECT_TRUE(f.advance(r.value(), 0).is_ok());
}

TEST(OnlineRunner, TheInitialEstimateIsCheckedAtCreation) {
  const TwoTank& f = two_tank();
  IdentificationSettings s = testing::two_tank_hensen();
  s.initial.mode = InitialState::kGiven;  // without x0
  auto r = OnlineRunner::create(f.model, s.filter, s.initial);
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().message().find("x0 is required (2 values: h1, h2)"), std::string::npos) << r.status().message();
  s = testing::two_tank_hensen();
  s.initial.P0(2, 2) = -1.0;
  r = OnlineRunner::create(f.model, s.filter, s.initial);
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().message().find("P0 has a negative variance"), std::string::npos) << r.status().message();
}

// The table of filter kinds: one row per kind, names unique and parsed back.
TEST(FilterKinds, EveryKindHasOneRowAndANameThatParsesBack) {
  std::set<std::string_view> names;
  for (FilterKind kind : {FilterKind::kEkf, FilterKind::kUkf, FilterKind::kOptimal}) {
    const FilterKindInfo& info = filter_kind_info(kind);
    EXPECT_EQ(info.kind, kind);
    EXPECT_TRUE(names.insert(info.name).second) << info.name;
    EXPECT_EQ(parse_filter_kind(info.name).value(), kind);
    EXPECT_FALSE(info.summary.empty());
  }
  EXPECT_EQ(filter_kinds().size(), names.size());
  const auto unknown = parse_filter_kind("kalman");
  ASSERT_FALSE(unknown.is_ok());
  EXPECT_NE(unknown.status().message().find("ekf, ukf or optimal"), std::string::npos) << unknown.status().message();
}

}  // namespace
}  // namespace riccati
