// What the two Kalman filters (the EKF and the UKF) share and the optimal
// filter does not: a gain K = C S^-1 from a cross covariance C and the
// innovation covariance S, solved as the settings' inversion says. Private
// to filters/.
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/QR>

#include "engine/filters/filter.hpp"

namespace riccati {

class KalmanFilter : public Filter {
 protected:
  KalmanFilter(ModelPtr model, FilterSettings settings);

  // Solves K S = C for the gain K = C S^-1 ([nz x ny]) with S_ and the NIS of
  // innovation_, without allocating.
  Status gain_and_nis(const Eigen::MatrixXd& C);

  Eigen::MatrixXd K_;  // gain of the last update [nz x ny]

 private:
  // Work space: K^T, S^-1 innovation and the factorisations of S.
  Eigen::MatrixXd KT_;
  Eigen::VectorXd S_innovation_;
  Eigen::LLT<Eigen::MatrixXd> S_llt_;
  Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> S_cod_;
};

}  // namespace riccati
