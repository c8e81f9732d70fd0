#include "engine/estimation/sensitivity.hpp"

#include <span>
#include <string>

#include "engine/models/variational.hpp"

namespace riccati {

// The right-hand side of [x; vec S] (S column-major: dx/dtheta, nx x
// ntheta, or [dx/dx0 dx/dtheta] with the initial states' columns), or of x
// alone.
class SensitivitySimulator::Rhs final : public OdeRhs {
 public:
  Rhs(const Model& model, HoldOrder hold, bool x0_columns)
      : model_(model),
        hold_(hold, model.nu()),
        unforced_(x0_columns ? model.nx() : 0),
        m_(model.ntheta() + unforced_),
        jac_(model.nx(), model.nz()),
        variational_(variational_derivative_for(model.nx())) {}

  void set_interval(double t0, double t1, const double* u0, const double* u1, const double* theta,
                    bool sensitivities) {
    hold_.set_interval(t0, t1, u0, u1);
    theta_ = theta;
    sensitivities_ = sensitivities;
  }

  int columns() const { return m_; }

  Status eval(double t, const double* w, double* wdot) override {
    const int nx = model_.nx();
    const double* u = hold_.at(t);
    if (!sensitivities_) return model_.f(t, u, 1, 1, w, theta_, wdot);
    RICCATI_RETURN_IF_ERROR(model_.f_jacobian(t, u, w, theta_, wdot, jac_.data()));
    variational_(nx, m_, unforced_, jac_.data(), w + nx, wdot + nx);
    return Status::ok();
  }

 private:
  const Model& model_;
  InputHold hold_;
  const int unforced_, m_;
  Eigen::MatrixXd jac_;  // [f_x f_theta], nx x nz
  const VariationalDerivativeFn variational_;
  const double* theta_ = nullptr;
  bool sensitivities_ = true;
};

Result<SensitivitySimulator> SensitivitySimulator::create(ModelPtr model, const SimulationSettings& settings,
                                                          bool x0_sensitivities) {
  if (model == nullptr) return invalid_argument("no model given");
  RICCATI_RETURN_IF_ERROR(validate(settings.integrator));
  RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Integrator> values, make_integrator(settings.integrator));
  RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Integrator> sensitivities, make_integrator(settings.integrator));
  return SensitivitySimulator(std::move(model), settings.hold, std::move(values), std::move(sensitivities),
                              x0_sensitivities);
}

SensitivitySimulator::SensitivitySimulator(ModelPtr model, HoldOrder hold, std::unique_ptr<Integrator> values,
                                           std::unique_ptr<Integrator> sensitivities, bool x0_sensitivities)
    : model_(std::move(model)),
      values_integrator_(std::move(values)),
      sensitivity_integrator_(std::move(sensitivities)),
      x0_sensitivities_(x0_sensitivities),
      rhs_(std::make_unique<Rhs>(*model_, hold, x0_sensitivities)) {
  const int nx = model_->nx();
  w_.resize(nx + nx * rhs_->columns());
  g_jac_.resize(model_->ny(), model_->nz());
  y_.resize(model_->ny());
}

SensitivitySimulator::SensitivitySimulator(SensitivitySimulator&&) noexcept = default;
SensitivitySimulator& SensitivitySimulator::operator=(SensitivitySimulator&&) noexcept = default;
SensitivitySimulator::~SensitivitySimulator() = default;

Status SensitivitySimulator::simulate(const Eigen::VectorXd& t, const Eigen::MatrixXd& u, const Eigen::VectorXd& x0,
                                      const Eigen::VectorXd& theta, bool sensitivities, SimulatedRecord* out) {
  const Model& model = *model_;
  const int nx = model.nx(), ny = model.ny(), ntheta = model.ntheta();
  const Eigen::Index N = t.size(), m = rhs_->columns();
  if (u.rows() != model.nu() || u.cols() != N || x0.size() != nx || theta.size() != ntheta) {
    return invalid_argument("simulation of " + model.name() + ": sizes do not fit the model");
  }
  out->x.resize(nx, N);
  out->y.resize(ny, N);
  if (sensitivities) {
    out->dy_dtheta.resize(N * ny, ntheta);
    if (x0_sensitivities_) out->dy_dx0.resize(N * ny, nx);
  }
  w_.head(nx) = x0;
  if (sensitivities) {
    Eigen::Map<Eigen::MatrixXd> S(w_.data() + nx, nx, m);
    S.setZero();
    if (x0_sensitivities_) S.leftCols(nx).setIdentity();
  }
  const Eigen::Index size = sensitivities ? w_.size() : nx;
  Integrator& integrator = sensitivities ? *sensitivity_integrator_ : *values_integrator_;
  for (Eigen::Index k = 0; k < N; ++k) {
    if (k > 0) {
      rhs_->set_interval(t[k - 1], t[k], u.col(k - 1).data(), u.col(k).data(), theta.data(), sensitivities);
      const Status s = integrator.integrate(*rhs_, t[k - 1], t[k], std::span<double>(w_.data(), size));
      if (!s.is_ok()) return s.with_context("simulation, sample " + std::to_string(k + 1));
    }
    out->x.col(k) = w_.head(nx);
    if (!sensitivities) {
      RICCATI_RETURN_IF_ERROR(model.g(t[k], u.col(k).data(), 1, 1, w_.data(), theta.data(), out->y.col(k).data())
                                  .with_context("sample " + std::to_string(k + 1)));
      continue;
    }
    RICCATI_RETURN_IF_ERROR(model.g_jacobian(t[k], u.col(k).data(), w_.data(), theta.data(), y_.data(), g_jac_.data())
                                .with_context("sample " + std::to_string(k + 1)));
    out->y.col(k) = y_;
    const Eigen::Map<const Eigen::MatrixXd> S(w_.data() + nx, nx, m);
    auto rows_theta = out->dy_dtheta.middleRows(k * ny, ny);
    rows_theta.noalias() = g_jac_.leftCols(nx) * S.rightCols(ntheta);
    rows_theta += g_jac_.rightCols(ntheta);
    if (x0_sensitivities_) out->dy_dx0.middleRows(k * ny, ny).noalias() = g_jac_.leftCols(nx) * S.leftCols(nx);
  }
  return Status::ok();
}

}  // namespace riccati
