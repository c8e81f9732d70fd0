// Continuous-discrete extended Kalman filter (Hensen 1999, ch. 2).
//
// Between samples the state and its covariance are integrated together:
//     x' = f(x, theta, u, t),   theta' = 0
//     P' = F P + P F^T + Q,     F = d[f; 0] / d[x; theta]
// At a sample, with G = dg/d[x; theta] at the prior:
//     S = G P G^T + R,  K = P G^T S^-1,  z += K (y - g),
//     P = (I - K G) P (I - K G)^T + K R K^T   (Joseph form, or (I - K G) P)
#include <Eigen/Core>
#include <algorithm>
#include <string>

#include "engine/filter.hpp"

namespace riccati {

namespace {

// P' = F P + P F^T + Q with F = [J; 0] (theta' = 0): F P has only nx non-zero
// rows, so P' = Q + (F P placed in the top rows) + (its transpose in the left
// columns). J is nx x nz, P and P' nz x nz, FP nx x nz scratch, all
// column-major; Q may be null (zero). NZ > 0 fixes nz at compile time so the
// inner loops unroll; NZ = 0 is the general case.
template <int NZ>
void covariance_derivative(int nx, int nz_runtime, const double* J, const double* P, const double* Q, double* FP,
                           double* Pdot) {
  const int nz = NZ > 0 ? NZ : nz_runtime;
  for (int j = 0; j < nz; ++j) {
    const double* Pj = P + j * nz;
    for (int i = 0; i < nx; ++i) {
      double acc = 0.0;
      for (int k = 0; k < nz; ++k) acc += J[i + k * nx] * Pj[k];
      FP[i + j * nx] = acc;
    }
  }
  // Every entry written once (no zero-fill pass): Q + F P + (F P)^T.
  for (int j = 0; j < nz; ++j) {
    double* Pdot_j = Pdot + j * nz;
    const double* Q_j = Q != nullptr ? Q + j * nz : nullptr;
    for (int i = 0; i < nz; ++i) {
      double v = Q_j != nullptr ? Q_j[i] : 0.0;
      if (i < nx) v += FP[i + j * nx];  // F P
      if (j < nx) v += FP[j + i * nx];  // P F^T = (F P)^T
      Pdot_j[i] = v;
    }
  }
}

using CovarianceDerivativeFn = void (*)(int, int, const double*, const double*, const double*, double*, double*);

// The kernel for a given nz: unrolled for the sizes of typical grey-box
// models, general beyond.
CovarianceDerivativeFn covariance_derivative_for(int nz) {
  switch (nz) {
    case 1: return &covariance_derivative<1>;
    case 2: return &covariance_derivative<2>;
    case 3: return &covariance_derivative<3>;
    case 4: return &covariance_derivative<4>;
    case 5: return &covariance_derivative<5>;
    case 6: return &covariance_derivative<6>;
    case 7: return &covariance_derivative<7>;
    case 8: return &covariance_derivative<8>;
    case 9: return &covariance_derivative<9>;
    case 10: return &covariance_derivative<10>;
    case 11: return &covariance_derivative<11>;
    case 12: return &covariance_derivative<12>;
    default: return &covariance_derivative<0>;
  }
}

class Ekf final : public Filter {
 public:
  Ekf(ModelPtr model, const FilterSettings& settings, std::unique_ptr<Integrator> integrator)
      : Filter(std::move(model), settings), integrator_(std::move(integrator)), rhs_(this) {
    const int nx = model_->nx(), nz = model_->nz(), ny = model_->ny();
    y_.resize(nx + nz * nz);
    jac_f_.resize(nx, nz);
    FP_.resize(nx, nz);
    G_.resize(ny, nz);
    PGt_.resize(nz, ny);
    IKG_.resize(nz, nz);
    Pnew_.resize(nz, nz);
    q_is_zero_ = settings_.Q.isZero(0.0);
    covariance_derivative_ = covariance_derivative_for(nz);
  }

  Status predict(double t1, const double* u0, const double* u1) override {
    if (!(t1 > t_)) {
      return invalid_argument("predict to t = " + std::to_string(t1) + " is not after the filter's time " +
                              std::to_string(t_));
    }
    const int nx = model_->nx(), nz = model_->nz();
    Eigen::Map<Eigen::VectorXd>(y_.data(), nx) = z_.head(nx);
    Eigen::Map<Eigen::MatrixXd>(y_.data() + nx, nz, nz) = P_;
    t0_ = t_;
    t1_ = t1;
    u0_ = u0;
    u1_ = u1;
    Status s = integrator_->integrate(rhs_, t_, t1, y_);
    if (!s.is_ok()) return s.with_context("EKF prediction from t = " + std::to_string(t_));
    z_.head(nx) = Eigen::Map<const Eigen::VectorXd>(y_.data(), nx);
    const Eigen::Map<const Eigen::MatrixXd> P(y_.data() + nx, nz, nz);
    P_ = 0.5 * (P + P.transpose());
    t_ = t1;
    return check_estimate("EKF prediction");
  }

  Status update(const double* y, const double* u) override {
    const int nx = model_->nx(), ny = model_->ny();
    RICCATI_RETURN_IF_ERROR(model_->g_jacobian(t_, u, z_.data(), z_.data() + nx, y_pred_.data(), G_.data())
                                .with_context("EKF update"));
    for (int i = 0; i < ny; ++i) innovation_[i] = y[i] - y_pred_[i];
    PGt_.noalias() = P_ * G_.transpose();
    S_.noalias() = G_ * PGt_;
    S_ += settings_.R;
    RICCATI_RETURN_IF_ERROR(gain_and_nis(PGt_));
    z_.noalias() += K_ * innovation_;
    if (settings_.joseph) {
      IKG_.setIdentity();
      IKG_.noalias() -= K_ * G_;
      Pnew_.noalias() = IKG_ * P_ * IKG_.transpose();
      Pnew_.noalias() += K_ * settings_.R * K_.transpose();
      P_ = 0.5 * (Pnew_ + Pnew_.transpose());
    } else {
      Pnew_ = P_;
      Pnew_.noalias() -= K_ * PGt_.transpose();
      P_ = 0.5 * (Pnew_ + Pnew_.transpose());
    }
    return check_estimate("EKF update");
  }

 private:
  // The joint system [x; vec(P)] integrated between two samples.
  class Rhs final : public OdeRhs {
   public:
    explicit Rhs(Ekf* ekf) : ekf_(ekf) {}
    Status eval(double t, const double* y, double* ydot) override { return ekf_->derivatives(t, y, ydot); }

   private:
    Ekf* ekf_;
  };

  Status derivatives(double t, const double* y, double* ydot) {
    const int nx = model_->nx(), nz = model_->nz();
    hold_input(t, t0_, t1_, u0_, u1_);
    const double* theta = z_.data() + nx;  // constant over the interval
    RICCATI_RETURN_IF_ERROR(model_->f_jacobian(t, u_hold_.data(), y, theta, ydot, jac_f_.data()));
    covariance_derivative_(nx, nz, jac_f_.data(), y + nx, q_is_zero_ ? nullptr : settings_.Q.data(), FP_.data(),
                           ydot + nx);
    return Status::ok();
  }

  std::unique_ptr<Integrator> integrator_;
  Rhs rhs_;
  bool q_is_zero_ = false;
  CovarianceDerivativeFn covariance_derivative_ = nullptr;
  // The interval being integrated and its inputs (valid during predict()).
  double t0_ = 0.0, t1_ = 0.0;
  const double* u0_ = nullptr;
  const double* u1_ = nullptr;
  // Work space, sized once.
  std::vector<double> y_;
  Eigen::MatrixXd jac_f_, FP_, G_, PGt_, IKG_, Pnew_;
};

}  // namespace

std::unique_ptr<Filter> make_ekf(ModelPtr model, const FilterSettings& settings,
                                 std::unique_ptr<Integrator> integrator) {
  return std::make_unique<Ekf>(std::move(model), settings, std::move(integrator));
}

}  // namespace riccati
