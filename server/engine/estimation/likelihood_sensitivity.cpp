#include "engine/estimation/likelihood_sensitivity.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <span>
#include <string>
#include <vector>

#include "engine/filters/fixed_size.hpp"
#include "engine/models/input_hold.hpp"

namespace riccati {

// What one run keeps: the point, the directions, the integrated vector
// w = [x; vec P; dx_1 .. dx_m; vec dP_1 .. vec dP_m] and scratch space.
struct LikelihoodSensitivity::Work {
  Work(const Model& model, HoldOrder order) : hold(order, model.nu()) {
    const int nx = model.nx(), ny = model.ny(), nz = model.nz();
    J.resize(nx, nz);
    H.resize(nx * nz, nz);
    Gfull.resize(ny, nz);
    Hg.resize(ny * nz, nz);
    y_pred.resize(ny);
    dz.resize(nz);
  }

  Eigen::Index m = 0;  // directions
  // Whether the run needs the model's second derivatives: only where the
  // covariance or its sensitivities can be non-zero (P0, Q or a direction
  // of Q non-zero). Without, P stays zero and the run is output error's.
  bool second_order = false;
  Eigen::VectorXd theta;
  Eigen::MatrixXd Q, R;
  const LikelihoodDirections* directions = nullptr;
  InputHold hold;
  Eigen::VectorXd w;
  // Scratch: f's Jacobian and second derivatives [(nx nz) x nz], g's, and
  // the update's matrices (sized on first use, reused after).
  Eigen::MatrixXd J, H, Gfull, Hg;
  Eigen::VectorXd y_pred, dz;
  Eigen::LLT<Eigen::MatrixXd> llt;
  Eigen::VectorXd e, white, de, white_d, dG_all;  // e, w = L^-1 e, de, a = L^-1 de, dG as a vector
  Eigen::MatrixXd A, X;  // per sample: a_c and vec(X_c) of each direction (likelihood_sensitivity.hpp)
  Eigen::MatrixXd PGt, S, Kt, dGPGt, dPGt, dS, Xc, dKt, SKt, dKSKt, dSKt, IKG, IKGP, P_new, RKt;
};

namespace {

// The derivatives of [x; P; dx_c; dP_c] at one point, given f, its Jacobian
// J = [F F_theta] (nx x nz) and its second derivatives H ((nx nz) x nz,
// model_abi.h's layout), all column-major; `directions` as in the header;
// `scratch` holds 3 nx^2 + nz. It runs at every stage of every integration
// step: NX fixes nx at compile time (fixed_size.hpp) so the loops unroll.
template <int NX>
void sensitivity_derivative(int nx_runtime, int nz, int m, const double* __restrict J, const double* __restrict H,
                            const double* __restrict Q, const LikelihoodDirections& directions,
                            const double* __restrict w, double* __restrict wdot, double* __restrict scratch) {
  const int nx = size_or<NX>(nx_runtime);
  const int nn = nx * nx;
  const double* F_theta = J + nn;
  const double* P = w + nx;
  double* A = scratch;       // F P, then dF P + F dP
  double* dF = A + nn;       // d(df/dx) along a direction
  double* dz = dF + nn;      // [dx; dtheta]
  const auto product_plus_transpose = [&](double* out, const double* add) {  // out = A + A^T + add
    for (int c = 0; c < nx; ++c) {
      for (int r = 0; r < nx; ++r) out[r + c * nx] = A[r + c * nx] + A[c + r * nx] + add[r + c * nx];
    }
  };
  // A = F P.
  for (int c = 0; c < nx; ++c) {
    for (int r = 0; r < nx; ++r) {
      double sum = 0.0;
      for (int i = 0; i < nx; ++i) sum += J[r + i * nx] * P[i + c * nx];
      A[r + c * nx] = sum;
    }
  }
  product_plus_transpose(wdot + nx, Q);
  const double* dx_all = w + nx + nn;
  const double* dP_all = dx_all + nx * m;
  double* dx_dot_all = wdot + nx + nn;
  double* dP_dot_all = dx_dot_all + nx * m;
  const int nth = nz - nx;
  for (int c = 0; c < m; ++c) {
    const double* dx = dx_all + c * nx;
    const double* dP = dP_all + c * nn;
    const double* dtheta = directions.theta.data() + static_cast<Eigen::Index>(c) * nth;
    for (int i = 0; i < nx; ++i) dz[i] = dx[i];
    for (int j = 0; j < nth; ++j) dz[nx + j] = dtheta[j];
    // dF(i, a) = sum_b H(i, a, b) dz_b, over the state columns a < nx (zero
    // without H: the covariance and its sensitivities stay zero).
    for (int i = 0; i < nn; ++i) dF[i] = 0.0;
    for (int b = 0; b < nz && H != nullptr; ++b) {
      const double d = dz[b];
      if (d == 0.0) continue;
      const double* Hb = H + static_cast<std::ptrdiff_t>(b) * nx * nz;
      for (int i = 0; i < nn; ++i) dF[i] += Hb[i] * d;
    }
    // dx' = F dx + F_theta dtheta.
    double* dx_dot = dx_dot_all + c * nx;
    for (int r = 0; r < nx; ++r) {
      double sum = 0.0;
      for (int i = 0; i < nx; ++i) sum += J[r + i * nx] * dx[i];
      for (int j = 0; j < nth; ++j) sum += F_theta[r + j * nx] * dtheta[j];
      dx_dot[r] = sum;
    }
    // dP' = B + B^T + diag(dq), B = dF P + F dP.
    for (int col = 0; col < nx; ++col) {
      for (int r = 0; r < nx; ++r) {
        double sum = 0.0;
        for (int i = 0; i < nx; ++i) sum += dF[r + i * nx] * P[i + col * nx] + J[r + i * nx] * dP[i + col * nx];
        A[r + col * nx] = sum;
      }
    }
    double* dP_dot = dP_dot_all + c * nn;
    for (int col = 0; col < nx; ++col) {
      for (int r = 0; r < nx; ++r) dP_dot[r + col * nx] = A[r + col * nx] + A[col + r * nx];
    }
    const double* dq = directions.q.data() + static_cast<Eigen::Index>(c) * nx;
    for (int i = 0; i < nx; ++i) dP_dot[i + i * nx] += dq[i];
  }
}

using SensitivityDerivativeFn = void (*)(int, int, int, const double*, const double*, const double*,
                                         const LikelihoodDirections&, const double*, double*, double*);

}  // namespace

class LikelihoodSensitivity::Rhs final : public OdeRhs {
 public:
  Rhs(const Model& model, Work& work)
      : model_(model),
        work_(work),
        kernel_(kernel_for<1, kMaxFixedSize>(model.nx(), []<int NX>() { return &sensitivity_derivative<NX>; })),
        scratch_(static_cast<std::size_t>(3 * model.nx() * model.nx() + model.nz())) {}

  Status eval(double t, const double* w, double* wdot) override {
    Work& k = work_;
    const double* u = k.hold.at(t);
    if (!k.second_order) {
      RICCATI_RETURN_IF_ERROR(model_.f_jacobian(t, u, w, k.theta.data(), wdot, k.J.data()));
    } else {
      RICCATI_RETURN_IF_ERROR(model_.f_hessian(t, u, w, k.theta.data(), wdot, k.J.data(), k.H.data()));
    }
    kernel_(model_.nx(), model_.nz(), static_cast<int>(k.m), k.J.data(), k.second_order ? k.H.data() : nullptr,
            k.Q.data(), *k.directions, w, wdot, scratch_.data());
    return Status::ok();
  }

 private:
  const Model& model_;
  Work& work_;
  SensitivityDerivativeFn kernel_;
  std::vector<double> scratch_;
};

Status LikelihoodSensitivity::available(const Model& model, const FilterSettings& filter) {
  if (filter.kind != FilterKind::kEkf) return failed_precondition("the UKF predictor has no exact gradient here");
  if (filter.inversion != GainInversion::kCholesky) {
    return failed_precondition("the pseudo-inverse gain has no exact gradient");
  }
  if (!model.has_second_derivatives()) {
    return failed_precondition("model " + model.name() + " gives no second derivatives");
  }
  return Status::ok();
}

Result<LikelihoodSensitivity> LikelihoodSensitivity::create(ModelPtr model, const FilterSettings& filter,
                                                           Eigen::MatrixXd P0x) {
  if (model == nullptr) return invalid_argument("no model given");
  RICCATI_RETURN_IF_ERROR(available(*model, filter));
  RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Integrator> integrator, make_integrator(filter.integrator));
  return LikelihoodSensitivity(std::move(model), filter.hold, std::move(integrator), std::move(P0x));
}

LikelihoodSensitivity::LikelihoodSensitivity(ModelPtr model, HoldOrder hold, std::unique_ptr<Integrator> integrator,
                                             Eigen::MatrixXd P0x)
    : model_(std::move(model)),
      integrator_(std::move(integrator)),
      work_(std::make_unique<Work>(*model_, hold)),
      rhs_(std::make_unique<Rhs>(*model_, *work_)),
      P0x_(std::move(P0x)) {}

LikelihoodSensitivity::LikelihoodSensitivity(LikelihoodSensitivity&&) noexcept = default;
LikelihoodSensitivity& LikelihoodSensitivity::operator=(LikelihoodSensitivity&&) noexcept = default;
LikelihoodSensitivity::~LikelihoodSensitivity() = default;

Status LikelihoodSensitivity::accumulate(const Experiment& ex, const LikelihoodPoint& at,
                                         const LikelihoodDirections& directions, bool derivatives,
                                         LikelihoodDerivatives* out) {
  return pass(ex, at, directions, derivatives ? directions.size() : 0, out);
}

// One pass of the filter over the experiment with m directions, adding to `sums`.
Status LikelihoodSensitivity::pass(const Experiment& ex, const LikelihoodPoint& at,
                                   const LikelihoodDirections& directions, Eigen::Index m,
                                   LikelihoodDerivatives* sums) {
  Work& k = *work_;
  const Eigen::Index nx = model_->nx();
  const Dataset& d = ex.data;
  const Eigen::Index N = d.size();
  k.m = m;
  k.second_order = m > 0 && !(P0x_.isZero(0.0) && at.Q.isZero(0.0) && directions.q.isZero(0.0));
  if (!k.second_order) k.Hg.setZero();  // dG then multiplies P and dP, both zero: no second derivatives
  k.theta = at.theta;
  k.Q = at.Q;
  k.R = at.R;
  k.directions = &directions;
  k.w.setZero(nx + nx * nx + m * (nx + nx * nx));
  k.w.head(nx) = at.x0;
  Eigen::Map<Eigen::MatrixXd>(k.w.data() + nx, nx, nx) = P0x_;
  for (Eigen::Index c = 0; c < m; ++c) k.w.segment(nx + nx * nx + c * nx, nx) = directions.x0.col(c);
  const bool masked = ex.mask.size() != 0;
  for (Eigen::Index s = 0; s < N; ++s) {
    const double* u = d.u.col(s).data();
    if (s > 0) {
      k.hold.set_interval(d.t[s - 1], d.t[s], d.u.col(s - 1).data(), u);
      const Status st = integrator_->integrate(*rhs_, d.t[s - 1], d.t[s], {k.w.data(), static_cast<std::size_t>(k.w.size())});
      if (!st.is_ok()) {
        return st.with_context("the likelihood's sensitivities, sample " + std::to_string(s + 1) +
                               " (t = " + std::to_string(d.t[s]) + ")");
      }
      // P and each dP are symmetric; the filter symmetrises P after its prediction too.
      for (Eigen::Index c = 0; c <= m; ++c) {
        double* p = k.w.data() + nx + (c == 0 ? 0 : nx * nx + m * nx + (c - 1) * nx * nx);
        Eigen::Map<Eigen::MatrixXd> M(p, nx, nx);
        M = (0.5 * (M + M.transpose())).eval();
      }
      RICCATI_RETURN_IF_ERROR(check_estimate(d.t[s], "EKF prediction").with_context("sample " + std::to_string(s + 1)));
    }
    if (masked && !(ex.mask.col(s) != 0.0).all()) continue;
    RICCATI_RETURN_IF_ERROR(update(d.t[s], u, d.y.col(s).data(), m, sums).with_context("sample " + std::to_string(s + 1)));
    RICCATI_RETURN_IF_ERROR(check_estimate(d.t[s], "EKF update").with_context("sample " + std::to_string(s + 1)));
  }
  return Status::ok();
}

// The filter's own test of a diverged run (Filter::check_estimate), on the
// states and their covariance: the same points fail here as there, so that
// the minimisation steps back from them alike.
Status LikelihoodSensitivity::check_estimate(double t, const char* where) const {
  const Eigen::Index nx = model_->nx();
  const Eigen::Map<const Eigen::VectorXd> x(work_->w.data(), nx);
  const Eigen::Map<const Eigen::MatrixXd> P(work_->w.data() + nx, nx, nx);
  const auto diverged = [&](const std::string& what) {
    return failed_precondition("filter diverged: " + what + " after the " + where + " at t = " + std::to_string(t));
  };
  for (Eigen::Index i = 0; i < nx; ++i) {
    const std::string& name = model_->state_names()[static_cast<std::size_t>(i)];
    if (!std::isfinite(x[i])) return diverged("the estimate of state " + name + " is " + std::to_string(x[i]));
    if (!P.row(i).allFinite()) return diverged("the covariance of state " + name + " is not finite");
  }
  const double scale = std::max(1.0, P.diagonal().cwiseAbs().maxCoeff());
  for (Eigen::Index i = 0; i < nx; ++i) {
    if (P(i, i) < -1e-9 * scale) {
      return diverged("the covariance lost positive semi-definiteness (the variance of state " +
                      model_->state_names()[static_cast<std::size_t>(i)] + " is " + std::to_string(P(i, i)) + ")");
    }
  }
  return Status::ok();
}

// The measurement update at one sample with its derivatives, adding the
// sample's terms to `sums`. Every matrix is the Work's, sized on first use:
// a run allocates nothing per sample after its first.
Status LikelihoodSensitivity::update(double t, const double* u, const double* y, Eigen::Index m,
                                     LikelihoodDerivatives* sums) {
  Work& k = *work_;
  const Eigen::Index nx = model_->nx(), ny = model_->ny();
  double* w = k.w.data();
  if (!k.second_order) {
    RICCATI_RETURN_IF_ERROR(model_->g_jacobian(t, u, w, k.theta.data(), k.y_pred.data(), k.Gfull.data()));
  } else {
    RICCATI_RETURN_IF_ERROR(model_->g_hessian(t, u, w, k.theta.data(), k.y_pred.data(), k.Gfull.data(), k.Hg.data()));
  }
  Eigen::Map<Eigen::VectorXd> x(w, nx);
  Eigen::Map<Eigen::MatrixXd> P(w + nx, nx, nx);
  const auto G = k.Gfull.leftCols(nx);
  k.e = Eigen::Map<const Eigen::VectorXd>(y, ny) - k.y_pred;
  k.PGt.noalias() = P * G.transpose();
  k.S.noalias() = G * k.PGt;
  k.S += k.R;
  k.llt.compute(k.S);
  if (k.llt.info() != Eigen::Success) {
    return failed_precondition("innovation covariance not positive definite at t = " + std::to_string(t));
  }
  const auto L = k.llt.matrixL();
  k.white = k.e;
  L.solveInPlace(k.white);
  sums->logdet += 2.0 * k.llt.matrixLLT().diagonal().array().log().sum();
  sums->quadratic += k.white.squaredNorm();
  sums->measurements += static_cast<double>(ny);
  k.A.resize(ny, m);
  k.X.resize(ny * ny, m);
  k.Kt = k.PGt.transpose();  // K^T = S^-1 G P
  k.llt.solveInPlace(k.Kt);
  if (m > 0) {
    k.SKt.noalias() = k.S * k.Kt;
    double* dx_all = w + nx + nx * nx;
    double* dP_all = dx_all + nx * m;
    const Eigen::Index nz = model_->nz();
    for (Eigen::Index c = 0; c < m; ++c) {
      Eigen::Map<Eigen::VectorXd> dx(dx_all + c * nx, nx);
      Eigen::Map<Eigen::MatrixXd> dP(dP_all + c * nx * nx, nx, nx);
      k.dz.head(nx) = dx;
      k.dz.tail(nz - nx) = k.directions->theta.col(c);
      // dG: g's second derivatives along dz, the state columns.
      k.dG_all.noalias() = k.Hg.topRows(ny * nx) * k.dz;
      const Eigen::Map<const Eigen::MatrixXd> dG(k.dG_all.data(), ny, nx);
      k.de.noalias() = -(k.Gfull * k.dz);
      // dS = dG P G^T + G dP G^T + G P dG^T + dR.
      k.dGPGt.noalias() = dG * k.PGt;
      k.dPGt.noalias() = dP * G.transpose();
      k.dS.noalias() = G * k.dPGt;
      k.dS += k.dGPGt + k.dGPGt.transpose();
      k.dS.diagonal() += k.directions->r.col(c);
      // X_c = L^-1 dS L^-T, a_c = L^-1 de.
      k.Xc = k.dS;
      L.solveInPlace(k.Xc);
      k.Xc.transposeInPlace();
      L.solveInPlace(k.Xc);
      k.white_d = k.de;
      L.solveInPlace(k.white_d);
      // dL = a' w - 1/2 w' X w + 1/2 tr X  (d ln det S = tr(S^-1 dS) = tr X).
      k.A.col(c) = k.white_d;
      k.X.col(c) = Eigen::Map<const Eigen::VectorXd>(k.Xc.data(), ny * ny);
      sums->gradient[c] += k.white_d.dot(k.white) - 0.5 * k.white.dot(k.Xc * k.white) + 0.5 * k.Xc.trace();
      // dK = (dP G^T + P dG^T - K dS) S^-1, as dK^T = S^-1 (G dP + dG P - dS K^T).
      k.dPGt.noalias() += P * dG.transpose();
      k.dKt = k.dPGt.transpose();
      k.dKt.noalias() -= k.dS * k.Kt;
      k.llt.solveInPlace(k.dKt);
      // dx+ = dx + dK e + K de;  dP+ = dP - dK S K^T - K S dK^T - K dS K^T.
      dx.noalias() += k.dKt.transpose() * k.e;
      dx.noalias() += k.Kt.transpose() * k.de;
      k.dKSKt.noalias() = k.dKt.transpose() * k.SKt;
      dP -= k.dKSKt;
      dP -= k.dKSKt.transpose();
      k.dSKt.noalias() = k.dS * k.Kt;
      dP.noalias() -= k.Kt.transpose() * k.dSKt;
    }
    sums->fisher.noalias() += k.A.transpose() * k.A;
    sums->fisher.noalias() += 0.5 * k.X.transpose() * k.X;  // vec(X_c)' vec(X_d) = tr(X_c X_d)
  }
  // The Joseph form, as the filter's: (I - K G) P (I - K G)^T + K R K^T.
  x.noalias() += k.Kt.transpose() * k.e;
  k.IKG.noalias() = -k.Kt.transpose() * G;
  k.IKG.diagonal().array() += 1.0;
  k.IKGP.noalias() = k.IKG * P;
  k.P_new.noalias() = k.IKGP * k.IKG.transpose();
  k.RKt.noalias() = k.R * k.Kt;
  k.P_new.noalias() += k.Kt.transpose() * k.RKt;
  P = 0.5 * (k.P_new + k.P_new.transpose());
  return Status::ok();
}

}  // namespace riccati
