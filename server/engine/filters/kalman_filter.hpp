// What the two Kalman filters (the EKF and the UKF) share and the optimal
// filter does not: a gain K = C S^-1 from a cross covariance C and the
// innovation covariance S, solved as the settings' inversion says. Private
// to filters/.
#pragma once

#include <Eigen/Eigenvalues>

#include "engine/filters/filter.hpp"
#include "engine/filters/small_cholesky.hpp"

namespace riccati {

class KalmanFilter : public Filter {
 protected:
  KalmanFilter(ModelPtr model, FilterSettings settings);

  // Solves K S = C for the gain K = C S^-1 ([nz x ny]) with S_ and the NIS of
  // innovation_, without allocating.
  Status gain_and_nis(const Eigen::MatrixXd& C);

  Eigen::MatrixXd K_;  // gain of the last update [nz x ny]

 private:
  // Work space: K^T, S^-1 innovation and the factorisations of S (the
  // pseudo-inverse from S's eigen decomposition, S being symmetric).
  Eigen::MatrixXd KT_, VtCt_, V_;
  Eigen::VectorXd S_innovation_, Vte_, inverse_eigenvalues_;
  Eigen::MatrixXd S_factor_;  // S's Cholesky factor (small_cholesky.hpp)
  CholeskySolveFn S_solve_ = nullptr;
  // S = Q T Q^T (tridiagonal T), T = Z D Z^T, so S = V D V^T with V = Q Z: Eigen's
  // SelfAdjointEigenSolver in its steps, to pass the workspace it would allocate.
  Eigen::Tridiagonalization<Eigen::MatrixXd> S_tridiagonal_;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> T_eigen_;
  Eigen::VectorXd T_diagonal_, T_subdiagonal_, householder_workspace_;
};

}  // namespace riccati
