// Residual diagnostics: does the model explain the data? Stored with every
// identification result.
//
// The residuals are normalised, one column per sample used (output error:
// r_k; maximum likelihood: S_k^-1/2 e_k); samples the estimation left out are
// left out by the caller. Tests, each at 95 %:
//   - whiteness: the autocorrelation of each output's residual and the
//     Ljung-Box Q over lags 1..h against chi-square(h);
//   - independence from the inputs: the cross-correlation of each output's
//     residual with each input, tested at lags 0..h (past and present inputs)
//     by N R^2 of the residual regressed on those lags, against chi-square;
//   - consistency of the noise model: the mean NIS against its chi-square band.
#pragma once

#include <Eigen/Core>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "engine/status.hpp"

namespace riccati {

// Diagnostics of normalised residuals [ny x N] against the inputs [nu x N].
//
// Correlations are the sample ones with the mean removed and the lag-0
// variance as denominator (the convention of Ljung-Box and MATLAB's resid):
//     rho(tau) = sum_{t} (e_t - mean e)(e_{t+tau} - mean e) / sum_t (e_t - mean e)^2,
//     r_eu(tau) = sum_{t} (e_{t+tau} - mean e)(u_t - mean u) / sqrt(sum (e - mean e)^2 sum (u - mean u)^2),
// each sum over the samples where both terms exist. Lag tau > 0 of r_eu pairs
// the residual with the input tau samples earlier: a correlation there is
// input the model failed to explain; at tau < 0 (the input after the
// residual) it is feedback, expected of a correct model on closed-loop data.
//
// A constant residual (zero variance, e.g. noise-free data fitted exactly) or
// a constant input has no variation to correlate: its correlations are
// reported as 0, Q and the cross statistic as 0, and its tests pass; the
// `constant_*` flags say so. The mean is removed by definition, so an offset
// is not seen here (the mean NIS does see it).
struct ResidualDiagnostics {
  Eigen::Index samples = 0;  // N
  int lags = 0;              // h = min(20, N/4)
  double band = 0.0;         // 1.96 / sqrt(N): the 95 % band of a correlation of white noise

  Eigen::MatrixXd autocorrelation;  // [ny x h], rho_i(tau), tau = 1..h
  Eigen::VectorXd ljung_box;        // [ny], Q_i = N (N + 2) sum_{tau=1..h} rho_i(tau)^2 / (N - tau)
  double ljung_box_limit = 0.0;     // the chi-square(h) 95 % quantile
  Eigen::VectorXd ljung_box_p;      // [ny], P(chi-square(h) >= Q_i); the test's degrees of freedom are h (`lags`)

  Eigen::MatrixXd cross_correlation;  // [(ny nu) x (2h + 1)]: output i against input j (row i*nu + j), column tau + h
                                      // for lags -h..h
  // The test of output i against input j (row i*nu + j): S = N R^2 of the
  // least-squares regression of the residual on the input at lags 0..h,
  // which equals N r' G^+ r with r the cross-correlations at lags 0..h and G
  // the Gram matrix of the (normalised) input at those lags. When the
  // residual is white and independent of the input, S is chi-square with
  // rank(G) degrees of freedom whatever the input's own spectrum (Ljung,
  // System Identification, 2nd ed., 1999, ch. 16, residual analysis: his
  // N r' P^-1 r with P = R_u when the residual is white), where a count of lags
  // outside the band, or N sum r^2, would be thrown off by an input
  // correlated with itself (the lags' correlations are then correlated).
  Eigen::VectorXd cross_statistic;  // [ny nu], S
  Eigen::VectorXi cross_dof;        // [ny nu], rank(G): h + 1 for an input that varies (its zero-filled lags are
                                    // independent), 0 for a constant one
  Eigen::VectorXd cross_limit;      // [ny nu], the chi-square(cross_dof) 95 % quantile (0 when cross_dof is 0)
  Eigen::VectorXd cross_p;          // [ny nu], P(chi-square(cross_dof) >= S); 1 when cross_dof is 0 (not tested)

  Eigen::Array<bool, Eigen::Dynamic, 1> constant_residual;  // [ny]: no variation; its correlations are 0
  Eigen::Array<bool, Eigen::Dynamic, 1> constant_input;     // [nu]: likewise

  double nis_mean = std::numeric_limits<double>::quiet_NaN();   // mean NIS when given (NaN otherwise)
  double nis_lower = std::numeric_limits<double>::quiet_NaN();  // its 95 % band: chi-square(N ny) 2.5 % and 97.5 %
  double nis_upper = std::numeric_limits<double>::quiet_NaN();  // quantiles over N (NaN when no NIS is given)
  double nis_dof = 0.0;  // N ny: the degrees of freedom of N times the mean NIS (0 when no NIS is given)
  // Two-sided, as the band: 2 min(P(X <= N mean), P(X >= N mean)), X chi-square(N ny); NaN when no NIS is given.
  double nis_p = std::numeric_limits<double>::quiet_NaN();

  // Verdicts. Each test is at 95 % on its own: with several outputs or pairs,
  // the chance that a correct model fails one of them is 1 - 0.95^m.
  bool white() const;                                   // every output's Q at most ljung_box_limit
  bool uncorrelated_with_inputs() const;                // every pair's S at most cross_limit (true with no inputs)
  bool nis_consistent() const;                          // mean NIS in [nis_lower, nis_upper] (true when no NIS given)
  std::vector<Eigen::Index> non_white_outputs() const;  // the outputs (0-based) that fail white()
  // The (output, input) pairs (0-based) that fail uncorrelated_with_inputs().
  std::vector<std::pair<Eigen::Index, Eigen::Index>> input_correlated_pairs() const;

  // One line per test: what it tests, the numbers, and "pass" or "fail"
  // (outputs and inputs numbered from 1).
  std::string summary() const;
};

// Errors (INVALID_ARGUMENT): no outputs; fewer than 8 samples (N = 8 gives
// h = 2 lags); inputs or NIS whose sample count differs from the residuals';
// a non-finite residual, input or NIS, or a negative NIS (each named by its
// sample, from 1). Inputs may be [0 x N] or empty for a model without inputs.
// `nis` has one value per sample: e_k' S_k^-1 e_k, chi-square(ny) for a
// consistent filter.
Result<ResidualDiagnostics> diagnose_residuals(const Eigen::MatrixXd& residuals, const Eigen::MatrixXd& inputs,
                                               const Eigen::VectorXd* nis = nullptr);

// The p-quantile of the chi-square distribution with `dof` degrees of freedom
// (Boost.Math). Never throws: 0 for p = 0, +inf for p = 1, NaN for p outside
// [0, 1], dof <= 0 or a non-finite argument.
double chi_square_quantile(double p, double dof);

// P(X >= x) for X chi-square with `dof` degrees of freedom: the p-value of a
// statistic x (Boost.Math, the complement computed directly, so that small
// p-values keep their digits). Never throws: 1 for x <= 0, 0 for x = +inf,
// NaN for dof <= 0 or a NaN argument.
double chi_square_p_value(double x, double dof);

}  // namespace riccati
