#include "engine/estimation/uncertainty.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "engine/status.hpp"

namespace riccati {
namespace {

constexpr double kRelativeEigenvalue = 1e-8;  // docs/identification.md
constexpr double kCorrelation = 0.99;
constexpr double kZ95 = 1.959963984540054;

// The inverse of the information on the directions the data determine
// (zero on the others), and the unknowns the others make up, named in
// `warnings`; `unidentifiable` [p] marks them.
Eigen::MatrixXd identifiable_inverse(const Eigen::MatrixXd& information, const std::vector<std::string>& names,
                                     const Eigen::VectorXd& values, std::vector<bool>* unidentifiable,
                                     std::vector<std::string>* warnings) {
  const Eigen::Index p = information.rows();
  unidentifiable->assign(static_cast<std::size_t>(p), false);
  if (p == 0) return Eigen::MatrixXd(0, 0);
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
        (*unidentifiable)[static_cast<std::size_t>(i)] = true;
        who += (who.empty() ? "" : ", ") + names[static_cast<std::size_t>(i)];
      }
    }
    warnings->push_back("not identifiable from these data: " + who + " (the information in that direction is " +
                        message_number(lambda[k] / largest, 4) + " of the largest)");
  }
  return scale.asDiagonal() * inverse * scale.asDiagonal();
}

// Fills std and correlation from `out.covariance`, and warns of pairs the
// data hardly tell apart.
void finish(const std::vector<bool>& unidentifiable, const std::vector<std::string>& names, Uncertainty& out) {
  const Eigen::Index p = out.covariance.rows();
  out.std = Eigen::VectorXd::Zero(p);
  out.correlation = Eigen::MatrixXd::Identity(p, p);
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
}

}  // namespace

Uncertainty uncertainty_from_information(const Eigen::MatrixXd& information, double s2,
                                         const std::vector<std::string>& names, const Eigen::VectorXd& values) {
  Uncertainty out;
  std::vector<bool> unidentifiable;
  out.covariance = s2 * identifiable_inverse(information, names, values, &unidentifiable, &out.warnings);
  finish(unidentifiable, names, out);
  return out;
}

Uncertainty uncertainty_from_sandwich(const Eigen::MatrixXd& information, const Eigen::MatrixXd& meat,
                                      const std::vector<std::string>& names, const Eigen::VectorXd& values) {
  Uncertainty out;
  std::vector<bool> unidentifiable;
  const Eigen::MatrixXd bread = identifiable_inverse(information, names, values, &unidentifiable, &out.warnings);
  out.covariance = bread * meat * bread;
  out.covariance = 0.5 * (out.covariance + out.covariance.transpose());
  finish(unidentifiable, names, out);
  return out;
}

LongRunCovariance long_run_covariance(const Eigen::MatrixXd& scores) {
  const Eigen::Index p = scores.rows(), n = scores.cols();
  LongRunCovariance out;
  if (p == 0 || n < 4) {
    out.S = scores * scores.transpose();
    return out;
  }
  // In units of each component's RMS: the parameters' scores differ by
  // orders of magnitude (a tank's area against a valve's coefficient), and
  // both the VAR's least squares and the bandwidth should weigh them alike.
  Eigen::VectorXd unit = (scores.rowwise().squaredNorm() / static_cast<double>(n)).cwiseSqrt();
  for (Eigen::Index a = 0; a < p; ++a) {
    if (!(unit[a] > 0.0) || !std::isfinite(unit[a])) unit[a] = 1.0;
  }
  const Eigen::MatrixXd g = unit.cwiseInverse().asDiagonal() * scores;
  // Prewhitening: g_k = A g_k-1 + e_k by least squares. A's singular values
  // are held below 0.97 (Andrews and Monahan 1992), so that (I - A)^-1 stays
  // bounded when the scores are nearly a random walk.
  const Eigen::MatrixXd previous = g.leftCols(n - 1), next = g.rightCols(n - 1);
  const Eigen::MatrixXd gram = previous * previous.transpose();
  Eigen::MatrixXd A = (next * previous.transpose()) *
                      gram.completeOrthogonalDecomposition().pseudoInverse();
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::VectorXd singular = svd.singularValues();
  if (singular.size() > 0 && singular.maxCoeff() > 0.97) {
    singular = singular.cwiseMin(0.97);
    A = svd.matrixU() * singular.asDiagonal() * svd.matrixV().transpose();
  }
  const Eigen::MatrixXd e = next - A * previous;  // [p x n-1]
  const Eigen::Index m = e.cols();
  // Andrews' (1991) bandwidth for the Bartlett kernel from an AR(1) fitted
  // to each component of e, all weighted alike: 1.1447 (alpha(1) m)^(1/3).
  double numerator = 0.0, denominator = 0.0;
  for (Eigen::Index a = 0; a < p; ++a) {
    const double lagged = e.row(a).head(m - 1).squaredNorm();
    if (!(lagged > 0.0)) continue;
    const double rho = std::clamp(e.row(a).tail(m - 1).dot(e.row(a).head(m - 1)) / lagged, -0.97, 0.97);
    const Eigen::RowVectorXd innovation = e.row(a).tail(m - 1) - rho * e.row(a).head(m - 1);
    const double s2 = innovation.squaredNorm() / static_cast<double>(m - 1);
    numerator += 4.0 * rho * rho * s2 * s2 / (std::pow(1.0 - rho, 6) * std::pow(1.0 + rho, 2));
    denominator += s2 * s2 / std::pow(1.0 - rho, 4);
  }
  const double alpha = denominator > 0.0 ? numerator / denominator : 0.0;
  out.bandwidth = std::min(1.1447 * std::cbrt(alpha * static_cast<double>(m)), static_cast<double>(m - 1));
  // Bartlett weights 1 - l / b for the lags l < b: Gamma_l = sum_t e_t
  // e_t-l', added with its transpose. (Loops, not products of blocks: their
  // temporaries would be allocated once per lag, and the lags grow with n.)
  Eigen::MatrixXd S = e * e.transpose();
  for (Eigen::Index l = 1; static_cast<double>(l) < out.bandwidth; ++l) {
    const double w = 1.0 - static_cast<double>(l) / out.bandwidth;
    for (Eigen::Index a = 0; a < p; ++a) {
      for (Eigen::Index b = 0; b < p; ++b) {
        double gamma = 0.0;  // (Gamma_l)_ab
        for (Eigen::Index t = l; t < m; ++t) gamma += e(a, t) * e(b, t - l);
        S(a, b) += w * gamma;
        S(b, a) += w * gamma;
      }
    }
  }
  // Recoloured: (I - A)^-1 S (I - A)^-T.
  const Eigen::MatrixXd recolour = unit.asDiagonal() * (Eigen::MatrixXd::Identity(p, p) - A).inverse();
  out.S = recolour * S * recolour.transpose();
  out.S = 0.5 * (out.S + out.S.transpose());
  return out;
}

Result<CovarianceChoice> parse_covariance_choice(std::string_view name) {
  if (name == "auto") return CovarianceChoice::kAuto;
  if (name == "white") return CovarianceChoice::kWhite;
  if (name == "robust") return CovarianceChoice::kRobust;
  return invalid_argument("unknown covariance \"" + std::string(name) + "\" (expected auto, white or robust)");
}

LeastSquaresCovariance::LeastSquaresCovariance(Eigen::Index unknowns)
    : information_(Eigen::MatrixXd::Zero(unknowns, unknowns)),
      meat_(Eigen::MatrixXd::Zero(unknowns, unknowns)),
      gradient_(Eigen::VectorXd::Zero(unknowns)) {}

Eigen::VectorXd LeastSquaresCovariance::gauss_newton_step() const {
  if (information_.rows() == 0) return Eigen::VectorXd(0);
  return -(information_.completeOrthogonalDecomposition().solve(gradient_));
}

void LeastSquaresCovariance::add(const Eigen::MatrixXd& J, const Eigen::VectorXd& r, Eigen::Index ny) {
  const Eigen::Index p = J.cols(), n = ny > 0 ? J.rows() / ny : 0;
  if (p == 0) {  // every unknown held: nothing to add (and no blocks of an empty J to take)
    bandwidths_.push_back(0.0);
    return;
  }
  information_.noalias() += J.transpose() * J;
  gradient_.noalias() += J.transpose() * r;
  Eigen::MatrixXd scores = Eigen::MatrixXd::Zero(p, n);  // column k: sum over outputs of J_k,i' r_k,i
  for (Eigen::Index k = 0; k < n; ++k) {
    scores.col(k).noalias() = J.middleRows(k * ny, ny).transpose() * r.segment(k * ny, ny);
  }
  const LongRunCovariance lr = long_run_covariance(scores);
  meat_ += lr.S;
  bandwidths_.push_back(lr.bandwidth);
}

Uncertainty LeastSquaresCovariance::uncertainty(CovarianceChoice choice, bool white, double s2, double dof_factor,
                                                const std::vector<std::string>& names, const Eigen::VectorXd& values,
                                                std::string* which) const {
  const bool robust = choice == CovarianceChoice::kRobust || (choice == CovarianceChoice::kAuto && !white);
  if (!robust) {
    *which = "white residuals: s2 (J'J)^-1";
    return uncertainty_from_information(information_, s2, names, values);
  }
  std::string bandwidths;
  for (double b : bandwidths_) bandwidths += (bandwidths.empty() ? "" : ", ") + message_number(b, 3);
  *which = std::string("robust to autocorrelated residuals") +
           (choice == CovarianceChoice::kRobust ? "" : " (the residuals are not white)") +
           ": (J'J)^-1 M (J'J)^-1, M the residual scores' long-run covariance (Newey-West, prewhitened; bandwidth " +
           bandwidths + " samples)";
  return uncertainty_from_sandwich(information_, dof_factor * meat_, names, values);
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
