// On a linear model the continuous-discrete EKF and the UKF must reproduce
// an exact discrete Kalman filter written here from the matrix exponential.
//
// Model (a damped oscillator driven by u plus an unknown constant bias theta):
//     x0' = x1
//     x1' = -4 x0 - 0.4 x1 + u + theta
//     y   = [x0, x1 + 0.1 theta]
// The augmented state z = [x0, x1, theta] obeys z' = Ac z + Bc u, y = C z,
// so every filter's prediction and update are exact linear-Gaussian steps.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <iomanip>
#include <random>
#include <sstream>
#include <string>
#include <unsupported/Eigen/MatrixFunctions>

#include "engine/filters/filter.hpp"
#include "engine/models/model.hpp"
#include "riccati/model.hpp"

namespace riccati {
namespace {

struct LinearOscillator {
  static constexpr ModelSpec<2, 1, 1, 2> spec{
      .name = "linear_oscillator",
      .states = {"x0", "x1"},
      .params = {"bias"},
      .inputs = {"u"},
      .outputs = {"y0", "y1"},
      .theta_default = {0.0},
  };
  template <typename T>
  void f(const T* x, const T* theta, const double* u, double /*t*/, T* dx) const {
    dx[0] = x[1];
    dx[1] = -4.0 * x[0] - 0.4 * x[1] + u[0] + theta[0];
  }
  template <typename T>
  void g(const T* x, const T* theta, const double* /*u*/, double /*t*/, T* y) const {
    y[0] = x[0];
    y[1] = x[1] + 0.1 * theta[0];
  }
};

ModelPtr linear_model() {
  auto m = Model::create(detail::Plugin<LinearOscillator>::entry(RICCATI_MODEL_ABI_VERSION), nullptr,
                         "linear_oscillator (in-process)");
  EXPECT_TRUE(m.is_ok()) << m.status().to_string();
  return m.value();
}

// The exact discrete-time Kalman filter of the augmented linear system, with
// zero-order-hold inputs over each interval dt.
class ExactKalman {
 public:
  // `van_loan_noise`: discretise Q exactly (what the continuous P' = AP + PA'
  // + Q of the EKF integrates to); otherwise add Q dt after the transition
  // (the UKF's model of process noise).
  ExactKalman(const Eigen::MatrixXd& Q, const Eigen::MatrixXd& R, double dt, bool van_loan_noise) : R_(R) {
    Eigen::MatrixXd Ac(3, 3);
    Ac << 0, 1, 0, -4, -0.4, 1, 0, 0, 0;
    Eigen::VectorXd Bc(3);
    Bc << 0, 1, 0;
    C_.resize(2, 3);
    C_ << 1, 0, 0, 0, 1, 0.1;
    // [Ac Bc; 0 0] dt exponentiated gives Phi and the ZOH input matrix Gamma.
    Eigen::MatrixXd M = Eigen::MatrixXd::Zero(4, 4);
    M.topLeftCorner(3, 3) = Ac;
    M.topRightCorner(3, 1) = Bc;
    const Eigen::MatrixXd E = (M * dt).exp();
    Phi_ = E.topLeftCorner(3, 3);
    Gamma_ = E.topRightCorner(3, 1);
    if (van_loan_noise) {
      // Van Loan: exp([-A Q; 0 A^T] dt) = [. Phi^-1 Qd; 0 Phi^T].
      Eigen::MatrixXd V = Eigen::MatrixXd::Zero(6, 6);
      V.topLeftCorner(3, 3) = -Ac;
      V.topRightCorner(3, 3) = Q;
      V.bottomRightCorner(3, 3) = Ac.transpose();
      const Eigen::MatrixXd EV = (V * dt).exp();
      Qd_ = EV.bottomRightCorner(3, 3).transpose() * EV.topRightCorner(3, 3);
    } else {
      Qd_ = Q * dt;
    }
  }
  void reset(const Eigen::VectorXd& z, const Eigen::MatrixXd& P) { z_ = z, P_ = P; }
  // Tracks, from here on, the mean square error E[e e'] of the estimate
  // against a truth that starts at `truth0` and follows Phi and Gamma
  // without process noise, measured as y = C z + v with v ~ N(0, R): the
  // error e = z - z_true evolves linearly, e+ = (I - K C) Phi e - K v, so
  // its second moment is exact, from e0 e0'.
  void track_error_from(const Eigen::VectorXd& truth0) { mse_ = (z_ - truth0) * (z_ - truth0).transpose(); }
  void predict(double u) {
    z_ = Phi_ * z_ + Gamma_ * u;
    P_ = Phi_ * P_ * Phi_.transpose() + Qd_;
    if (mse_.size() > 0) mse_ = Phi_ * mse_ * Phi_.transpose();
  }
  void update(const Eigen::VectorXd& y) {
    const Eigen::MatrixXd S = C_ * P_ * C_.transpose() + R_;
    const Eigen::MatrixXd K = P_ * C_.transpose() * S.inverse();  // fine for a 2x2 reference
    z_ += K * (y - C_ * z_);
    const Eigen::MatrixXd I_KC = Eigen::MatrixXd::Identity(3, 3) - K * C_;
    P_ = I_KC * P_;
    if (mse_.size() > 0) mse_ = I_KC * mse_ * I_KC.transpose() + K * R_ * K.transpose();
  }
  const Eigen::VectorXd& z() const { return z_; }
  const Eigen::MatrixXd& P() const { return P_; }
  const Eigen::MatrixXd& C() const { return C_; }  // y = C z: the model's g
  const Eigen::MatrixXd& mse() const { return mse_; }

 private:
  Eigen::MatrixXd Phi_, Gamma_, Qd_, C_, R_, P_, mse_;
  Eigen::VectorXd z_;
};

struct Case {
  const char* name;
  FilterKind kind;
  IntegratorKind integrator;
  bool zero_noise;     // Q = 0 and zero initial state variances
  double tolerance;    // relative, on z and P at every sample
};

class LinearKalmanTest : public ::testing::TestWithParam<Case> {};

// Numbers in messages, with 6 significant digits (std::to_string's fixed
// 6 decimals print a 1e-12 difference as 0.000000).
template <typename T>
std::string g6(const T& value) {
  std::ostringstream out;
  out << std::setprecision(6) << value;
  return out.str();
}

TEST_P(LinearKalmanTest, MatchesExactDiscreteKalmanFilter) {
  const Case c = GetParam();
  const double dt = 0.1;
  const int steps = 200;
  Eigen::MatrixXd Q = Eigen::Vector3d(0.01, 0.02, 0.001).asDiagonal();
  Eigen::MatrixXd P0 = Eigen::Vector3d(0.5, 0.3, 1.0).asDiagonal();
  if (c.zero_noise) {
    Q.setZero();
    P0 = Eigen::Vector3d(0.0, 0.0, 1.0).asDiagonal();  // states known exactly, bias unknown
  }
  const Eigen::MatrixXd R = Eigen::Vector2d(0.01, 0.04).asDiagonal();

  FilterSettings settings;
  settings.kind = c.kind;
  settings.Q = Q;
  settings.R = R;
  settings.integrator.kind = c.integrator;
  settings.integrator.substeps = 100;  // RK4 error per interval ~ (h |A|)^5 / 120 ~ 1e-15
  settings.integrator.rtol = 1e-11;
  settings.integrator.atol = 1e-13;
  auto filter = make_filter(linear_model(), settings);
  ASSERT_TRUE(filter.is_ok()) << filter.status().to_string();
  Filter& kf = *filter.value();

  ExactKalman exact(Q, R, dt, /*van_loan_noise=*/c.kind == FilterKind::kEkf);
  const Eigen::Vector3d z0(0.2, -0.1, 0.0);
  exact.reset(z0, P0);
  ASSERT_TRUE(kf.reset(0.0, z0, P0).is_ok());

  // A true trajectory with bias 0.3, simulated exactly (the same Phi and
  // Gamma), measured through the model's own equation (C, which is
  // LinearOscillator::g) with noise of exactly R. Where the filters take
  // the states as known (zero_noise), the truth starts there.
  std::mt19937 rng(42);
  std::normal_distribution<double> noise(0.0, 1.0);
  ExactKalman truth(Eigen::MatrixXd::Zero(3, 3), R, dt, true);
  const double true_bias = 0.3;
  const Eigen::Vector3d truth0 =
      c.zero_noise ? Eigen::Vector3d(z0[0], z0[1], true_bias) : Eigen::Vector3d(0.25, 0.0, true_bias);
  truth.reset(truth0, Eigen::MatrixXd::Zero(3, 3));
  exact.track_error_from(truth0);

  double worst = 0.0;
  for (int k = 0; k < steps; ++k) {
    const double u = std::sin(0.05 * k);
    const double u_next = std::sin(0.05 * (k + 1));
    ASSERT_TRUE(kf.predict((k + 1) * dt, &u, &u_next).is_ok());
    exact.predict(u);
    truth.predict(u);
    const Eigen::Vector2d v(std::sqrt(R(0, 0)) * noise(rng), std::sqrt(R(1, 1)) * noise(rng));
    const Eigen::Vector2d y = truth.C() * truth.z() + v;
    const Status updated = kf.update(y.data(), &u_next);
    ASSERT_TRUE(updated.is_ok()) << updated.to_string();
    exact.update(y);

    const double ez = (kf.state() - exact.z()).norm() / std::max(1.0, exact.z().norm());
    const double eP = (kf.covariance() - exact.P()).norm() / std::max(1e-3, exact.P().norm());
    worst = std::max({worst, ez, eP});
    ASSERT_LT(ez, c.tolerance) << "state differs at sample " << k + 1 << ": " << g6(kf.state().transpose())
                               << " against " << g6(exact.z().transpose());
    ASSERT_LT(eP, c.tolerance) << "covariance differs at sample " << k + 1;
  }
  // The data must have taught the filters the bias, or the comparison
  // proves little. How close to the truth the estimate should be is exact
  // here: the root mean square error of the exact filter's bias estimate
  // on this truth (ExactKalman::mse), which the filters under test equal
  // to the tolerance above: 0.037 with process noise (the filters let the
  // bias wander), 0.026 without. The error is Gaussian (linear in the
  // noise) with that RMS, so 4 of it leave out about 1e-4 of noise draws
  // at most, whatever part of the RMS the start's offset is; the seed is
  // fixed, the margin is for the next one. And the RMS must be small (a
  // twentieth of the prior's standard deviation, 1), or the data do not
  // determine the bias.
  const double rms = std::sqrt(exact.mse()(2, 2));
  EXPECT_LT(rms, 0.05) << "the data hardly tell the bias: RMS error " << g6(rms);
  EXPECT_NEAR(kf.state()[2], true_bias, 4 * rms) << "RMS error " << g6(rms);
  RecordProperty("worst_relative_difference", g6(worst));
  RecordProperty("bias_rms_error", g6(rms));
  RecordProperty("bias_error", g6(kf.state()[2] - true_bias));
}

// RK4 with 100 substeps is exact to rounding here, so 1e-9; the adaptive
// integrators are held to their tolerances (1e-11 relative, growing over 200
// samples), so 1e-7.
INSTANTIATE_TEST_SUITE_P(
    Filters, LinearKalmanTest,
    ::testing::Values(Case{"ekf_rk4", FilterKind::kEkf, IntegratorKind::kRk4, false, 1e-9},
                      Case{"ekf_rk4_zero_noise", FilterKind::kEkf, IntegratorKind::kRk4, true, 1e-9},
                      Case{"ukf_rk4", FilterKind::kUkf, IntegratorKind::kRk4, false, 1e-9},
                      Case{"ukf_rk4_zero_noise", FilterKind::kUkf, IntegratorKind::kRk4, true, 1e-9},
                      Case{"ekf_cvode_bdf", FilterKind::kEkf, IntegratorKind::kCvodeBdf, false, 1e-7},
                      Case{"ukf_arkode", FilterKind::kUkf, IntegratorKind::kArkodeErk, false, 1e-7}),
    [](const auto& test_info) { return std::string(test_info.param.name); });

TEST(LinearKalman, GainInversionAndJosephFormAgree) {
  // With a positive definite S the pseudo-inverse gain and the Cholesky
  // solve, and the Joseph and the short covariance update, are the same
  // filter up to rounding.
  FilterSettings base;
  base.kind = FilterKind::kEkf;
  base.Q = Eigen::Vector3d(0.01, 0.02, 0.001).asDiagonal();
  base.R = Eigen::Vector2d(0.01, 0.04).asDiagonal();
  FilterSettings variant = base;
  variant.inversion = GainInversion::kPseudoInverse;
  variant.joseph = false;
  auto a = make_filter(linear_model(), base);
  auto b = make_filter(linear_model(), variant);
  ASSERT_TRUE(a.is_ok() && b.is_ok());
  const Eigen::Vector3d z0(0.2, -0.1, 0.0);
  const Eigen::MatrixXd P0 = Eigen::Vector3d(0.5, 0.3, 1.0).asDiagonal();
  ASSERT_TRUE(a.value()->reset(0, z0, P0).is_ok());
  ASSERT_TRUE(b.value()->reset(0, z0, P0).is_ok());
  for (int k = 0; k < 50; ++k) {
    const double u = 1.0;
    const Eigen::Vector2d y(std::cos(0.1 * k), -std::sin(0.1 * k));
    for (auto* f : {a.value().get(), b.value().get()}) {
      ASSERT_TRUE(f->predict((k + 1) * 0.1, &u, &u).is_ok());
      ASSERT_TRUE(f->update(y.data(), &u).is_ok());
    }
  }
  EXPECT_LT((a.value()->state() - b.value()->state()).norm(), 1e-10);
  EXPECT_LT((a.value()->covariance() - b.value()->covariance()).norm(), 1e-10);
  EXPECT_NEAR(a.value()->nis(), b.value()->nis(), 1e-9);
}

TEST(LinearKalman, SingularInnovationCovarianceNeedsPseudoInverse) {
  // R = 0 and an exactly known state make S singular at the first update:
  // the Cholesky gain refuses with a clear error, the pseudo-inverse copes.
  FilterSettings s;
  s.kind = FilterKind::kEkf;
  s.Q = Eigen::MatrixXd::Zero(3, 3);
  s.R = Eigen::MatrixXd::Zero(2, 2);
  const Eigen::Vector3d z0(0.2, -0.1, 0.0);
  const Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(3, 3);
  const Eigen::Vector2d y(0.2, -0.1);
  const double u = 0.0;

  auto chol = make_filter(linear_model(), s);
  ASSERT_TRUE(chol.is_ok());
  ASSERT_TRUE(chol.value()->reset(0, z0, P0).is_ok());
  const Status st = chol.value()->update(y.data(), &u);
  EXPECT_EQ(st.code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(st.message().find("pseudo-inverse"), std::string::npos) << st.message();

  s.inversion = GainInversion::kPseudoInverse;
  auto pinv = make_filter(linear_model(), s);
  ASSERT_TRUE(pinv.is_ok());
  ASSERT_TRUE(pinv.value()->reset(0, z0, P0).is_ok());
  ASSERT_TRUE(pinv.value()->update(y.data(), &u).is_ok());
  EXPECT_TRUE(pinv.value()->state().isApprox(z0));
}

TEST(LinearKalman, RejectsBadSettings) {
  FilterSettings s;
  s.Q = Eigen::MatrixXd::Zero(2, 2);  // wrong size: nz = 3
  s.R = Eigen::MatrixXd::Identity(2, 2);
  auto f = make_filter(linear_model(), s);
  ASSERT_FALSE(f.is_ok());
  EXPECT_EQ(f.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(f.status().message().find("process noise Q must be 3 x 3"), std::string::npos) << f.status().message();

  s.Q = Eigen::MatrixXd::Zero(3, 3);
  s.R = Eigen::Vector2d(1.0, -1.0).asDiagonal();
  f = make_filter(linear_model(), s);
  ASSERT_FALSE(f.is_ok());
  EXPECT_NE(f.status().message().find("negative variance"), std::string::npos) << f.status().message();
}

}  // namespace
}  // namespace riccati
