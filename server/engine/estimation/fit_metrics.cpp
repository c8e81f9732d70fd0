#include "engine/estimation/fit_metrics.hpp"

#include <cmath>
#include <limits>
#include <string>
#include <utility>

namespace riccati {
namespace {

using Eigen::Index;

// The first non-finite value, by sample then output, so the message points
// at the earliest trouble.
Status check_finite(const Eigen::MatrixXd& values, const char* which, const std::vector<std::string>& names) {
  if (values.allFinite()) return Status::ok();
  for (Index j = 0; j < values.cols(); ++j) {
    for (Index i = 0; i < values.rows(); ++i) {
      if (!std::isfinite(values(i, j))) {
        return invalid_argument(std::string(which) + " output \"" + names[static_cast<std::size_t>(i)] + "\" is " +
                                (std::isnan(values(i, j)) ? "NaN" : "infinite") + " at sample " + std::to_string(j + 1));
      }
    }
  }
  return Status::ok();
}

}  // namespace

// RRSE: the brief pointed at Zheng, Ikeda & Shimomura, "Estimation of
// continuous-time nonlinear systems by using unscented Kalman filter" (in
// "Kalman Filter", InTech 2010), eq. (61). The stored copy of that chapter
// that could be searched only yields its opening pages, so eq. (61) itself
// could not be checked; what is implemented is the standard relative root
// squared error
//     RRSE = sqrt( sum_k (y_k - yhat_k)^2 / sum_k (y_k - mean(y))^2 ),
// i.e. the error relative to that of predicting the mean. Note that with this
// definition RRSE = 1 - fit_percent / 100.
Result<std::vector<OutputFit>> compare_outputs(const Eigen::MatrixXd& measured, const Eigen::MatrixXd& simulated,
                                               const std::vector<std::string>& names) {
  if (measured.rows() != simulated.rows() || measured.cols() != simulated.cols()) {
    return invalid_argument("measured outputs are " + size_text(measured) + " but simulated outputs are " +
                            size_text(simulated) + " (outputs x samples)");
  }
  if (static_cast<Index>(names.size()) != measured.rows()) {
    return invalid_argument(std::to_string(names.size()) + " output names for " + std::to_string(measured.rows()) +
                            " outputs");
  }
  if (measured.cols() == 0) return invalid_argument("no samples to compare");
  RICCATI_RETURN_IF_ERROR(check_finite(measured, "measured", names));
  RICCATI_RETURN_IF_ERROR(check_finite(simulated, "simulated", names));

  constexpr double kUndefined = std::numeric_limits<double>::quiet_NaN();
  const double num_samples = static_cast<double>(measured.cols());
  std::vector<OutputFit> fits;
  fits.reserve(names.size());
  for (Index i = 0; i < measured.rows(); ++i) {
    const auto y = measured.row(i).array();
    const auto error = y - simulated.row(i).array();
    const double error_mean = error.mean();
    const double squared_error = error.square().sum();
    const double error_variance = (error - error_mean).square().mean();
    const double centred_squares = (y - y.mean()).square().sum();

    OutputFit fit{names[static_cast<std::size_t>(i)], std::sqrt(squared_error / num_samples), kUndefined, kUndefined,
                  kUndefined};
    // Exactly equal samples can still leave a rounding residue around their
    // computed mean, hence the min/max test rather than centred_squares == 0.
    const bool varies = y.maxCoeff() != y.minCoeff() && centred_squares > 0.0;
    if (varies) {
      fit.rrse = std::sqrt(squared_error / centred_squares);
      fit.fit_percent = 100.0 * (1.0 - fit.rrse);
      fit.vaf_percent = 100.0 * (1.0 - error_variance / (centred_squares / num_samples));
    }
    fits.push_back(std::move(fit));
  }
  return fits;
}

}  // namespace riccati
