// The Kalman filters' gain with a singular innovation covariance S: the
// pseudo-inverse option must give the minimum-norm gain K = P G^T S^+, here
// checked against Eigen's complete orthogonal decomposition (an independent
// minimum-norm solver) on the two-tank model, whose outputs are its two
// states (G = [I 0]).
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include "engine/filters/filter.hpp"
#include "engine/models/plugin_loader.hpp"

namespace riccati {
namespace {

TEST(KalmanGain, PseudoInverseGainIsTheMinimumNormOneWhenSIsSingular) {
  const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  FilterSettings s;
  s.kind = FilterKind::kEkf;
  s.inversion = GainInversion::kPseudoInverse;
  s.Q = Eigen::MatrixXd::Zero(6, 6);
  s.R = Eigen::MatrixXd::Zero(2, 2);  // exact measurements
  // h1 uncertain (and correlated with A1), h2 known exactly: S = G P G^T = diag(0.04, 0) has rank 1.
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(6, 6);
  P0(0, 0) = 0.04;
  P0(2, 2) = 4.0;
  P0(0, 2) = P0(2, 0) = 0.2;
  Eigen::VectorXd z0(6);
  z0 << 0.4, 0.15, 10, 5, 0.08, 0.13;
  const Eigen::Vector2d y(0.43, 0.17);  // both outputs disagree with the prior
  const Eigen::Vector2d u(1e-4, 0.0);

  for (bool joseph : {true, false}) {
    s.joseph = joseph;
    auto filter = make_filter(registry.find("two_tank"), s);
    ASSERT_TRUE(filter.is_ok()) << filter.status().to_string();
    ASSERT_TRUE(filter.value()->reset(0.0, z0, P0).is_ok());
    ASSERT_TRUE(filter.value()->update(y.data(), u.data()).is_ok());

    Eigen::MatrixXd G = Eigen::MatrixXd::Zero(2, 6);
    G.leftCols(2).setIdentity();
    const Eigen::MatrixXd S = G * P0 * G.transpose();
    const Eigen::MatrixXd S_pinv = S.completeOrthogonalDecomposition().pseudoInverse();
    const Eigen::MatrixXd K = P0 * G.transpose() * S_pinv;
    const Eigen::Vector2d e = y - z0.head(2);
    const Eigen::VectorXd z = z0 + K * e;
    const Eigen::MatrixXd IKG = Eigen::MatrixXd::Identity(6, 6) - K * G;
    const Eigen::MatrixXd P = IKG * P0 * IKG.transpose();
    // The exact h1 is taken, h2's innovation is ignored (S has no variance there), A1 moves with h1.
    EXPECT_NEAR(z[0], 0.43, 1e-12);
    EXPECT_NEAR(z[1], 0.15, 1e-12);
    EXPECT_LT((filter.value()->state() - z).norm(), 1e-12) << "joseph " << joseph;
    EXPECT_LT((filter.value()->covariance() - P).norm(), 1e-12) << "joseph " << joseph;
    EXPECT_NEAR(filter.value()->nis(), e.dot(S_pinv * e), 1e-12);
  }
}

}  // namespace
}  // namespace riccati
