#include "engine/estimation/uncertainty.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>
#include <cstdio>
#include <limits>

#include "engine/status.hpp"

namespace riccati {
namespace {

constexpr double kRelativeEigenvalue = 1e-8;  // docs/identification.md
constexpr double kCorrelation = 0.99;
constexpr double kZ95 = 1.959963984540054;


}  // namespace

Uncertainty uncertainty_from_information(const Eigen::MatrixXd& information, double s2,
                                         const std::vector<std::string>& names, const Eigen::VectorXd& values) {
  const Eigen::Index p = information.rows();
  Uncertainty out;
  out.covariance = Eigen::MatrixXd::Zero(p, p);
  out.std = Eigen::VectorXd::Zero(p);
  out.correlation = Eigen::MatrixXd::Identity(p, p);
  if (p == 0) return out;

  // Scaled by the values (1 for a value of 0), so that eigenvalues compare
  // directions of relative change: D I D with D = diag(|value|).
  Eigen::VectorXd scale = values.cwiseAbs();
  for (Eigen::Index i = 0; i < p; ++i) {
    if (!(scale[i] > 0.0) || !std::isfinite(scale[i])) scale[i] = 1.0;
  }
  const Eigen::MatrixXd scaled = scale.asDiagonal() * (0.5 * (information + information.transpose())) * scale.asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(scaled);
  const Eigen::VectorXd lambda = eigen.eigenvalues();  // ascending
  const Eigen::MatrixXd& V = eigen.eigenvectors();
  const double largest = std::max(lambda.cwiseAbs().maxCoeff(), std::numeric_limits<double>::min());
  std::vector<bool> unidentifiable(static_cast<std::size_t>(p), false);
  Eigen::MatrixXd inverse = Eigen::MatrixXd::Zero(p, p);  // of the scaled information, on its identifiable part
  for (Eigen::Index k = 0; k < p; ++k) {
    if (lambda[k] > kRelativeEigenvalue * largest) {
      inverse.noalias() += (1.0 / lambda[k]) * V.col(k) * V.col(k).transpose();
      continue;
    }
    // A direction the data do not determine: the unknowns that make it up.
    std::string who;
    for (Eigen::Index i = 0; i < p; ++i) {
      if (std::abs(V(i, k)) > 0.1) {
        unidentifiable[static_cast<std::size_t>(i)] = true;
        who += (who.empty() ? "" : ", ") + names[static_cast<std::size_t>(i)];
      }
    }
    out.warnings.push_back("not identifiable from these data: " + who + " (the information in that direction is " +
                           message_number(lambda[k] / largest, 4) + " of the largest)");
  }
  out.covariance = s2 * (scale.asDiagonal() * inverse * scale.asDiagonal());
  for (Eigen::Index i = 0; i < p; ++i) {
    out.std[i] = unidentifiable[static_cast<std::size_t>(i)] ? std::numeric_limits<double>::infinity()
                                                             : std::sqrt(std::max(out.covariance(i, i), 0.0));
  }
  for (Eigen::Index i = 0; i < p; ++i) {
    for (Eigen::Index j = 0; j < p; ++j) {
      if (i == j) continue;
      const bool known = std::isfinite(out.std[i]) && std::isfinite(out.std[j]) && out.std[i] > 0.0 && out.std[j] > 0.0;
      out.correlation(i, j) = known ? out.covariance(i, j) / (out.std[i] * out.std[j]) : 0.0;
    }
  }
  for (Eigen::Index i = 0; i < p; ++i) {
    for (Eigen::Index j = i + 1; j < p; ++j) {
      if (std::abs(out.correlation(i, j)) > kCorrelation) {
        out.warnings.push_back(names[static_cast<std::size_t>(i)] + " and " + names[static_cast<std::size_t>(j)] +
                               " are correlated at " + message_number(out.correlation(i, j), 4) +
                               ": the data hardly tell them apart");
      }
    }
  }
  return out;
}

void confidence_interval(double value, double std, bool log_scale, double* lower, double* upper) {
  if (!std::isfinite(std)) {
    *lower = -std::numeric_limits<double>::infinity();
    *upper = std::numeric_limits<double>::infinity();
    if (log_scale) *lower = 0.0;
    return;
  }
  if (log_scale && value > 0.0) {
    const double half = kZ95 * std / value;
    *lower = value * std::exp(-half);
    *upper = value * std::exp(half);
    return;
  }
  *lower = value - kZ95 * std;
  *upper = value + kZ95 * std;
}

}  // namespace riccati
