// How sure an estimate is (docs/identification.md, "What an estimate comes with"): the covariance of
// the free unknowns from the information at the optimum, their standard
// errors, correlations and 95 % confidence intervals, and the unknowns the
// data cannot tell apart, named. Never NaN: an unknown the data do not
// determine gets an infinite standard error and a warning saying which.
#pragma once

#include <Eigen/Core>
#include <string>
#include <string_view>
#include <vector>

#include "engine/status.hpp"

namespace riccati {

// Which covariance the intervals of a least-squares estimate come from:
// the white-residual s2 (J'J)^-1, the sandwich robust to autocorrelated
// residuals, or (auto) the robust one where the residuals fail the
// whiteness test.
enum class CovarianceChoice { kAuto, kWhite, kRobust };
// "auto", "white", "robust".
Result<CovarianceChoice> parse_covariance_choice(std::string_view name);

struct Uncertainty {
  Eigen::MatrixXd covariance;   // [p x p]
  Eigen::VectorXd std;          // [p]; +inf for an unknown that is not identifiable
  Eigen::MatrixXd correlation;  // [p x p]; 0 off the diagonal for one that is not identifiable
  std::vector<std::string> warnings;
};

// From the information matrix I = J'J (least squares, residuals weighted so
// that `s2` is their variance: Cov = s2 I^-1) or the Hessian of a negative
// log-likelihood (Cov = H^-1, s2 = 1), at the unknowns `values` named
// `names`. The identifiability check looks at I scaled by the values (so
// that units do not matter): an eigenvalue below 1e-8 of the largest names
// the unknowns in its eigenvector, and a correlation above 0.99 in size
// names the pair.
Uncertainty uncertainty_from_information(const Eigen::MatrixXd& information, double s2,
                                         const std::vector<std::string>& names, const Eigen::VectorXd& values);

// The same as a sandwich, for residuals that are not white: Cov = I^-1 M I^-1
// with the "meat" M the long-run covariance of the scores (sum over samples
// of J_k' r_k, long_run_covariance) instead of s2 I. The identifiability
// check is the same, on I.
Uncertainty uncertainty_from_sandwich(const Eigen::MatrixXd& information, const Eigen::MatrixXd& meat,
                                      const std::vector<std::string>& names, const Eigen::VectorXd& values);

// The long-run covariance of a series of scores g [p x n] (column k: sample
// k's J_k' r_k), in sum form (white scores give sum g_k g_k'): Newey and
// West's Bartlett-kernel estimator after Andrews and Monahan's prewhitening
// (a VAR(1) fitted to g, its residuals' estimate recoloured), with Andrews'
// AR(1) plug-in bandwidth (docs/identification.md, "Coloured residuals").
struct LongRunCovariance {
  Eigen::MatrixXd S;       // [p x p]
  double bandwidth = 0.0;  // of the Bartlett kernel, in samples, after prewhitening
};
LongRunCovariance long_run_covariance(const Eigen::MatrixXd& scores);

// The information and residual scores of a weighted least-squares fit over
// one experiment after another (experiments are independent: their scores'
// long-run covariances add), and the uncertainty from the covariance chosen.
class LeastSquaresCovariance {
 public:
  explicit LeastSquaresCovariance(Eigen::Index unknowns);
  // One experiment: the weighted Jacobian J [N ny x p] (row k ny + i is
  // sample k, output i) and weighted residuals r [N ny], both zero on the
  // rows the mask leaves out.
  void add(const Eigen::MatrixXd& J, const Eigen::VectorXd& r, Eigen::Index ny);
  const Eigen::MatrixXd& information() const { return information_; }
  // The Gauss-Newton step -(J'J)^+ J'r: from a point that is not the least
  // squares optimum, about where the optimum is.
  Eigen::VectorXd gauss_newton_step() const;
  // White: s2 I^-1. Robust: the sandwich, its meat scaled by `dof_factor`
  // (n / (n - p), as s2 divides by n - p). Auto: robust when `white` is
  // false (some experiment's residuals failed the whiteness test). `which`
  // says which one was used, and why.
  Uncertainty uncertainty(CovarianceChoice choice, bool white, double s2, double dof_factor,
                          const std::vector<std::string>& names, const Eigen::VectorXd& values,
                          std::string* which) const;

 private:
  Eigen::MatrixXd information_, meat_;
  Eigen::VectorXd gradient_;        // J'r
  std::vector<double> bandwidths_;  // per experiment
};

// Whether residuals are at rounding level: a noise-free record fitted
// exactly, whose residuals say nothing of the noise's colour (no whiteness
// verdict is drawn from them). `rss` the weighted residuals' sum of
// squares, `signal` the weighted measurements'.
inline bool rounding_residuals(double rss, double signal) { return rss <= 1e-20 * signal; }

// The 95 % interval of a value with standard error `std`: value -+ 1.96 std,
// or, for a positive value estimated on a log scale, exp(log value -+ 1.96
// std / value).
void confidence_interval(double value, double std, bool log_scale, double* lower, double* upper);

}  // namespace riccati
