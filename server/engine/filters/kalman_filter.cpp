#include "engine/filters/kalman_filter.hpp"

#include <string>

namespace riccati {

KalmanFilter::KalmanFilter(ModelPtr model, FilterSettings settings) : Filter(std::move(model), std::move(settings)) {
  const Eigen::Index nz = model_->nz(), ny = model_->ny();
  K_ = Eigen::MatrixXd::Zero(nz, ny);
  KT_.resize(ny, nz);
  S_innovation_.resize(ny);
  S_llt_ = Eigen::LLT<Eigen::MatrixXd>(ny);
  S_cod_ = Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd>(ny, ny);
}

Status KalmanFilter::gain_and_nis(const Eigen::MatrixXd& C) {
  // K = C S^-1 is computed as K^T = S^-1 C^T (S symmetric): a solve, never an inverse.
  KT_ = C.transpose();
  S_innovation_ = innovation_;
  if (settings_.inversion == GainInversion::kCholesky) {
    S_llt_.compute(S_);
    if (S_llt_.info() != Eigen::Success) {
      return failed_precondition(
          "innovation covariance S is not positive definite at t = " + std::to_string(t_) +
          " (R has zero variances and the prediction is exact?): give R positive variances or use the "
          "pseudo-inverse gain");
    }
    S_llt_.solveInPlace(KT_);
    S_llt_.solveInPlace(S_innovation_);
  } else {
    S_cod_.compute(S_);
    KT_ = S_cod_.solve(C.transpose());
    S_innovation_ = S_cod_.solve(innovation_);
  }
  K_ = KT_.transpose();
  nis_ = innovation_.dot(S_innovation_);
  return Status::ok();
}

}  // namespace riccati
