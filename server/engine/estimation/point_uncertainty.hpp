// How sure an estimate found by another criterion is, judged by output
// error at that estimate (docs/identification.md, "The iterated filter's
// intervals"): the model simulated over the record with its forward
// sensitivities, the residuals weighted by the assumed measurement noise and
// scaled by their own variance, and the covariance of least squares (white,
// or robust to autocorrelated residuals). The iterated filter's own P
// counts the record's information once per pass and is no interval of the
// estimate after many passes; this is.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "engine/data/dataset.hpp"
#include "engine/estimation/uncertainty.hpp"
#include "engine/estimation/validation.hpp"
#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

struct PointUncertainty {
  Eigen::VectorXd theta_std;   // [ntheta]: 0 for a parameter held; +inf for one the data do not determine
  Eigen::MatrixXd covariance;  // [ntheta x ntheta]: zero rows and columns for those held
  // [ntheta] one Gauss-Newton step of output error from the point: about
  // how far the point is from output error's optimum (0 for those held).
  Eigen::VectorXd theta_step;
  double sigma2 = 1.0;         // the weighted residuals' variance the covariance is scaled by
  std::string method;          // which covariance, in words
  std::vector<std::string> warnings;  // unknowns not identifiable, residuals not white
};

// `data` bound to the model; `mask` [ny x N] or empty; `weights` [ny] each
// output's 1/sigma (relative: their scale is estimated); the initial
// states x0 with those in `x0_free` [nx] counted as estimated too.
Result<PointUncertainty> uncertainty_at(const ModelPtr& model, const Dataset& data, const Eigen::ArrayXXd& mask,
                                        const Eigen::VectorXd& x0, const std::vector<bool>& x0_free,
                                        const Eigen::VectorXd& theta, const std::vector<bool>& theta_free,
                                        const Eigen::VectorXd& weights, const SimulationSettings& simulation,
                                        CovarianceChoice choice);

// What coloured residuals mean for the intervals: `coloured` [ny] marks the
// outputs whose residuals failed the whiteness test.
std::string coloured_residuals_warning(const Model& model, const std::vector<bool>& coloured, CovarianceChoice choice);

}  // namespace riccati
