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

// P' = F P + P F^T + Q with F = [J; 0] (theta' = 0). With G = P J^T
// (nz x nx), F P = [G^T; 0] and P F^T = [G 0]: only the first nx rows and
// columns of P' differ from Q. G is built column by column as a sum of
// columns of P (contiguous, vectorisable axpys). J is nx x nz; P, P' and Q
// nz x nz; G nz x nx scratch; all column-major. NZ > 0 fixes nz at compile
// time so the inner loops unroll; NZ = 0 is the general case.
template <int NZ>
void covariance_derivative(int nx, int nz_runtime, const double* __restrict J, const double* __restrict P,
                           const double* __restrict Q, double* __restrict G, double* __restrict Pdot) {
  const int nz = NZ > 0 ? NZ : nz_runtime;
  for (int i = 0; i < nx; ++i) {
    double* __restrict g = G + i * nz;
    for (int r = 0; r < nz; ++r) g[r] = J[i] * P[r];
    for (int k = 1; k < nz; ++k) {
      const double a = J[i + k * nx];
      const double* Pk = P + k * nz;
      for (int r = 0; r < nz; ++r) g[r] += a * Pk[r];
    }
  }
  // Each entry written once, block by block: [x x] gets both terms, [x th]
  // and [th x] one each, [th th] only Q. (A zero fill first compiles to a
  // `rep stos` whose start-up cost dominated this kernel.)
  for (int j = 0; j < nz; ++j) {
    const double* Qj = Q + j * nz;
    double* Pdot_j = Pdot + j * nz;
    if (j < nx) {
      const double* g = G + j * nz;  // column j of P F^T
      for (int r = 0; r < nx; ++r) Pdot_j[r] = Qj[r] + g[r] + G[j + r * nz];
      for (int r = nx; r < nz; ++r) Pdot_j[r] = Qj[r] + g[r];
    } else {
      for (int r = 0; r < nx; ++r) Pdot_j[r] = Qj[r] + G[j + r * nz];  // row r of F P
      for (int r = nx; r < nz; ++r) Pdot_j[r] = Qj[r];
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
    PJt_.resize(nz, nx);
    G_.resize(ny, nz);
    PGt_.resize(nz, ny);
    IKG_.resize(nz, nz);
    Pnew_.resize(nz, nz);
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
    covariance_derivative_(nx, nz, jac_f_.data(), y + nx, settings_.Q.data(), PJt_.data(),
                           ydot + nx);
    return Status::ok();
  }

  std::unique_ptr<Integrator> integrator_;
  Rhs rhs_;
  CovarianceDerivativeFn covariance_derivative_ = nullptr;
  // The interval being integrated and its inputs (valid during predict()).
  double t0_ = 0.0, t1_ = 0.0;
  const double* u0_ = nullptr;
  const double* u1_ = nullptr;
  // Work space, sized once.
  std::vector<double> y_;
  Eigen::MatrixXd jac_f_, PJt_, G_, PGt_, IKG_, Pnew_;
};

}  // namespace

std::unique_ptr<Filter> make_ekf(ModelPtr model, const FilterSettings& settings,
                                 std::unique_ptr<Integrator> integrator) {
  return std::make_unique<Ekf>(std::move(model), settings, std::move(integrator));
}

}  // namespace riccati
