#include "engine/estimation/diagnostics.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <boost/math/distributions/chi_squared.hpp>
#include <boost/math/policies/policy.hpp>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <utility>
#include <vector>

namespace riccati {
namespace {

using Eigen::Index;

constexpr Index kMinSamples = 8;  // h = min(20, N/4) is 2 at N = 8: fewer leave Ljung-Box next to nothing
constexpr int kMaxLags = 20;
constexpr double kLevel = 0.95;
// Directions of the lagged inputs' Gram matrix with less than this fraction
// of its largest eigenvalue are taken as absent (the input has no energy
// there): a component is computed as (v' r)^2 / lambda, and keeping lambda
// above 1e-9 lambda_max bounds the rounding in it to about eps / sqrt(1e-9),
// 1e-11 of a unit component.
constexpr double kRankTolerance = 1e-9;

// The chi-square functions return NaN or +inf instead of throwing.
using NoThrowPolicy =
    boost::math::policies::policy<boost::math::policies::domain_error<boost::math::policies::ignore_error>,
                                  boost::math::policies::overflow_error<boost::math::policies::ignore_error>,
                                  boost::math::policies::evaluation_error<boost::math::policies::ignore_error>>;

// The first non-finite value, by sample then row, so the message points at
// the earliest trouble.
Status check_finite(const Eigen::MatrixXd& values, const char* what) {
  if (values.allFinite()) return Status::ok();
  for (Index k = 0; k < values.cols(); ++k) {
    for (Index i = 0; i < values.rows(); ++i) {
      if (!std::isfinite(values(i, k))) {
        return invalid_argument(std::string(what) + " " + std::to_string(i + 1) + " is " +
                                (std::isnan(values(i, k)) ? "NaN" : "infinite") + " at sample " +
                                std::to_string(k + 1));
      }
    }
  }
  return Status::ok();
}

using Series = Eigen::Ref<const Eigen::VectorXd>;  // one normalised residual or input, samples contiguous

// z = (x - mean x) / ||x - mean x||, so that a correlation is a dot product
// of two such series and the lag-0 variance is 1. Returns false, with z = 0,
// for a constant x. x is first scaled by a power of two near its largest
// magnitude (exact), so that squares neither overflow nor underflow.
bool normalise(const Eigen::Ref<const Eigen::RowVectorXd, 0, Eigen::InnerStride<>>& x, Eigen::Ref<Eigen::VectorXd> z) {
  z.setZero();
  if (x.maxCoeff() == x.minCoeff()) return false;
  int exponent = 0;
  std::frexp(x.cwiseAbs().maxCoeff(), &exponent);
  for (Index k = 0; k < x.size(); ++k) z(k) = std::ldexp(x(k), -exponent);
  z.array() -= z.mean();
  const double norm = z.norm();
  if (!(norm > 0.0)) {
    z.setZero();
    return false;
  }
  z /= norm;
  return true;
}

// The correlation of normalised series at lag tau: sum_s e(s) u(s - tau) over
// the samples where both exist (e = u gives the autocorrelation).
double correlation(const Series& e, const Series& u, Index tau) {
  const Index n = e.size() - std::abs(tau);
  return tau >= 0 ? e.segment(tau, n).dot(u.segment(0, n)) : e.segment(0, n).dot(u.segment(-tau, n));
}

// The Gram matrix G(a, b) = sum_s u(s - a) u(s - b) of a normalised input at
// lags 0..h, each lag a column of the input delayed by it (zeros before the
// first sample): the regressors of the cross-correlation test.
Eigen::MatrixXd lagged_gram(const Series& u, int h) {
  const Index n = u.size();
  Eigen::MatrixXd gram(h + 1, h + 1);
  for (Index a = 0; a <= h; ++a) {
    for (Index b = 0; b <= a; ++b) {
      // s runs from max(a, b) = a to n - 1.
      gram(a, b) = gram(b, a) = u.segment(0, n - a).dot(u.segment(a - b, n - a));
    }
  }
  return gram;
}

}  // namespace

double chi_square_quantile(double p, double dof) {
  if (!std::isfinite(p) || !std::isfinite(dof) || p < 0.0 || p > 1.0 || !(dof > 0.0)) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  if (p == 0.0) return 0.0;
  if (p == 1.0) return std::numeric_limits<double>::infinity();
  const boost::math::chi_squared_distribution<double, NoThrowPolicy> distribution(dof);
  return boost::math::quantile(distribution, p);
}

double chi_square_p_value(double x, double dof) {
  if (std::isnan(x) || !std::isfinite(dof) || !(dof > 0.0)) return std::numeric_limits<double>::quiet_NaN();
  if (x <= 0.0) return 1.0;
  if (x == std::numeric_limits<double>::infinity()) return 0.0;
  const boost::math::chi_squared_distribution<double, NoThrowPolicy> distribution(dof);
  return boost::math::cdf(boost::math::complement(distribution, x));
}

Result<ResidualDiagnostics> diagnose_residuals(const Eigen::MatrixXd& residuals, const Eigen::MatrixXd& inputs,
                                               const Eigen::VectorXd* nis) {
  const Index ny = residuals.rows();
  const Index n = residuals.cols();
  const Index nu = inputs.rows();
  if (ny == 0) return invalid_argument("no residuals to diagnose: " + size_text(residuals) + " (outputs x samples)");
  if (nu > 0 && inputs.cols() != n) {
    return invalid_argument("residuals are " + size_text(residuals) + " but inputs are " + size_text(inputs) +
                            " (rows x samples)");
  }
  if (n < kMinSamples) {
    return invalid_argument("residual diagnostics need " + std::to_string(kMinSamples) +
                            " samples or more, got N = " + std::to_string(n));
  }
  RICCATI_RETURN_IF_ERROR(check_finite(residuals, "residual of output"));
  RICCATI_RETURN_IF_ERROR(check_finite(inputs, "input"));
  if (nis != nullptr) {
    if (nis->size() != n) {
      return invalid_argument(std::to_string(nis->size()) + " NIS values for N = " + std::to_string(n) + " samples");
    }
    for (Index k = 0; k < n; ++k) {
      const double value = (*nis)(k);
      if (!std::isfinite(value) || value < 0.0) {
        return invalid_argument("NIS is " + (std::isnan(value) ? std::string("NaN") : message_number(value, 4)) + " at sample " +
                                std::to_string(k + 1) + " (a squared norm: finite and not negative)");
      }
    }
  }

  ResidualDiagnostics d;
  const int h = static_cast<int>(std::min<Index>(kMaxLags, n / 4));
  const double samples = static_cast<double>(n);
  d.samples = n;
  d.lags = h;
  d.band = 1.96 / std::sqrt(samples);

  // Each row normalised once, into a column: every correlation below is then
  // a dot product of contiguous segments.
  Eigen::MatrixXd e(n, ny);
  Eigen::MatrixXd u(n, nu);
  d.constant_residual.resize(ny);
  d.constant_input.resize(nu);
  for (Index i = 0; i < ny; ++i) d.constant_residual(i) = !normalise(residuals.row(i), e.col(i));
  for (Index j = 0; j < nu; ++j) d.constant_input(j) = !normalise(inputs.row(j), u.col(j));

  // Ljung & Box (1978): Q = N (N + 2) sum_{tau=1..h} rho(tau)^2 / (N - tau),
  // chi-square(h) for white noise. No degrees of freedom are taken off for
  // the estimated parameters: that correction is for ARMA residuals, and
  // these are a grey-box model's.
  d.autocorrelation.resize(ny, h);
  d.ljung_box.resize(ny);
  for (Index i = 0; i < ny; ++i) {
    double q = 0.0;
    for (int tau = 1; tau <= h; ++tau) {
      const double rho = correlation(e.col(i), e.col(i), tau);
      d.autocorrelation(i, tau - 1) = rho;
      q += rho * rho / (samples - tau);
    }
    d.ljung_box(i) = samples * (samples + 2.0) * q;
  }
  d.ljung_box_limit = chi_square_quantile(kLevel, h);
  d.ljung_box_p = d.ljung_box.unaryExpr([h](double q) { return chi_square_p_value(q, h); });

  // Cross-correlations at lags -h..h, and per pair S = N r' G^+ r over lags
  // 0..h (the header says why that statistic). G's eigen decomposition is
  // once per input; S sums (v_k' r)^2 / lambda_k over the kept directions.
  d.cross_correlation.resize(ny * nu, 2 * h + 1);
  d.cross_statistic.resize(ny * nu);
  d.cross_dof.resize(ny * nu);
  d.cross_limit.resize(ny * nu);
  d.cross_p.resize(ny * nu);
  Eigen::VectorXd r(h + 1);
  for (Index j = 0; j < nu; ++j) {
    const Series input = u.col(j);
    int rank = 0;
    Eigen::MatrixXd basis;   // [(h + 1) x rank]: the kept eigenvectors
    Eigen::VectorXd scales;  // [rank]: their eigenvalues
    if (!d.constant_input(j)) {
      const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(lagged_gram(input, h));
      const Eigen::VectorXd& lambda = eigen.eigenvalues();  // ascending
      const double floor = kRankTolerance * lambda(h);
      for (int k = 0; k <= h; ++k) rank += lambda(k) > floor ? 1 : 0;
      basis = eigen.eigenvectors().rightCols(rank);
      scales = lambda.tail(rank);
    }
    const double limit = rank > 0 ? chi_square_quantile(kLevel, rank) : 0.0;
    for (Index i = 0; i < ny; ++i) {
      const Index pair = i * nu + j;
      for (int tau = -h; tau <= h; ++tau) d.cross_correlation(pair, tau + h) = correlation(e.col(i), input, tau);
      r = d.cross_correlation.row(pair).tail(h + 1).transpose();
      d.cross_statistic(pair) =
          rank > 0 ? samples * ((basis.transpose() * r).array().square() / scales.array()).sum() : 0.0;
      d.cross_dof(pair) = rank;
      d.cross_limit(pair) = limit;
      d.cross_p(pair) = rank > 0 ? chi_square_p_value(d.cross_statistic(pair), rank) : 1.0;
    }
  }

  // Each NIS is chi-square(ny) for a consistent filter, so N times their mean
  // is chi-square(N ny) (Bar-Shalom, Li & Kirubarajan 2001, ch. 5, consistency of estimators).
  if (nis != nullptr) {
    const double dof = samples * static_cast<double>(ny);
    d.nis_mean = nis->mean();
    d.nis_lower = chi_square_quantile(0.025, dof) / samples;
    d.nis_upper = chi_square_quantile(0.975, dof) / samples;
    d.nis_dof = dof;
    // Both tails computed directly (1 - upper would lose a small lower tail's digits).
    const boost::math::chi_squared_distribution<double, NoThrowPolicy> distribution(dof);
    const double x = samples * d.nis_mean;
    const double lower = boost::math::cdf(distribution, x);
    const double upper = boost::math::cdf(boost::math::complement(distribution, x));
    d.nis_p = std::min(1.0, 2.0 * std::min(lower, upper));
  }
  return d;
}

std::vector<Index> ResidualDiagnostics::non_white_outputs() const {
  std::vector<Index> outputs;
  for (Index i = 0; i < ljung_box.size(); ++i) {
    if (!(ljung_box(i) <= ljung_box_limit)) outputs.push_back(i);
  }
  return outputs;
}

std::vector<std::pair<Index, Index>> ResidualDiagnostics::input_correlated_pairs() const {
  std::vector<std::pair<Index, Index>> pairs;
  const Index nu = constant_input.size();
  for (Index pair = 0; pair < cross_statistic.size(); ++pair) {
    if (!(cross_statistic(pair) <= cross_limit(pair))) pairs.emplace_back(pair / nu, pair % nu);
  }
  return pairs;
}

bool ResidualDiagnostics::white() const { return non_white_outputs().empty(); }

bool ResidualDiagnostics::uncorrelated_with_inputs() const { return input_correlated_pairs().empty(); }

bool ResidualDiagnostics::nis_consistent() const {
  if (std::isnan(nis_mean)) return true;
  return nis_mean >= nis_lower && nis_mean <= nis_upper;
}

std::string ResidualDiagnostics::summary() const {
  const auto verdict = [](bool pass) { return pass ? std::string("pass") : std::string("fail"); };
  std::string text = "whiteness (Ljung-Box Q over lags 1.." + std::to_string(lags) +
                     ", N = " + std::to_string(samples) + ", 95 % limit chi2(" + std::to_string(lags) +
                     ") = " + message_number(ljung_box_limit, 4) + "):";
  for (Index i = 0; i < ljung_box.size(); ++i) {
    text += (i > 0 ? "; output " : " output ") + std::to_string(i + 1) + " Q = " + message_number(ljung_box(i), 4);
    if (constant_residual(i)) {
      text += " (constant residual: no correlation)";
    } else {
      const Index outside = (autocorrelation.row(i).array().abs() > band).count();
      text += " (p = " + message_number(ljung_box_p(i), 3) + ", " + std::to_string(outside) + " of " + std::to_string(lags) +
              " lags outside +-" + message_number(band, 4) + ")";
    }
  }
  text += ": " + verdict(white()) + "\n";

  const Index nu = constant_input.size();
  text += "independence from inputs (N R^2 of the residual on the input at lags 0.." + std::to_string(lags) +
          ", 95 % limit chi2(dof)):";
  if (nu == 0) text += " no inputs";
  for (Index pair = 0; pair < cross_statistic.size(); ++pair) {
    text += (pair > 0 ? "; output " : " output ") + std::to_string(pair / nu + 1) + "/input " +
            std::to_string(pair % nu + 1) + " S = " + message_number(cross_statistic(pair), 4);
    if (constant_input(pair % nu)) {
      text += " (constant input: no correlation)";
    } else {
      text += " (limit " + message_number(cross_limit(pair), 4) + ", " + std::to_string(cross_dof(pair)) +
              " dof, p = " + message_number(cross_p(pair), 3) + ")";
    }
  }
  text += ": " + verdict(uncorrelated_with_inputs()) + "\n";

  if (std::isnan(nis_mean)) {
    text += "noise consistency (mean NIS): no NIS given, not tested\n";
  } else {
    const Index ny = ljung_box.size();
    text += "noise consistency (mean NIS over " + std::to_string(samples) + " samples, 95 % band chi2(" +
            std::to_string(samples * ny) + ") / N = [" + message_number(nis_lower, 4) + ", " + message_number(nis_upper, 4) +
            "]): " + message_number(nis_mean, 4) + " (p = " + message_number(nis_p, 3) + ", two-sided): " + verdict(nis_consistent()) +
            "\n";
  }
  return text;
}

}  // namespace riccati
