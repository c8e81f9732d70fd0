#include "engine/estimation/fit_metrics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <initializer_list>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

namespace riccati {
namespace {

constexpr double kTol = 1e-12;

Eigen::MatrixXd row(std::initializer_list<double> values) {
  Eigen::MatrixXd m(1, static_cast<Eigen::Index>(values.size()));
  Eigen::Index j = 0;
  for (const double v : values) m(0, j++) = v;
  return m;
}

// Passes when `status` failed with `code` and its message contains every part.
testing::AssertionResult FailsWith(const Status& status, StatusCode code, std::initializer_list<std::string_view> parts) {
  if (status.is_ok()) return testing::AssertionFailure() << "succeeded; expected " << status_code_name(code);
  if (status.code() != code) return testing::AssertionFailure() << "wrong code: " << status.to_string();
  for (const std::string_view part : parts) {
    if (status.message().find(part) == std::string::npos) {
      return testing::AssertionFailure() << "message \"" << status.message() << "\" lacks \"" << part << "\"";
    }
  }
  return testing::AssertionSuccess();
}

TEST(CompareOutputs, HandComputedExample) {
  // y = [1 2 3 4], yhat = [1 2 3 5]: error e = y - yhat = [0 0 0 -1]
  //   sum e^2 = 1                  -> rmse = sqrt(1/4) = 0.5
  //   mean y = 2.5, sum (y - 2.5)^2 = 2.25 + 0.25 + 0.25 + 2.25 = 5
  //                                -> rrse = sqrt(1/5) = 0.447213595499958
  //                                -> fit = 100 (1 - 1/sqrt(5)) = 55.2786404500042
  //   mean e = -0.25, var e = (3 * 0.0625 + 0.5625) / 4 = 0.1875; var y = 5/4 = 1.25
  //                                -> vaf = 100 (1 - 0.1875/1.25) = 85
  const Result<std::vector<OutputFit>> fits = compare_outputs(row({1, 2, 3, 4}), row({1, 2, 3, 5}), {"h1"});
  ASSERT_TRUE(fits.is_ok()) << fits.status().to_string();
  ASSERT_EQ(fits->size(), 1u);
  const OutputFit& fit = fits->front();
  EXPECT_EQ(fit.name, "h1");
  EXPECT_NEAR(fit.rmse, 0.5, kTol);
  EXPECT_NEAR(fit.rrse, 0.447213595499958, kTol);
  EXPECT_NEAR(fit.fit_percent, 55.2786404500042, 1e-10);
  EXPECT_NEAR(fit.vaf_percent, 85.0, 1e-10);
}

TEST(CompareOutputs, ConstantOffsetHurtsFitButNotVaf) {
  // y = [0 1 0 -1], yhat = y + 0.5: e = -0.5 everywhere
  //   sum e^2 = 1 -> rmse = 0.5
  //   mean y = 0, sum y^2 = 2 -> rrse = sqrt(1/2) = 0.707106781186548, fit = 29.2893218813452
  //   var e = 0 -> vaf = 100: VAF cannot see an offset
  const Eigen::MatrixXd y = row({0, 1, 0, -1});
  const Eigen::MatrixXd yhat = (y.array() + 0.5).matrix();
  const Result<std::vector<OutputFit>> fits = compare_outputs(y, yhat, {"q"});
  ASSERT_TRUE(fits.is_ok()) << fits.status().to_string();
  const OutputFit& fit = fits->front();
  EXPECT_NEAR(fit.rmse, 0.5, kTol);
  EXPECT_NEAR(fit.rrse, 0.707106781186548, kTol);
  EXPECT_NEAR(fit.fit_percent, 29.2893218813452, 1e-10);
  EXPECT_NEAR(fit.vaf_percent, 100.0, 1e-10);
}

TEST(CompareOutputs, PerfectFitAndRowsAreIndependent) {
  // Row 1 is matched exactly; row 2 is the hand-computed example above.
  Eigen::MatrixXd measured(2, 4);
  measured << 0.3, -1.2, 7.5, 2.0,  //
      1, 2, 3, 4;
  Eigen::MatrixXd simulated = measured;
  simulated(1, 3) = 5;
  const Result<std::vector<OutputFit>> fits = compare_outputs(measured, simulated, {"h1", "h2"});
  ASSERT_TRUE(fits.is_ok()) << fits.status().to_string();
  ASSERT_EQ(fits->size(), 2u);
  EXPECT_EQ((*fits)[0].name, "h1");
  EXPECT_EQ((*fits)[0].rmse, 0.0);
  EXPECT_EQ((*fits)[0].rrse, 0.0);
  EXPECT_EQ((*fits)[0].fit_percent, 100.0);
  EXPECT_EQ((*fits)[0].vaf_percent, 100.0);
  EXPECT_EQ((*fits)[1].name, "h2");
  EXPECT_NEAR((*fits)[1].rmse, 0.5, kTol);
  EXPECT_NEAR((*fits)[1].vaf_percent, 85.0, 1e-10);
}

TEST(CompareOutputs, ConstantMeasuredOutputHasUndefinedRelativeMetrics) {
  // y = [2 2 2], yhat = [2 3 2]: rmse = sqrt(1/3); fit, VAF and RRSE divide by
  // the spread of y, which is zero, so they are NaN.
  const Result<std::vector<OutputFit>> fits = compare_outputs(row({2, 2, 2}), row({2, 3, 2}), {"h1"});
  ASSERT_TRUE(fits.is_ok()) << fits.status().to_string();
  EXPECT_NEAR(fits->front().rmse, std::sqrt(1.0 / 3.0), kTol);
  EXPECT_TRUE(std::isnan(fits->front().fit_percent));
  EXPECT_TRUE(std::isnan(fits->front().vaf_percent));
  EXPECT_TRUE(std::isnan(fits->front().rrse));
}

TEST(CompareOutputs, ConstantOutputWithRoundingInItsMeanIsStillConstant) {
  // The computed mean of [0.1 0.1 0.1] is not exactly 0.1; a naive
  // ||y - mean(y)|| would be tiny but nonzero and the fit hugely negative.
  const Result<std::vector<OutputFit>> fits = compare_outputs(row({0.1, 0.1, 0.1}), row({0.1, 0.2, 0.1}), {"h1"});
  ASSERT_TRUE(fits.is_ok()) << fits.status().to_string();
  EXPECT_TRUE(std::isnan(fits->front().fit_percent));
  EXPECT_TRUE(std::isnan(fits->front().rrse));
}

TEST(CompareOutputs, MismatchedSizes) {
  EXPECT_TRUE(FailsWith(compare_outputs(row({1, 2, 3}), row({1, 2}), {"h1"}).status(), StatusCode::kInvalidArgument,
                        {"1 x 3", "1 x 2"}));
  EXPECT_TRUE(FailsWith(compare_outputs(Eigen::MatrixXd::Zero(2, 3), row({1, 2, 3}), {"h1", "h2"}).status(),
                        StatusCode::kInvalidArgument, {"2 x 3", "1 x 3"}));
  EXPECT_TRUE(FailsWith(compare_outputs(row({1, 2}), row({1, 2}), {"h1", "h2"}).status(), StatusCode::kInvalidArgument,
                        {"2 output names for 1 outputs"}));
  EXPECT_TRUE(FailsWith(compare_outputs(Eigen::MatrixXd(1, 0), Eigen::MatrixXd(1, 0), {"h1"}).status(),
                        StatusCode::kInvalidArgument, {"no samples"}));
}

TEST(CompareOutputs, NonFiniteValues) {
  Eigen::MatrixXd measured = Eigen::MatrixXd::Ones(2, 4);
  Eigen::MatrixXd simulated = measured;
  simulated(1, 2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_TRUE(FailsWith(compare_outputs(measured, simulated, {"h1", "h2"}).status(), StatusCode::kInvalidArgument,
                        {"simulated output \"h2\" is NaN at sample 3"}));
  measured(0, 1) = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(FailsWith(compare_outputs(measured, simulated, {"h1", "h2"}).status(), StatusCode::kInvalidArgument,
                        {"measured output \"h1\" is infinite at sample 2"}));
}

}  // namespace
}  // namespace riccati
