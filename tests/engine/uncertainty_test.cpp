// The covariance of least-squares estimates, white and robust to coloured
// residuals, against the truth of simulated regressions.
#include <gtest/gtest.h>

#include <cmath>
#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <limits>
#include <random>
#include <utility>
#include <vector>

#include "engine/estimation/estimate.hpp"
#include "engine/estimation/uncertainty.hpp"

namespace riccati {
namespace {

constexpr double kZ95 = 1.959963984540054;

// y_k = b0 + b1 sin(2 pi k / 500) + e_k with AR(1) noise e_k = phi e_k-1 +
// w_k of unit variance: the regressor is smooth, as a model's sensitivities
// are, so the scores J_k' e_k are as coloured as the noise. Over `runs`
// realisations, how often each 95 % interval holds the true b1: from the
// white covariance s2 (J'J)^-1 and from the sandwich with the long-run
// covariance of the scores.
struct Coverage {
  int white = 0, robust = 0, runs = 0;
  double mean_bandwidth = 0.0;
};

Coverage regression_coverage(double phi, int runs, std::uint64_t seed) {
  constexpr Eigen::Index n = 2000;
  const Eigen::Vector2d truth(1.0, 0.5);
  Eigen::MatrixXd J(n, 2);
  for (Eigen::Index k = 0; k < n; ++k) J.row(k) << 1.0, std::sin(2.0 * M_PI * static_cast<double>(k) / 500.0);
  const Eigen::MatrixXd information = J.transpose() * J;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  Coverage c;
  c.runs = runs;
  for (int run = 0; run < runs; ++run) {
    Eigen::VectorXd e(n);
    e[0] = normal(rng);  // stationary from the start: unit variance
    for (Eigen::Index k = 1; k < n; ++k) e[k] = phi * e[k - 1] + std::sqrt(1.0 - phi * phi) * normal(rng);
    const Eigen::VectorXd y = J * truth + e;
    const Eigen::Vector2d estimate = information.ldlt().solve(J.transpose() * y);
    const Eigen::VectorXd r = y - J * estimate;
    const double s2 = r.squaredNorm() / static_cast<double>(n - 2);
    const Uncertainty white = uncertainty_from_information(information, s2, {"b0", "b1"}, estimate);
    Eigen::MatrixXd scores(2, n);
    for (Eigen::Index k = 0; k < n; ++k) scores.col(k) = J.row(k).transpose() * r[k];
    const LongRunCovariance meat = long_run_covariance(scores);
    const Uncertainty robust = uncertainty_from_sandwich(information, meat.S, {"b0", "b1"}, estimate);
    c.white += std::abs(estimate[1] - truth[1]) <= kZ95 * white.std[1];
    c.robust += std::abs(estimate[1] - truth[1]) <= kZ95 * robust.std[1];
    c.mean_bandwidth += meat.bandwidth / runs;
  }
  return c;
}

// AR(1) noise with phi = 0.9: the white covariance's intervals are about
// sqrt((1 + phi) / (1 - phi)) = 4.4 times too narrow and hold the truth far
// less often than 95 %; the robust ones within the binomial range of 200
// runs at 95 % (90-99 %, as the targets).
TEST(LongRunCovariance, IntervalsHoldTheTruthUnderAutocorrelatedNoise) {
  const Coverage c = regression_coverage(0.9, 200, 20261128);
  std::printf("phi 0.9: white %d, robust %d of %d; mean bandwidth %.2f\n", c.white, c.robust, c.runs,
              c.mean_bandwidth);
  EXPECT_LT(c.white, 120);
  EXPECT_GE(c.robust, 180);
  EXPECT_LE(c.robust, 198);
}

// White noise: the robust intervals are not needlessly wide (they hold the
// truth at their level, as the white ones do), and the prewhitened
// bandwidth stays small.
TEST(LongRunCovariance, WhiteNoiseKeepsTheLevel) {
  const Coverage c = regression_coverage(0.0, 200, 20261129);
  std::printf("phi 0: white %d, robust %d of %d; mean bandwidth %.2f\n", c.white, c.robust, c.runs, c.mean_bandwidth);
  EXPECT_GE(c.white, 180);
  EXPECT_LE(c.white, 198);
  EXPECT_GE(c.robust, 180);
  EXPECT_LE(c.robust, 198);
  EXPECT_LT(c.mean_bandwidth, 5.0);
}

// The sandwich with the meat s2 I is the white covariance s2 I^-1.
TEST(LongRunCovariance, TheSandwichOfAWhiteMeatIsTheWhiteCovariance) {
  Eigen::Matrix3d information;
  information << 4, 1, 0.5, 1, 3, 0.2, 0.5, 0.2, 2;
  const Eigen::Vector3d values(1.0, -2.0, 0.5);
  const Uncertainty white = uncertainty_from_information(information, 0.3, {"a", "b", "c"}, values);
  const Uncertainty sandwich = uncertainty_from_sandwich(information, 0.3 * information, {"a", "b", "c"}, values);
  EXPECT_LT((white.covariance - sandwich.covariance).cwiseAbs().maxCoeff(), 1e-14);
  EXPECT_LT((white.covariance - 0.3 * information.inverse()).cwiseAbs().maxCoeff(), 1e-14);
}

// The chi-square upper tail compare's likelihood-ratio tests reads its p-value
// from, against the 95 % quantiles of the tables and a value by hand
// (P(chi2_1 > 1) = P(|Z| > 1)).
TEST(ChiSquare, SurvivalAtTheTablesQuantiles) {
  const std::vector<std::pair<unsigned, double>> quantile95 = {
      {1, 3.841458820694124}, {2, 5.991464547107979}, {3, 7.814727903251178}, {5, 11.070497693516351},
      {10, 18.307038053275146}};
  for (const auto& [dof, x] : quantile95) EXPECT_NEAR(chi_square_survival(x, dof), 0.05, 1e-12) << dof;
  EXPECT_NEAR(chi_square_survival(1.0, 1), 0.31731050786291410, 1e-14);
  EXPECT_EQ(chi_square_survival(0.0, 3), 1.0);
  EXPECT_EQ(chi_square_survival(std::numeric_limits<double>::infinity(), 2), 0.0);
}

}  // namespace
}  // namespace riccati
