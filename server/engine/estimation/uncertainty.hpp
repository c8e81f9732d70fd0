// How sure an estimate is (docs/identification.md, "What an estimate comes with"): the covariance of
// the free unknowns from the information at the optimum, their standard
// errors, correlations and 95 % confidence intervals, and the unknowns the
// data cannot tell apart, named. Never NaN: an unknown the data do not
// determine gets an infinite standard error and a warning saying which.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

namespace riccati {

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

// The 95 % interval of a value with standard error `std`: value -+ 1.96 std,
// or, for a positive value estimated on a log scale, exp(log value -+ 1.96
// std / value).
void confidence_interval(double value, double std, bool log_scale, double* lower, double* upper);

}  // namespace riccati
