#include "engine/estimation/point_uncertainty.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "engine/estimation/diagnostics.hpp"
#include "engine/estimation/sensitivity.hpp"

namespace riccati {

Result<PointUncertainty> uncertainty_at(const ModelPtr& model, const Dataset& data, const Eigen::ArrayXXd& mask,
                                        const Eigen::VectorXd& x0, const std::vector<bool>& x0_free,
                                        const Eigen::VectorXd& theta, const std::vector<bool>& theta_free,
                                        const Eigen::VectorXd& weights, const SimulationSettings& simulation,
                                        CovarianceChoice choice) {
  const int ntheta = model->ntheta(), nx = model->nx(), ny = model->ny();
  const Eigen::Index N = data.size();
  // The unknowns: free parameters first, then the estimated initial states.
  std::vector<std::string> names;
  std::vector<Eigen::Index> theta_columns(static_cast<std::size_t>(ntheta), -1), x0_columns(static_cast<std::size_t>(nx), -1);
  for (int i = 0; i < ntheta; ++i) {
    if (!theta_free[static_cast<std::size_t>(i)]) continue;
    theta_columns[static_cast<std::size_t>(i)] = static_cast<Eigen::Index>(names.size());
    names.push_back(model->param_names()[static_cast<std::size_t>(i)]);
  }
  const bool any_x0 = std::any_of(x0_free.begin(), x0_free.end(), [](bool f) { return f; });
  for (int i = 0; i < nx; ++i) {
    if (!x0_free[static_cast<std::size_t>(i)]) continue;
    x0_columns[static_cast<std::size_t>(i)] = static_cast<Eigen::Index>(names.size());
    names.push_back(model->state_names()[static_cast<std::size_t>(i)] + "(0)");
  }
  const auto p = static_cast<Eigen::Index>(names.size());
  Eigen::VectorXd values(p);
  for (int i = 0; i < ntheta; ++i) {
    if (theta_columns[static_cast<std::size_t>(i)] >= 0) values[theta_columns[static_cast<std::size_t>(i)]] = theta[i];
  }
  for (int i = 0; i < nx; ++i) {
    if (x0_columns[static_cast<std::size_t>(i)] >= 0) values[x0_columns[static_cast<std::size_t>(i)]] = x0[i];
  }

  RICCATI_ASSIGN_OR_RETURN(SensitivitySimulator simulator, SensitivitySimulator::create(model, simulation, any_x0));
  SimulatedRecord record;
  RICCATI_RETURN_IF_ERROR(simulator.simulate(data.t, data.u, x0, theta, true, &record)
                              .with_context("simulating the model at the estimate"));
  const Eigen::ArrayXXd used = mask.size() != 0 ? mask : Eigen::ArrayXXd::Ones(ny, N);
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(N * ny, p);
  Eigen::VectorXd r(N * ny);
  for (Eigen::Index k = 0; k < N; ++k) {
    for (Eigen::Index i = 0; i < ny; ++i) {
      const Eigen::Index row = k * ny + i;
      const double w = weights[i] * used(i, k);
      r[row] = w * (record.y(i, k) - data.y(i, k));
      for (int j = 0; j < ntheta; ++j) {
        const Eigen::Index c = theta_columns[static_cast<std::size_t>(j)];
        if (c >= 0) J(row, c) = w * record.dy_dtheta(row, j);
      }
      for (int j = 0; j < nx; ++j) {
        const Eigen::Index c = x0_columns[static_cast<std::size_t>(j)];
        if (c >= 0) J(row, c) = w * record.dy_dx0(row, j);
      }
    }
  }
  if (!r.allFinite() || !J.allFinite()) {
    return failed_precondition("the simulation at the estimate is not finite");
  }
  LeastSquaresCovariance information(p);
  information.add(J, r, ny);
  const double n = used.sum(), dof = n - static_cast<double>(p);
  PointUncertainty out;
  out.sigma2 = dof > 0.0 ? r.squaredNorm() / dof : std::numeric_limits<double>::infinity();

  // The whiteness of the residuals, over the samples where every output is used.
  std::vector<Eigen::Index> complete;
  complete.reserve(static_cast<std::size_t>(N));
  for (Eigen::Index k = 0; k < N; ++k) {
    if ((used.col(k) != 0.0).all()) complete.push_back(k);
  }
  Eigen::MatrixXd residuals(ny, static_cast<Eigen::Index>(complete.size())), inputs(data.u.rows(), residuals.cols());
  for (Eigen::Index c = 0; c < residuals.cols(); ++c) {
    const Eigen::Index k = complete[static_cast<std::size_t>(c)];
    residuals.col(c) = r.segment(k * ny, ny);
    inputs.col(c) = data.u.col(k);
  }
  std::vector<bool> coloured(static_cast<std::size_t>(ny), false);
  double signal = 0.0;
  for (Eigen::Index k = 0; k < N; ++k) {
    for (Eigen::Index i = 0; i < ny; ++i) signal += std::pow(weights[i] * used(i, k) * data.y(i, k), 2);
  }
  const Result<ResidualDiagnostics> diagnostics = diagnose_residuals(residuals, inputs, nullptr);
  if (diagnostics.is_ok() && !rounding_residuals(r.squaredNorm(), signal)) {
    for (const Eigen::Index i : diagnostics->non_white_outputs()) coloured[static_cast<std::size_t>(i)] = true;
  }
  const bool white = std::none_of(coloured.begin(), coloured.end(), [](bool c) { return c; });

  const Uncertainty u = information.uncertainty(choice, white, out.sigma2, dof > 0.0 ? n / dof : 1.0, names, values,
                                                &out.method);
  out.warnings = u.warnings;
  if (!white) out.warnings.push_back(coloured_residuals_warning(*model, coloured, choice));
  out.theta_std = Eigen::VectorXd::Zero(ntheta);
  out.theta_step = Eigen::VectorXd::Zero(ntheta);
  out.covariance = Eigen::MatrixXd::Zero(ntheta, ntheta);
  const Eigen::VectorXd step = information.gauss_newton_step();
  for (int a = 0; a < ntheta; ++a) {
    const Eigen::Index ca = theta_columns[static_cast<std::size_t>(a)];
    if (ca < 0) continue;
    out.theta_std[a] = u.std[ca];
    out.theta_step[a] = step[ca];
    for (int b = 0; b < ntheta; ++b) {
      const Eigen::Index cb = theta_columns[static_cast<std::size_t>(b)];
      if (cb >= 0) out.covariance(a, b) = u.covariance(ca, cb);
    }
  }
  return out;
}

std::string coloured_residuals_warning(const Model& model, const std::vector<bool>& coloured, CovarianceChoice choice) {
  std::string outputs;
  for (std::size_t i = 0; i < coloured.size(); ++i) {
    if (coloured[i]) outputs += (outputs.empty() ? "" : ", ") + model.output_names()[i];
  }
  const std::string what = "the simulation residuals of " + outputs + " are not white (Ljung-Box test at 95 %): ";
  const std::string alternative =
      "; a model of the disturbance, maximum likelihood with estimated process noise (--method ml --estimate-q), is "
      "the principled alternative";
  if (choice == CovarianceChoice::kWhite) {
    return what + "the intervals assume they are (--covariance white) and are too narrow" + alternative;
  }
  return what + "the intervals are from the covariance robust to autocorrelated residuals" + alternative;
}

}  // namespace riccati
