#include "engine/estimation/validation.hpp"

#include <string>

namespace riccati {

namespace {

// x' = f(x, theta, u(t), t) with the input held between two samples.
class SimulationRhs final : public OdeRhs {
 public:
  SimulationRhs(const Model& model, const Eigen::VectorXd& theta, HoldOrder hold)
      : model_(model), theta_(theta), hold_(hold, model.nu()) {}

  void set_interval(double t0, double t1, const double* u0, const double* u1) { hold_.set_interval(t0, t1, u0, u1); }

  Status eval(double t, const double* y, double* ydot) override {
    return model_.f(t, hold_.at(t), 1, 1, y, theta_.data(), ydot);
  }

 private:
  const Model& model_;
  const Eigen::VectorXd& theta_;
  InputHold hold_;
};

}  // namespace

Result<Eigen::MatrixXd> simulate(const Model& model, const Eigen::VectorXd& t, const Eigen::MatrixXd& u,
                                 const Eigen::VectorXd& x0, const Eigen::VectorXd& theta,
                                 const SimulationSettings& settings, Eigen::MatrixXd* states,
                                 const std::function<bool()>& stopped) {
  const Eigen::Index N = t.size();
  if (u.rows() != model.nu() || u.cols() != N) {
    return invalid_argument("inputs must be " + std::to_string(model.nu()) + " x " + std::to_string(N));
  }
  if (x0.size() != model.nx() || !x0.allFinite()) {
    return invalid_argument("x0 must hold " + std::to_string(model.nx()) + " finite values");
  }
  if (theta.size() != model.ntheta() || !theta.allFinite()) {
    return invalid_argument("theta must hold " + std::to_string(model.ntheta()) + " finite values");
  }
  RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Integrator> integrator, make_integrator(settings.integrator));
  SimulationRhs rhs(model, theta, settings.hold);
  Eigen::VectorXd x = x0;
  Eigen::MatrixXd y(model.ny(), N);
  if (states != nullptr) states->resize(model.nx(), N);
  for (Eigen::Index k = 0; k < N; ++k) {
    if (stopped && stopped()) return cancelled("simulation stopped at sample " + std::to_string(k + 1));
    if (k > 0) {
      rhs.set_interval(t[k - 1], t[k], u.col(k - 1).data(), u.col(k).data());
      Status s = integrator->integrate(rhs, t[k - 1], t[k], std::span<double>(x.data(), std::size_t(x.size())));
      if (!s.is_ok()) return s.with_context("simulation, sample " + std::to_string(k + 1));
    }
    RICCATI_RETURN_IF_ERROR(model.g(t[k], u.col(k).data(), 1, 1, x.data(), theta.data(), y.col(k).data()));
    if (states != nullptr) states->col(k) = x;
  }
  return y;
}

Result<ValidationResult> validate_model(const Model& model, const Dataset& data, const ValidationSettings& settings) {
  RICCATI_ASSIGN_OR_RETURN(const Dataset bound, bind_dataset(model, data));
  RICCATI_ASSIGN_OR_RETURN(const Eigen::VectorXd x0,
                           initial_state(model, settings.initial_state, settings.x0,
                                         {bound.y.col(0).data(), static_cast<std::size_t>(bound.y.rows())}));
  ValidationResult result;
  RICCATI_ASSIGN_OR_RETURN(result.y_simulated,
                           simulate(model, bound.t, bound.u, x0, settings.theta, settings.simulation));
  result.t = bound.t;
  result.x0 = x0;
  result.y_measured = bound.y;
  RICCATI_ASSIGN_OR_RETURN(result.fits, compare_outputs(bound.y, result.y_simulated, bound.output_names));
  return result;
}

Result<ValidationResult> predict_model(ModelPtr model, const Dataset& data, const ValidationSettings& settings,
                                       const PredictionSettings& prediction) {
  if (model == nullptr) return invalid_argument("no model given");
  const int K = prediction.horizon;
  if (K < 1) return invalid_argument("the prediction horizon must be at least 1 sample, got " + std::to_string(K));
  // The simulation: what the first K samples are predicted as.
  RICCATI_ASSIGN_OR_RETURN(ValidationResult result, validate_model(*model, data, settings));
  result.horizon = K;
  RICCATI_ASSIGN_OR_RETURN(const Dataset bound, bind_dataset(*model, data));
  const int nx = model->nx(), nz = model->nz(), ny = model->ny();
  const Eigen::Index N = bound.size();
  if (K >= N) return result;

  // The filter over the states: the parameters without variance or process noise.
  FilterSettings filter = prediction.filter;
  filter.hold = settings.simulation.hold;
  filter.integrator = settings.simulation.integrator;
  filter.Q = Eigen::MatrixXd::Zero(nz, nz);
  const Eigen::MatrixXd& Q = prediction.filter.Q;
  if (Q.rows() == nx && Q.cols() == nx) {
    filter.Q.topLeftCorner(nx, nx) = Q;
  } else if (Q.rows() == nz && Q.cols() == nz) {
    filter.Q.topLeftCorner(nx, nx) = Q.topLeftCorner(nx, nx);
  } else if (Q.size() != 0) {
    return invalid_argument("the predictor's Q must be " + std::to_string(nx) + " x " + std::to_string(nx) +
                            " (the states') or " + std::to_string(nz) + " x " + std::to_string(nz));
  }
  InitialEstimate initial;
  initial.mode = InitialState::kGiven;
  initial.x0 = result.x0;
  initial.theta0 = settings.theta;
  initial.P0 = Eigen::MatrixXd::Zero(nz, nz);
  if (prediction.P0x.size() != 0) {
    if (prediction.P0x.rows() != nx || prediction.P0x.cols() != nx) {
      return invalid_argument("the predictor's P0 must be " + std::to_string(nx) + " x " + std::to_string(nx));
    }
    initial.P0.topLeftCorner(nx, nx) = prediction.P0x;
  }
  RICCATI_ASSIGN_OR_RETURN(OnlineRunner runner, OnlineRunner::create(model, filter, initial));
  // Its estimate after each of the samples that start a prediction.
  Eigen::MatrixXd corrected(nx, N - K);
  for (Eigen::Index k = 0; k < N - K; ++k) {
    RICCATI_RETURN_IF_ERROR(runner
                                .advance(bound.t[k], {bound.u.col(k).data(), static_cast<std::size_t>(model->nu())},
                                         {bound.y.col(k).data(), static_cast<std::size_t>(ny)})
                                .with_context("the predictor's filter, sample " + std::to_string(k + 1)));
    corrected.col(k) = runner.filter().state().head(nx);
  }
  // From each, K samples on.
  RICCATI_ASSIGN_OR_RETURN(std::unique_ptr<Integrator> integrator, make_integrator(settings.simulation.integrator));
  SimulationRhs rhs(*model, settings.theta, settings.simulation.hold);
  Eigen::VectorXd x(nx);
  for (Eigen::Index k = K; k < N; ++k) {
    x = corrected.col(k - K);
    for (Eigen::Index j = k - K + 1; j <= k; ++j) {
      rhs.set_interval(bound.t[j - 1], bound.t[j], bound.u.col(j - 1).data(), bound.u.col(j).data());
      RICCATI_RETURN_IF_ERROR(integrator->integrate(rhs, bound.t[j - 1], bound.t[j], std::span<double>(x.data(), std::size_t(nx)))
                                  .with_context("prediction of sample " + std::to_string(k + 1)));
    }
    RICCATI_RETURN_IF_ERROR(model->g(bound.t[k], bound.u.col(k).data(), 1, 1, x.data(), settings.theta.data(),
                                     result.y_simulated.col(k).data()));
  }
  RICCATI_ASSIGN_OR_RETURN(result.fits, compare_outputs(bound.y, result.y_simulated, bound.output_names));
  return result;
}

}  // namespace riccati
