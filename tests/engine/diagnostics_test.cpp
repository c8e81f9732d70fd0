// Residual diagnostics against references that do not use the code under
// test: printed chi-square tables and closed-form chi-square CDFs, examples
// computed by hand, and the known distribution of each statistic under white
// noise, counted over many seeds.
#include "engine/estimation/diagnostics.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <initializer_list>
#include <limits>
#include <numbers>
#include <random>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace riccati {
namespace {

using Eigen::Index;

constexpr double kTol = 1e-12;

Eigen::MatrixXd row(std::initializer_list<double> values) {
  Eigen::MatrixXd m(1, static_cast<Index>(values.size()));
  Index j = 0;
  for (const double v : values) m(0, j++) = v;
  return m;
}

Eigen::MatrixXd gaussian(Index rows, Index cols, std::mt19937_64& rng) {
  std::normal_distribution<double> normal;
  Eigen::MatrixXd m(rows, cols);
  for (Index k = 0; k < cols; ++k) {
    for (Index i = 0; i < rows; ++i) m(i, k) = normal(rng);
  }
  return m;
}

// x_t = phi x_{t-1} + w_t with w standard normal, after 200 samples of warm-up.
Eigen::MatrixXd ar1(double phi, Index cols, std::mt19937_64& rng) {
  std::normal_distribution<double> normal;
  double x = 0.0;
  for (int k = 0; k < 200; ++k) x = phi * x + normal(rng);
  Eigen::MatrixXd m(1, cols);
  for (Index k = 0; k < cols; ++k) m(0, k) = x = phi * x + normal(rng);
  return m;
}

// Passes when `status` failed with `code` and its message contains every part.
testing::AssertionResult FailsWith(const Status& status, StatusCode code,
                                   std::initializer_list<std::string_view> parts) {
  if (status.is_ok()) return testing::AssertionFailure() << "succeeded; expected " << status_code_name(code);
  if (status.code() != code) return testing::AssertionFailure() << "wrong code: " << status.to_string();
  for (const std::string_view part : parts) {
    if (status.message().find(part) == std::string::npos) {
      return testing::AssertionFailure() << "message \"" << status.message() << "\" lacks \"" << part << "\"";
    }
  }
  return testing::AssertionSuccess();
}

// Every number a diagnosis holds is finite.
testing::AssertionResult AllFinite(const ResidualDiagnostics& d) {
  if (!d.autocorrelation.allFinite()) return testing::AssertionFailure() << "autocorrelation " << d.autocorrelation;
  if (!d.ljung_box.allFinite()) return testing::AssertionFailure() << "ljung_box " << d.ljung_box.transpose();
  if (!d.cross_correlation.allFinite()) return testing::AssertionFailure() << "cross " << d.cross_correlation;
  if (!d.cross_statistic.allFinite()) return testing::AssertionFailure() << "S " << d.cross_statistic.transpose();
  if (!d.cross_limit.allFinite()) return testing::AssertionFailure() << "limit " << d.cross_limit.transpose();
  if (!std::isfinite(d.band) || !std::isfinite(d.ljung_box_limit)) return testing::AssertionFailure() << "band/limit";
  return testing::AssertionSuccess();
}

// The closed-form chi-square CDF, independent of Boost:
//   k = 1: erf(sqrt(x/2));  k = 3: erf(sqrt(x/2)) - sqrt(2x/pi) e^(-x/2);
//   k = 2m: 1 - e^(-x/2) sum_{i<m} (x/2)^i / i!  (the Poisson tail, terms in logs so large m is fine).
double chi_square_cdf(double x, int k) {
  if (k == 1) return std::erf(std::sqrt(x / 2));
  if (k == 3) return std::erf(std::sqrt(x / 2)) - std::sqrt(2 * x / std::numbers::pi) * std::exp(-x / 2);
  double upper = 0.0;
  for (int i = 0; i < k / 2; ++i) upper += std::exp(i * std::log(x / 2) - std::lgamma(i + 1.0) - x / 2);
  return 1.0 - upper;
}

// The closed-form upper tail P(X >= x), X chi-square(k), independent of
// Boost: Q_1 = erfc(sqrt(x/2)), Q_2 = e^(-x/2), and
// Q_{k+2} = Q_k + (x/2)^(k/2) e^(-x/2) / Gamma(k/2 + 1) (terms in logs).
// Accurate in relative terms where the tail is small (no 1 - CDF).
double chi_square_upper(double x, int k) {
  double q = k % 2 == 1 ? std::erfc(std::sqrt(x / 2)) : std::exp(-x / 2);
  for (int j = 2 - k % 2; j < k; j += 2) {
    const double half = j / 2.0;
    q += std::exp(half * std::log(x / 2) - x / 2 - std::lgamma(half + 1.0));
  }
  return q;
}

// The exact two-sided interval [lo, hi] of a Binomial(n, p) count: it falls
// below lo, or above hi, each with probability at most alpha / 2.
std::pair<int, int> binomial_interval(int n, double p, double alpha) {
  double cdf = 0.0;
  int lo = -1;
  for (int k = 0; k <= n; ++k) {
    cdf += std::exp(std::lgamma(n + 1.0) - std::lgamma(k + 1.0) - std::lgamma(n - k + 1.0) + k * std::log(p) +
                    (n - k) * std::log1p(-p));
    if (lo < 0 && cdf > alpha / 2) lo = k;
    if (cdf >= 1 - alpha / 2) return {lo, k};
  }
  return {lo, n};
}

// The counts over seeds are held to 99.9 % binomial intervals rather than
// 95 % ones: the seeds are fixed, so each check passes or fails for good, and
// with five checks at 95 % a correct implementation would fail one for about
// a fifth of all choices of seeds (the seeds would then be chosen, not the
// code checked). 1000 seeds keep the intervals narrow enough to catch a
// wrong level: at 5 %, [29, 74] rejections, where a test at 10 % gives ~100.
constexpr int kSeeds = 1000;
constexpr double kAlpha = 0.001;
constexpr Index kN = 2000;

TEST(ChiSquareQuantile, PrintedTableValues) {
  // Printed tables give three decimals: each value is within 5e-4 of the truth.
  struct Row {
    double p, dof, value;
  };
  for (const Row& r : {Row{0.95, 1, 3.841}, Row{0.975, 1, 5.024}, Row{0.95, 2, 5.991}, Row{0.95, 3, 7.815},
                       Row{0.05, 5, 1.145}, Row{0.95, 10, 18.307}, Row{0.95, 20, 31.410}, Row{0.95, 21, 32.671},
                       Row{0.025, 100, 74.222}, Row{0.95, 100, 124.342}, Row{0.975, 100, 129.561}}) {
    EXPECT_NEAR(chi_square_quantile(r.p, r.dof), r.value, 5e-4 + 1e-9) << "chi2(" << r.dof << ") at " << r.p;
  }
}

TEST(ChiSquareQuantile, InvertsTheClosedFormCdf) {
  // CDF(quantile(p)) = p, with the CDF from its closed form. 1e-10 in p
  // covers the rounding of the 2000 terms of the k = 4000 sum.
  for (const int dof : {1, 2, 3, 4, 10, 40, 400, 4000}) {
    for (const double p : {0.001, 0.025, 0.05, 0.5, 0.95, 0.975, 0.999}) {
      const double q = chi_square_quantile(p, dof);
      EXPECT_NEAR(chi_square_cdf(q, dof), p, 1e-10) << "chi2(" << dof << ") at " << p << ": " << q;
    }
  }
}

TEST(ChiSquareQuantile, EdgesNeverThrow) {
  EXPECT_EQ(chi_square_quantile(0.0, 3), 0.0);
  EXPECT_EQ(chi_square_quantile(1.0, 3), std::numeric_limits<double>::infinity());
  EXPECT_TRUE(std::isnan(chi_square_quantile(-0.1, 3)));
  EXPECT_TRUE(std::isnan(chi_square_quantile(1.1, 3)));
  EXPECT_TRUE(std::isnan(chi_square_quantile(0.5, 0)));
  EXPECT_TRUE(std::isnan(chi_square_quantile(0.5, -2)));
  EXPECT_TRUE(std::isnan(chi_square_quantile(std::nan(""), 3)));
  EXPECT_TRUE(std::isnan(chi_square_quantile(0.5, std::numeric_limits<double>::infinity())));
}

TEST(ChiSquarePValue, ClosedFormTails) {
  // Against the closed form above, across both sides of the mode and far in
  // the tail (relative accuracy: the complement is computed directly).
  for (const int dof : {1, 2, 3, 4, 7, 20, 21, 41, 400}) {
    for (const double x : {0.01, 0.5, 1.0, 3.0, 10.0, 25.0, 60.0, 200.0, 600.0}) {
      const double expected = chi_square_upper(x, dof);
      EXPECT_NEAR(chi_square_p_value(x, dof), expected, 1e-12 * expected + 1e-300) << "chi2(" << dof << ") at " << x;
    }
  }
  // Printed table values: the 95 % points have p = 0.05, to their three
  // decimals' 5e-4 times the density there (under 0.03: 1.5e-5).
  EXPECT_NEAR(chi_square_p_value(31.410, 20), 0.05, 1.5e-5);
  EXPECT_NEAR(chi_square_p_value(32.671, 21), 0.05, 1.5e-5);
  EXPECT_NEAR(chi_square_p_value(3.841, 1), 0.05, 1.5e-5);
  // The inverse of the quantile.
  EXPECT_NEAR(chi_square_p_value(chi_square_quantile(0.95, 13), 13), 0.05, 1e-14);
  // chi2(2) is exponential: p = e^(-x/2) exactly, far into the tail.
  EXPECT_NEAR(chi_square_p_value(100.0, 2) / std::exp(-50.0), 1.0, 1e-13);
}

TEST(ChiSquarePValue, EdgesNeverThrow) {
  EXPECT_EQ(chi_square_p_value(0.0, 3), 1.0);
  EXPECT_EQ(chi_square_p_value(-1.0, 3), 1.0);
  EXPECT_EQ(chi_square_p_value(std::numeric_limits<double>::infinity(), 3), 0.0);
  EXPECT_TRUE(std::isnan(chi_square_p_value(std::nan(""), 3)));
  EXPECT_TRUE(std::isnan(chi_square_p_value(1.0, 0)));
  EXPECT_TRUE(std::isnan(chi_square_p_value(1.0, -2)));
  EXPECT_TRUE(std::isnan(chi_square_p_value(1.0, std::numeric_limits<double>::infinity())));
}

TEST(DiagnoseResiduals, EachTestCarriesItsPValueAndDegreesOfFreedom) {
  // Two outputs (one white, one AR(1)), two inputs (one varying, one
  // constant), a NIS: every p-value against the closed form at the test's
  // degrees of freedom.
  std::mt19937_64 rng(11);
  constexpr Index n = 400;
  Eigen::MatrixXd residuals(2, n);
  residuals.row(0) = gaussian(1, n, rng);
  residuals.row(1) = ar1(0.5, n, rng);
  Eigen::MatrixXd inputs(2, n);
  inputs.row(0) = gaussian(1, n, rng);
  inputs.row(1).setConstant(3.0);
  const Eigen::VectorXd nis = residuals.colwise().squaredNorm().transpose();
  const Result<ResidualDiagnostics> d = diagnose_residuals(residuals, inputs, &nis);
  ASSERT_TRUE(d.is_ok()) << d.status().to_string();
  ASSERT_EQ(d->lags, 20);
  ASSERT_EQ(d->ljung_box_p.size(), 2);
  for (Index i = 0; i < 2; ++i) {
    const double expected = chi_square_upper(d->ljung_box(i), 20);
    EXPECT_NEAR(d->ljung_box_p(i), expected, 1e-12 * expected + 1e-300) << "output " << i;
    EXPECT_EQ(d->ljung_box_p(i) < 0.05, d->ljung_box(i) > d->ljung_box_limit) << "output " << i;
  }
  EXPECT_LT(d->ljung_box_p(1), 1e-10);  // AR(1) with phi = 0.5 at N = 400: far from white
  // Pairs (output i, input j) at row i * nu + j: the varying input has h + 1
  // = 21 degrees of freedom, the constant one 0 and p = 1 (not tested).
  ASSERT_EQ(d->cross_p.size(), 4);
  for (Index i = 0; i < 2; ++i) {
    const Index varying = i * 2, constant = i * 2 + 1;
    EXPECT_EQ(d->cross_dof(varying), 21);
    const double expected = chi_square_upper(d->cross_statistic(varying), 21);
    EXPECT_NEAR(d->cross_p(varying), expected, 1e-12 * expected + 1e-300) << "output " << i;
    EXPECT_EQ(d->cross_dof(constant), 0);
    EXPECT_EQ(d->cross_p(constant), 1.0);
  }
  // N times the mean NIS against chi2(N ny), two-sided.
  EXPECT_EQ(d->nis_dof, 2.0 * n);
  const double upper = chi_square_upper(n * d->nis_mean, 2 * n);
  EXPECT_NEAR(d->nis_p, 2.0 * std::min(upper, 1.0 - upper), 1e-10);
  EXPECT_EQ(d->nis_p < 0.05, !d->nis_consistent());

  // No NIS: its p-value is NaN and its dof 0.
  const Result<ResidualDiagnostics> oe = diagnose_residuals(residuals, inputs);
  ASSERT_TRUE(oe.is_ok());
  EXPECT_TRUE(std::isnan(oe->nis_p));
  EXPECT_EQ(oe->nis_dof, 0.0);
}

TEST(DiagnoseResiduals, HandComputedRamp) {
  // e = 1..10: N = 10, h = min(20, 10/4) = 2, mean 5.5, d = e - 5.5 = -4.5..4.5
  //   sum d^2 = 2 (4.5^2 + 3.5^2 + 2.5^2 + 1.5^2 + 0.5^2) = 82.5
  //   lag 1: sum d_t d_{t+1} = 15.75 + 8.75 + 3.75 + 0.75 - 0.25 + 0.75 + 3.75 + 8.75 + 15.75 = 57.75
  //          rho(1) = 57.75 / 82.5 = 0.7
  //   lag 2: sum d_t d_{t+2} = 11.25 + 5.25 + 1.25 - 0.75 - 0.75 + 1.25 + 5.25 + 11.25 = 34
  //          rho(2) = 34 / 82.5 = 68 / 165 = 0.41212..
  //   Q = 10 * 12 (0.7^2 / 9 + (68/165)^2 / 8) = 6.5333.. + 2.5477.. = 9.0810..
  //   chi2(2) 95 % = 5.991 < Q: not white
  const Result<ResidualDiagnostics> d = diagnose_residuals(row({1, 2, 3, 4, 5, 6, 7, 8, 9, 10}), Eigen::MatrixXd());
  ASSERT_TRUE(d.is_ok()) << d.status().to_string();
  EXPECT_EQ(d->samples, 10);
  EXPECT_EQ(d->lags, 2);
  EXPECT_NEAR(d->band, 1.96 / std::sqrt(10.0), kTol);
  ASSERT_EQ(d->autocorrelation.rows(), 1);
  ASSERT_EQ(d->autocorrelation.cols(), 2);
  EXPECT_NEAR(d->autocorrelation(0, 0), 0.7, kTol);
  EXPECT_NEAR(d->autocorrelation(0, 1), 68.0 / 165.0, kTol);
  EXPECT_NEAR(d->ljung_box(0), 120.0 * (0.49 / 9 + (68.0 / 165.0) * (68.0 / 165.0) / 8), kTol);
  EXPECT_NEAR(d->ljung_box_limit, 5.991, 5e-4);
  // chi2(2) is exponential: p = e^(-Q/2) = 0.0107
  EXPECT_NEAR(d->ljung_box_p(0), std::exp(-60.0 * (0.49 / 9 + (68.0 / 165.0) * (68.0 / 165.0) / 8)), 1e-14);
  EXPECT_FALSE(d->white());
  EXPECT_EQ(d->non_white_outputs(), std::vector<Index>{0});
  EXPECT_EQ(d->cross_correlation.rows(), 0);
  EXPECT_TRUE(d->uncorrelated_with_inputs());
}

TEST(DiagnoseResiduals, MeanIsRemovedAndScaleDoesNotMatter) {
  // e = 5 + (1, -1, 1, ...): d = (1, -1, ...), sum d^2 = 10, lag 1: -9, lag 2: 8
  //   rho = (-0.9, 0.8); Q = 120 (0.81 / 9 + 0.64 / 8) = 120 * 0.17 = 20.4
  // Without the mean removed rho(1) would be 9 * 24 / (5 * 36 + 5 * 16) = 0.83.
  const Eigen::MatrixXd alternating = row({6, 4, 6, 4, 6, 4, 6, 4, 6, 4});
  for (const double scale : {1.0, 1e-300, 1e300, -3.0}) {
    const Result<ResidualDiagnostics> d = diagnose_residuals(scale * alternating, Eigen::MatrixXd());
    ASSERT_TRUE(d.is_ok()) << d.status().to_string();
    EXPECT_NEAR(d->autocorrelation(0, 0), -0.9, kTol) << scale;
    EXPECT_NEAR(d->autocorrelation(0, 1), 0.8, kTol) << scale;
    EXPECT_NEAR(d->ljung_box(0), 20.4, 1e-11) << scale;
  }
}

TEST(DiagnoseResiduals, HandComputedCrossCorrelation) {
  // e = 1..10 (d = e - 5.5, sum d^2 = 82.5); u = (1, -1, 0, ..., 0): mean 0, sum u^2 = 2.
  // r(tau) = sum_s d_s u_{s - tau} / sqrt(82.5 * 2), sqrt(165):
  //   tau =  0: d_1 - d_2 = -4.5 + 3.5 = -1;  tau = 1: d_2 - d_3 = -1;  tau = 2: d_3 - d_4 = -1
  //   tau = -1: d_1 u_2 = 4.5;                tau = -2: no overlap with u's nonzero samples: 0
  // S = N R^2 of d on the input at lags 0..2. Those three columns are
  // (1, -1, 0, 0, ...), (0, 1, -1, 0, ...), (0, 0, 1, -1, ...): they span the
  // vectors on samples 1..4 that sum to zero, so the fit is d_1..4 less its
  // mean -3: (-1.5, -0.5, 0.5, 1.5), squares 5. S = 10 * 5 / 82.5 = 20 / 33.
  const Result<ResidualDiagnostics> d =
      diagnose_residuals(row({1, 2, 3, 4, 5, 6, 7, 8, 9, 10}), row({1, -1, 0, 0, 0, 0, 0, 0, 0, 0}));
  ASSERT_TRUE(d.is_ok()) << d.status().to_string();
  ASSERT_EQ(d->cross_correlation.rows(), 1);
  ASSERT_EQ(d->cross_correlation.cols(), 5);
  const double s = std::sqrt(165.0);
  const double expected[] = {0.0, 4.5 / s, -1 / s, -1 / s, -1 / s};  // lags -2..2
  for (int c = 0; c < 5; ++c) EXPECT_NEAR(d->cross_correlation(0, c), expected[c], kTol) << "lag " << c - 2;
  EXPECT_NEAR(d->cross_statistic(0), 20.0 / 33.0, 1e-10);
  EXPECT_EQ(d->cross_dof(0), 3);
  EXPECT_NEAR(d->cross_limit(0), 7.815, 5e-4);
  EXPECT_TRUE(d->uncorrelated_with_inputs());
}

TEST(DiagnoseResiduals, WhiteNoiseAgainstAnInputCorrelatedWithItselfPassesAtTheLevel) {
  // Two white residuals and an AR(1) input (phi = 0.9, far from white), N =
  // 2000, h = 20, per seed. Under this null every statistic has a known law:
  //   each rho(tau) is within the band with probability 95 % (asymptotically
  //   independent across lags: Bartlett), each Q and S exceeds its limit with
  //   probability 5 %, and the mean NIS of standard normal residuals (NIS =
  //   |e_k|^2, chi2(2)) is inside its band with probability 95 %.
  // The sum of squares N sum r(tau)^2 over lags 0..h against chi2(h + 1), the
  // statistic this module does not use, rejects far more often here: with
  // the input correlated with itself the lags' cross-correlations are too.
  // The band's rate is not quite 95 %: for white noise var rho(tau) =
  // (N - tau) / (N (N + 2)) (what Ljung-Box's weights undo), a little under
  // 1 / N, so each lag is inside with probability erf(1.96 / sqrt(2 N var)),
  // 95.07 % on average over these lags.
  double band_rate = 0.0;
  for (int tau = 1; tau <= 20; ++tau) {
    band_rate += std::erf(1.96 / std::sqrt(2.0 * (kN - tau) / (kN + 2.0))) / 20;
  }
  int inside_band = 0, lb_rejections = 0, cross_rejections = 0, naive_rejections = 0, nis_inside = 0;
  const double naive_limit = chi_square_quantile(0.95, 21);
  for (int seed = 0; seed < kSeeds; ++seed) {
    std::mt19937_64 rng(static_cast<std::uint64_t>(seed));
    const Eigen::MatrixXd residuals = gaussian(2, kN, rng);
    const Eigen::MatrixXd input = ar1(0.9, kN, rng);
    const Eigen::VectorXd nis = residuals.colwise().squaredNorm().transpose();
    const Result<ResidualDiagnostics> d = diagnose_residuals(residuals, input, &nis);
    ASSERT_TRUE(d.is_ok()) << d.status().to_string();
    ASSERT_EQ(d->lags, 20);
    ASSERT_TRUE(AllFinite(*d));
    inside_band += static_cast<int>((d->autocorrelation.array().abs() <= d->band).count());
    lb_rejections += static_cast<int>(d->non_white_outputs().size());
    cross_rejections += static_cast<int>(d->input_correlated_pairs().size());
    for (Index i = 0; i < 2; ++i) {
      const double naive = kN * d->cross_correlation.row(i).tail(21).squaredNorm();
      naive_rejections += naive > naive_limit ? 1 : 0;
      EXPECT_EQ(d->cross_dof(i), 21);
    }
    nis_inside += d->nis_consistent() ? 1 : 0;
  }
  const auto [band_lo, band_hi] = binomial_interval(kSeeds * 2 * 20, band_rate, kAlpha);
  EXPECT_GE(inside_band, band_lo);
  EXPECT_LE(inside_band, band_hi);
  const auto [test_lo, test_hi] = binomial_interval(kSeeds * 2, 0.05, kAlpha);
  EXPECT_GE(lb_rejections, test_lo);
  EXPECT_LE(lb_rejections, test_hi);
  EXPECT_GE(cross_rejections, test_lo);
  EXPECT_LE(cross_rejections, test_hi);
  EXPECT_GT(naive_rejections, test_hi);
  const auto [nis_lo, nis_hi] = binomial_interval(kSeeds, 0.95, kAlpha);
  EXPECT_GE(nis_inside, nis_lo);
  EXPECT_LE(nis_inside, nis_hi);
  std::printf(
      "over %d seeds: %d of %d autocorrelations inside the band [%d, %d]; Ljung-Box rejects %d, the "
      "cross test %d of %d [%d, %d]; N sum r^2 would reject %d; mean NIS inside its band %d [%d, %d]\n",
      kSeeds, inside_band, kSeeds * 40, band_lo, band_hi, lb_rejections, cross_rejections, kSeeds * 2, test_lo, test_hi,
      naive_rejections, nis_inside, nis_lo, nis_hi);
}

TEST(DiagnoseResiduals, Ar1ResidualIsNeverWhite) {
  // e_t = 0.5 e_{t-1} + w_t: rho(1) = 0.5, so Q is about N rho(1)^2 = 500
  // against a limit of 31.4 (more than 15 standard deviations of Q).
  for (int seed = 0; seed < 200; ++seed) {
    std::mt19937_64 rng(static_cast<std::uint64_t>(seed));
    const Result<ResidualDiagnostics> d = diagnose_residuals(ar1(0.5, kN, rng), Eigen::MatrixXd());
    ASSERT_TRUE(d.is_ok()) << d.status().to_string();
    EXPECT_FALSE(d->white()) << "seed " << seed << ": Q = " << d->ljung_box(0);
    EXPECT_NEAR(d->autocorrelation(0, 0), 0.5, 5 * std::sqrt((1 - 0.25) / kN)) << "seed " << seed;
  }
}

TEST(DiagnoseResiduals, ResidualThatIsThePastInputIsCaught) {
  // The residual is the input 3 samples earlier (a white input: the residual
  // is white too, so only the cross test can see it). r(3) = 1 - 3/N or so,
  // and S is about N r(3)^2 = 2000 against 32.7.
  for (int seed = 0; seed < 200; ++seed) {
    std::mt19937_64 rng(static_cast<std::uint64_t>(seed));
    const Eigen::MatrixXd u = gaussian(1, kN + 3, rng);
    const Eigen::MatrixXd input = u.rightCols(kN);
    const Eigen::MatrixXd residual = u.leftCols(kN);  // residual_t = input_{t-3}
    const Result<ResidualDiagnostics> d = diagnose_residuals(residual, input);
    ASSERT_TRUE(d.is_ok()) << d.status().to_string();
    EXPECT_GT(d->cross_correlation(0, d->lags + 3), 0.99) << "seed " << seed;
    EXPECT_FALSE(d->uncorrelated_with_inputs()) << "seed " << seed << ": S = " << d->cross_statistic(0);
    EXPECT_EQ(d->input_correlated_pairs(), (std::vector<std::pair<Index, Index>>{{0, 0}}));
  }
}

TEST(DiagnoseResiduals, ResidualThatIsTheFutureInputIsFeedbackNotAFailure) {
  // The input is the residual 3 samples later, as a controller acting on the
  // residual makes it: r(-3) is about 1 and shows it, but the test is of
  // lags 0..h, where the residual and a white input are independent, so it
  // rejects at its level (5 %), not always.
  int rejections = 0;
  for (int seed = 0; seed < kSeeds; ++seed) {
    std::mt19937_64 rng(static_cast<std::uint64_t>(seed));
    const Eigen::MatrixXd u = gaussian(1, kN + 3, rng);
    const Result<ResidualDiagnostics> d = diagnose_residuals(u.rightCols(kN), u.leftCols(kN));
    ASSERT_TRUE(d.is_ok()) << d.status().to_string();
    ASSERT_GT(d->cross_correlation(0, d->lags - 3), 0.99) << "seed " << seed;
    rejections += d->uncorrelated_with_inputs() ? 0 : 1;
  }
  const auto [lo, hi] = binomial_interval(kSeeds, 0.05, kAlpha);
  EXPECT_GE(rejections, lo);
  EXPECT_LE(rejections, hi);
}

TEST(DiagnoseResiduals, TwoOutputsTwoInputsArePairedByRow) {
  // Row i * nu + j is output i against input j: output 1 is input 0 two
  // samples earlier, output 0 is noise. S of the pair (1, 0) is about N; the
  // others are chi2(21) and exceed 100 with probability 1e-11.
  std::mt19937_64 rng(7);
  const Eigen::MatrixXd u = gaussian(2, kN + 2, rng);
  Eigen::MatrixXd residuals(2, kN);
  residuals.row(0) = gaussian(1, kN, rng);
  residuals.row(1) = u.row(0).leftCols(kN);
  const Eigen::MatrixXd inputs = u.rightCols(kN);
  const Result<ResidualDiagnostics> d = diagnose_residuals(residuals, inputs);
  ASSERT_TRUE(d.is_ok()) << d.status().to_string();
  ASSERT_EQ(d->cross_correlation.rows(), 4);
  ASSERT_EQ(d->cross_correlation.cols(), 41);
  EXPECT_GT(d->cross_correlation(1 * 2 + 0, 20 + 2), 0.99);
  EXPECT_GT(d->cross_statistic(1 * 2 + 0), 1000.0);
  for (const Index pair : {0, 1, 3}) EXPECT_LT(d->cross_statistic(pair), 100.0) << pair;
  const std::vector<std::pair<Index, Index>> failing = d->input_correlated_pairs();
  EXPECT_NE(std::find(failing.begin(), failing.end(), std::pair<Index, Index>{1, 0}), failing.end());
}

TEST(DiagnoseResiduals, ConstantResidualsAndInputsHaveNoCorrelation) {
  // Output 0 is constant (an exact fit), with a mean that does not round
  // exactly (0.1); output 1 is noise. Input 0 is constant, input 1 noise.
  // Documented: a constant series' correlations are 0, its Q and S are 0 and
  // its tests pass; the constant flags say which.
  std::mt19937_64 rng(11);
  Eigen::MatrixXd residuals(2, 100);
  residuals.row(0).setConstant(0.1);
  residuals.row(1) = gaussian(1, 100, rng);
  Eigen::MatrixXd inputs(2, 100);
  inputs.row(0).setConstant(-4.0);
  inputs.row(1) = gaussian(1, 100, rng);
  const Result<ResidualDiagnostics> d = diagnose_residuals(residuals, inputs);
  ASSERT_TRUE(d.is_ok()) << d.status().to_string();
  EXPECT_TRUE(AllFinite(*d));
  EXPECT_TRUE(d->constant_residual(0));
  EXPECT_FALSE(d->constant_residual(1));
  EXPECT_TRUE(d->constant_input(0));
  EXPECT_FALSE(d->constant_input(1));
  EXPECT_TRUE(d->autocorrelation.row(0).isZero(0.0));
  EXPECT_EQ(d->ljung_box(0), 0.0);
  for (const Index pair : {0, 1, 2}) {  // (0, 0), (0, 1), (1, 0): a constant in each
    EXPECT_TRUE(d->cross_correlation.row(pair).isZero(0.0)) << pair;
    EXPECT_EQ(d->cross_statistic(pair), 0.0) << pair;
  }
  EXPECT_EQ(d->cross_dof(0), 0);  // a constant input: nothing to regress on
  EXPECT_EQ(d->cross_limit(0), 0.0);
  EXPECT_EQ(d->cross_dof(1), 21);  // h = min(20, 100 / 4) = 20: lags 0..20
  // Only the two noise series may fail (each at 5 %), never a constant.
  for (const Index i : d->non_white_outputs()) EXPECT_EQ(i, 1);
  for (const auto& [i, j] : d->input_correlated_pairs()) EXPECT_TRUE(i == 1 && j == 1) << i << ", " << j;
  EXPECT_NE(d->summary().find("output 1 Q = 0 (constant residual"), std::string::npos) << d->summary();
  EXPECT_NE(d->summary().find("output 1/input 1 S = 0 (constant input"), std::string::npos) << d->summary();

  // All residuals zero and no inputs: everything passes.
  const Result<ResidualDiagnostics> zero = diagnose_residuals(Eigen::MatrixXd::Zero(3, 50), Eigen::MatrixXd(0, 50));
  ASSERT_TRUE(zero.is_ok()) << zero.status().to_string();
  EXPECT_TRUE(AllFinite(*zero));
  EXPECT_TRUE(zero->constant_residual.all());
  EXPECT_TRUE(zero->white());
  EXPECT_TRUE(zero->uncorrelated_with_inputs());
}

TEST(DiagnoseResiduals, MeanNisAndItsBand) {
  // NIS (1, 2, ..., 8) over N = 8 samples of ny = 1 output: mean 4.5; band
  // chi2(8) 2.5 % and 97.5 % (2.180, 17.535) over 8 = (0.2725, 2.192): 4.5 is
  // outside. Halving the NIS (0.5..4, mean 2.25) is still outside; dividing
  // by 4 (mean 1.125) is inside.
  const Eigen::MatrixXd residuals = row({1, -2, 3, -1, 2, -3, 1, -2});
  Eigen::VectorXd nis(8);
  nis << 1, 2, 3, 4, 5, 6, 7, 8;
  Result<ResidualDiagnostics> d = diagnose_residuals(residuals, Eigen::MatrixXd(), &nis);
  ASSERT_TRUE(d.is_ok()) << d.status().to_string();
  EXPECT_NEAR(d->nis_mean, 4.5, kTol);
  EXPECT_NEAR(d->nis_lower, 2.180 / 8, 5e-4 / 8);
  EXPECT_NEAR(d->nis_upper, 17.535 / 8, 5e-4 / 8);
  EXPECT_FALSE(d->nis_consistent());
  nis /= 2;
  d = diagnose_residuals(residuals, Eigen::MatrixXd(), &nis);
  ASSERT_TRUE(d.is_ok());
  EXPECT_FALSE(d->nis_consistent());
  nis /= 2;
  d = diagnose_residuals(residuals, Eigen::MatrixXd(), &nis);
  ASSERT_TRUE(d.is_ok());
  EXPECT_TRUE(d->nis_consistent());

  // Without NIS: NaN, and the test does not fail.
  d = diagnose_residuals(residuals, Eigen::MatrixXd());
  ASSERT_TRUE(d.is_ok());
  EXPECT_TRUE(std::isnan(d->nis_mean));
  EXPECT_TRUE(std::isnan(d->nis_lower));
  EXPECT_TRUE(std::isnan(d->nis_upper));
  EXPECT_TRUE(d->nis_consistent());
  EXPECT_NE(d->summary().find("no NIS given, not tested"), std::string::npos) << d->summary();
}

TEST(DiagnoseResiduals, InflatedNisIsCaught) {
  // Residuals 10 % larger than the filter claims: NIS 1.21 times chi2(2),
  // mean about 2.42 against a band of about 2 +- 0.088 at N = 2000.
  for (int seed = 0; seed < 100; ++seed) {
    std::mt19937_64 rng(static_cast<std::uint64_t>(seed));
    const Eigen::MatrixXd residuals = 1.1 * gaussian(2, kN, rng);
    const Eigen::VectorXd nis = residuals.colwise().squaredNorm().transpose();
    const Result<ResidualDiagnostics> d = diagnose_residuals(residuals, Eigen::MatrixXd(), &nis);
    ASSERT_TRUE(d.is_ok()) << d.status().to_string();
    EXPECT_FALSE(d->nis_consistent()) << "seed " << seed << ": " << d->nis_mean;
  }
}

TEST(DiagnoseResiduals, SummaryHasOneLinePerTest) {
  std::mt19937_64 rng(3);
  const Eigen::MatrixXd residuals = ar1(0.5, 400, rng);
  const Eigen::MatrixXd input = gaussian(1, 400, rng);
  const Eigen::VectorXd nis = residuals.colwise().squaredNorm().transpose();
  const Result<ResidualDiagnostics> d = diagnose_residuals(residuals, input, &nis);
  ASSERT_TRUE(d.is_ok()) << d.status().to_string();
  const std::string summary = d->summary();
  std::printf("%s", summary.c_str());
  std::vector<std::string> lines;
  std::size_t start = 0;
  for (std::size_t end; (end = summary.find('\n', start)) != std::string::npos; start = end + 1) {
    lines.push_back(summary.substr(start, end - start));
  }
  ASSERT_EQ(lines.size(), 3u) << summary;
  EXPECT_EQ(lines[0].rfind("whiteness (Ljung-Box Q over lags 1..20, N = 400, 95 % limit chi2(20) = 31.41)", 0), 0u)
      << lines[0];
  EXPECT_TRUE(lines[0].ends_with(": fail")) << lines[0];
  EXPECT_EQ(lines[1].rfind("independence from inputs", 0), 0u) << lines[1];
  EXPECT_NE(lines[1].find("output 1/input 1 S = "), std::string::npos) << lines[1];
  EXPECT_NE(lines[1].find("(limit 32.67, 21 dof, p = "), std::string::npos) << lines[1];
  EXPECT_TRUE(lines[1].ends_with(d->uncorrelated_with_inputs() ? ": pass" : ": fail")) << lines[1];
  EXPECT_EQ(lines[2].rfind("noise consistency (mean NIS over 400 samples, 95 % band chi2(400) / N = [", 0), 0u)
      << lines[2];
  EXPECT_TRUE(lines[2].ends_with(d->nis_consistent() ? ": pass" : ": fail")) << lines[2];
}

TEST(DiagnoseResiduals, Errors) {
  const Eigen::MatrixXd none;
  // N = 7 leaves h = 1; N = 8 is the least (h = 2).
  EXPECT_TRUE(FailsWith(diagnose_residuals(Eigen::MatrixXd::Ones(1, 7), none).status(), StatusCode::kInvalidArgument,
                        {"8 samples or more", "N = 7"}));
  EXPECT_TRUE(
      FailsWith(diagnose_residuals(Eigen::MatrixXd(1, 0), none).status(), StatusCode::kInvalidArgument, {"N = 0"}));
  const Result<ResidualDiagnostics> eight = diagnose_residuals(row({1, 3, 2, 5, 4, 4, 1, 2}), none);
  ASSERT_TRUE(eight.is_ok()) << eight.status().to_string();
  EXPECT_EQ(eight->lags, 2);

  EXPECT_TRUE(FailsWith(diagnose_residuals(Eigen::MatrixXd(0, 10), none).status(), StatusCode::kInvalidArgument,
                        {"no residuals", "0 x 10"}));

  Eigen::MatrixXd residuals = Eigen::MatrixXd::Random(2, 10);
  residuals(1, 4) = std::nan("");
  EXPECT_TRUE(FailsWith(diagnose_residuals(residuals, none).status(), StatusCode::kInvalidArgument,
                        {"residual of output 2 is NaN at sample 5"}));
  residuals(1, 4) = 0.0;
  residuals(0, 8) = -std::numeric_limits<double>::infinity();
  EXPECT_TRUE(FailsWith(diagnose_residuals(residuals, none).status(), StatusCode::kInvalidArgument,
                        {"residual of output 1 is infinite at sample 9"}));
  residuals(0, 8) = 0.0;

  Eigen::MatrixXd inputs = Eigen::MatrixXd::Random(3, 10);
  inputs(2, 0) = std::nan("");
  EXPECT_TRUE(FailsWith(diagnose_residuals(residuals, inputs).status(), StatusCode::kInvalidArgument,
                        {"input 3 is NaN at sample 1"}));
  EXPECT_TRUE(FailsWith(diagnose_residuals(residuals, Eigen::MatrixXd::Random(1, 9)).status(),
                        StatusCode::kInvalidArgument, {"2 x 10", "1 x 9"}));

  Eigen::VectorXd nis = Eigen::VectorXd::Ones(9);
  EXPECT_TRUE(FailsWith(diagnose_residuals(residuals, none, &nis).status(), StatusCode::kInvalidArgument,
                        {"9 NIS values for N = 10"}));
  nis = Eigen::VectorXd::Ones(10);
  nis(6) = -0.5;
  EXPECT_TRUE(FailsWith(diagnose_residuals(residuals, none, &nis).status(), StatusCode::kInvalidArgument,
                        {"NIS is -0.5 at sample 7"}));
  nis(6) = std::nan("");
  EXPECT_TRUE(FailsWith(diagnose_residuals(residuals, none, &nis).status(), StatusCode::kInvalidArgument,
                        {"NIS is NaN at sample 7"}));
}

}  // namespace
}  // namespace riccati
