// Whether a plugin's exact Jacobians are right: each one (df/dz, dg/dz and,
// for a model with a mechanical form, those of c and Fc; z = [x; theta])
// against central finite differences of the plugin's own values, at a few
// points. A plugin written with the SDK gets its Jacobians by dual numbers
// and agrees to rounding; a hand-written table (or an SDK model with a branch
// the dual numbers do not see) may not, and then the EKF, the sensitivities
// of output error and the likelihood's gradient are wrong without any error.
// The registry checks every model when it loads it (`riccati models show`
// reports the result) and an identification job checks its own start point.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "engine/models/model.hpp"

namespace riccati {

// Where to compare: one time, input, state and parameter vector.
struct JacobianPoint {
  double t = 0.0;
  Eigen::VectorXd u, x, theta;
};

struct JacobianCheck {
  // False when there was nothing to check (the model gives no Jacobians: the
  // host differentiates it itself) or the model could not be evaluated at
  // any point; `detail` says which.
  bool checked = false;
  std::string detail;
  int points = 0;          // points compared
  double max_error = 0.0;  // the largest scaled difference (see kJacobianTolerance)
  // One line per Jacobian that disagrees: its worst entry, both values and
  // the point.
  std::vector<std::string> disagreements;

  bool agrees() const { return disagreements.empty(); }
};

// An entry disagrees when |exact - numeric| > tolerance * max(|numeric|,
// 1e-3 max_j |numeric_ij| over its row, 1e-6). The fourth-order differences
// of the check are good to about 1e-10 of that scale at the smooth points
// checked, so an entry flagged is wrong by far more than the oracle's own
// error, while a missing term or a wrong sign is off by O(1).
constexpr double kJacobianTolerance = 1e-4;

Result<JacobianCheck> check_jacobians(const Model& model, const std::vector<JacobianPoint>& points);

// Points for a model alone, without data: its default parameters, and states
// and inputs from a fixed pattern of distinct, non-zero values (0.3 to about
// 2), away from the zeros and symmetries where a wrong term can vanish.
std::vector<JacobianPoint> generic_points(const Model& model);

}  // namespace riccati
