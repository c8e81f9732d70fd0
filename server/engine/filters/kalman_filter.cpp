#include "engine/filters/kalman_filter.hpp"

#include <algorithm>
#include <limits>
#include <string>

namespace riccati {

KalmanFilter::KalmanFilter(ModelPtr model, FilterSettings settings) : Filter(std::move(model), std::move(settings)) {
  const Eigen::Index nz = model_->nz(), ny = model_->ny();
  K_ = Eigen::MatrixXd::Zero(nz, ny);
  KT_.resize(ny, nz);
  S_innovation_.resize(ny);
  S_factor_.resize(ny, ny);
  S_solve_ = cholesky_solve_for(static_cast<int>(ny));
  VtCt_.resize(ny, nz);
  Vte_.resize(ny);
  inverse_eigenvalues_.resize(ny);
  V_.resize(ny, ny);
  S_tridiagonal_ = Eigen::Tridiagonalization<Eigen::MatrixXd>(ny);
  T_eigen_ = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(ny);
  T_diagonal_.resize(ny);
  T_subdiagonal_.resize(std::max<Eigen::Index>(ny - 1, 0));
  householder_workspace_.resize(ny);
}

Status KalmanFilter::gain_and_nis(const Eigen::MatrixXd& C) {
  // K = C S^-1 is computed as K^T = S^-1 C^T (S symmetric): a solve, never an inverse.
  KT_ = C.transpose();
  S_innovation_ = innovation_;
  if (settings_.inversion == GainInversion::kCholesky) {
    const int ny = static_cast<int>(S_.rows());
    if (!cholesky(ny, S_.data(), S_factor_.data())) {
      return failed_precondition(
          "innovation covariance S is not positive definite at t = " + std::to_string(t_) +
          " (R has zero variances and the prediction is exact?): give R positive variances or use the "
          "pseudo-inverse gain");
    }
    S_solve_(ny, S_factor_.data(), KT_.data(), static_cast<int>(KT_.cols()));
    S_solve_(ny, S_factor_.data(), S_innovation_.data(), 1);
  } else {
    // Minimum-norm solution: S^+ = V D^+ V^T, eigenvalues below n eps max|d|
    // taken as zero (the rank threshold of Eigen's COD and of MATLAB's pinv).
    S_tridiagonal_.compute(S_);
    T_diagonal_ = S_tridiagonal_.diagonal();
    T_subdiagonal_ = S_tridiagonal_.subDiagonal();
    T_eigen_.computeFromTridiagonal(T_diagonal_, T_subdiagonal_, Eigen::ComputeEigenvectors);
    V_ = T_eigen_.eigenvectors();
    S_tridiagonal_.matrixQ().applyThisOnTheLeft(V_, householder_workspace_);
    const auto& d = T_eigen_.eigenvalues();
    const Eigen::MatrixXd& V = V_;
    const double threshold = static_cast<double>(d.size()) * std::numeric_limits<double>::epsilon() *
                             d.cwiseAbs().maxCoeff();
    for (Eigen::Index i = 0; i < d.size(); ++i) inverse_eigenvalues_[i] = d[i] > threshold ? 1.0 / d[i] : 0.0;
    VtCt_.noalias() = V.transpose() * KT_;
    VtCt_.array().colwise() *= inverse_eigenvalues_.array();
    KT_.noalias() = V * VtCt_;
    Vte_.noalias() = V.transpose() * S_innovation_;
    Vte_.array() *= inverse_eigenvalues_.array();
    S_innovation_.noalias() = V * Vte_;
  }
  K_ = KT_.transpose();
  nis_ = innovation_.dot(S_innovation_);
  return Status::ok();
}

}  // namespace riccati
