// Forward sensitivities of every shipped model against central finite
// differences of the same simulation (the oracle): d y / d theta and
// d y / d x0 over a stretch of each model's reference record, to 1e-6 of
// each column's largest value.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "engine/estimation/sensitivity.hpp"
#include "engine/models/plugin_loader.hpp"

namespace riccati {
namespace {

struct Case {
  std::string model, csv;
  std::vector<std::string> inputs, outputs;
  std::vector<double> x0;
  int substeps;
  Eigen::Index samples;
  // The oracle's first step, relative to each value's scale: 1e-2, but for
  // the manipulator, whose Coulomb friction saturates at |v| = vg, a step
  // small enough not to carry the stages across that kink at most samples.
  double first_step = 1e-2;
};

void PrintTo(const Case& c, std::ostream* os) { *os << c.model; }

std::vector<Case> cases() {
  return {
      {"two_tank", "two_tank.csv", {"F1", "F2"}, {"h1", "h2"}, {0.4, 0.15}, 10, 300},
      {"rotating_arm", "rotating_arm.csv", {"i"}, {"q", "qdot"}, {0.1, 0.0}, 4, 300},
      {"rotary_pendulum", "rotary_pendulum.csv", {"v"}, {"phi", "alpha"}, {0.0, 0.1, 0.0, 0.0}, 4, 300},
      {"flexible_manipulator", "flexible_manipulator.csv", {"T"}, {"s1", "s2"}, {0.0, 0.0, 0.0, 0.0}, 2, 400, 1e-5},
  };
}

class Sensitivities : public ::testing::TestWithParam<Case> {};

// max over the rows of |a - b| against max |b|, column by column.
double worst_relative_column_error(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b, Eigen::Index* column) {
  double worst = 0.0;
  for (Eigen::Index j = 0; j < a.cols(); ++j) {
    const double scale = std::max(b.col(j).cwiseAbs().maxCoeff(), 1e-300);
    const double e = (a.col(j) - b.col(j)).cwiseAbs().maxCoeff() / scale;
    if (e > worst) {
      worst = e;
      *column = j;
    }
  }
  return worst;
}

TEST_P(Sensitivities, EqualCentralFiniteDifferences) {
  const Case& c = GetParam();
  static const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  const ModelPtr model = registry.get(c.model).value();
  const Dataset d = read_csv_file(std::string(RICCATI_TEST_DATA_DIR) + "/" + c.csv,
                                  ColumnMapping{"t", c.inputs, c.outputs})
                        .value();
  const Eigen::VectorXd t = d.t.head(c.samples);
  const Eigen::MatrixXd u = d.u.leftCols(c.samples);
  const Eigen::VectorXd theta = model->theta_default();
  const Eigen::VectorXd x0 = Eigen::Map<const Eigen::VectorXd>(c.x0.data(), static_cast<Eigen::Index>(c.x0.size()));
  SimulationSettings settings;
  settings.integrator.substeps = c.substeps;
  auto sim = SensitivitySimulator::create(model, settings, true);
  ASSERT_TRUE(sim.is_ok()) << sim.status().to_string();
  SimulatedRecord exact, plus, minus;
  ASSERT_TRUE(sim->simulate(t, u, x0, theta, true, &exact).is_ok());

  // The values alone must be the same simulation.
  SimulatedRecord values;
  ASSERT_TRUE(sim->simulate(t, u, x0, theta, false, &values).is_ok());
  EXPECT_TRUE(values.y.isApprox(exact.y, 1e-14)) << "with and without sensitivities";

  // The oracle: central differences extrapolated to step zero by Ridders'
  // method (Numerical Recipes' dfridr, on the whole output vector): steps
  // from the case's first step down by 1.4 each time, the extrapolation
  // with the smallest error estimate kept. It picks its step by its own
  // consistency, so it avoids both the rounding of too small a step (the
  // arm's third neuron moves y very little) and the kinks a large step
  // crosses (the manipulator's Coulomb friction, saturated at |v| = vg).
  const auto stacked = [](const SimulatedRecord& r) { return Eigen::Map<const Eigen::VectorXd>(r.y.data(), r.y.size()); };
  const auto derivative = [&](auto&& simulate_at, double h) -> Eigen::VectorXd {
    constexpr int kTable = 10;
    constexpr double kShrink = 1.4, kShrink2 = kShrink * kShrink;
    std::vector<std::vector<Eigen::VectorXd>> a(kTable, std::vector<Eigen::VectorXd>(kTable));
    const auto central = [&](double step) -> Eigen::VectorXd {
      EXPECT_TRUE(simulate_at(step, &plus).is_ok());
      EXPECT_TRUE(simulate_at(-step, &minus).is_ok());
      return (stacked(plus) - stacked(minus)) / (2 * step);
    };
    a[0][0] = central(h);
    Eigen::VectorXd best = a[0][0];
    double best_error = std::numeric_limits<double>::infinity();
    for (int i = 1; i < kTable; ++i) {
      h /= kShrink;
      a[0][i] = central(h);
      double factor = kShrink2;
      for (int j = 1; j <= i; ++j) {
        a[j][i] = (a[j - 1][i] * factor - a[j - 1][i - 1]) / (factor - 1.0);
        factor *= kShrink2;
        const double error = std::max((a[j][i] - a[j - 1][i]).cwiseAbs().maxCoeff(),
                                      (a[j][i] - a[j - 1][i - 1]).cwiseAbs().maxCoeff());
        if (error <= best_error) {
          best_error = error;
          best = a[j][i];
        }
      }
      // Higher order got worse by a lot: rounding has taken over.
      if ((a[i][i] - a[i - 1][i - 1]).cwiseAbs().maxCoeff() >= 2.0 * best_error) break;
    }
    return best;
  };
  Eigen::MatrixXd fd_theta(exact.dy_dtheta.rows(), theta.size()), fd_x0(exact.dy_dx0.rows(), x0.size());
  for (Eigen::Index j = 0; j < theta.size(); ++j) {
    const auto at = [&](double h, SimulatedRecord* r) {
      Eigen::VectorXd moved = theta;
      moved[j] += h;
      return sim->simulate(t, u, x0, moved, false, r);
    };
    fd_theta.col(j) = derivative(at, c.first_step * std::max(std::abs(theta[j]), 1e-3));
  }
  for (Eigen::Index j = 0; j < x0.size(); ++j) {
    const auto at = [&](double h, SimulatedRecord* r) {
      Eigen::VectorXd moved = x0;
      moved[j] += h;
      return sim->simulate(t, u, moved, theta, false, r);
    };
    fd_x0.col(j) = derivative(at, c.first_step * std::max(std::abs(x0[j]), 0.1));
  }
  Eigen::Index column = -1;
  const double theta_error = worst_relative_column_error(exact.dy_dtheta, fd_theta, &column);
  EXPECT_LT(theta_error, 1e-6) << c.model << ": d y / d " << model->param_names()[std::max<Eigen::Index>(column, 0)];
  const double x0_error = worst_relative_column_error(exact.dy_dx0, fd_x0, &column);
  EXPECT_LT(x0_error, 1e-6) << c.model << ": d y / d x0 of " << model->state_names()[std::max<Eigen::Index>(column, 0)];
  RecordProperty("worst_relative_error_theta", std::to_string(theta_error));
  RecordProperty("worst_relative_error_x0", std::to_string(x0_error));
}

INSTANTIATE_TEST_SUITE_P(EveryShippedModel, Sensitivities, ::testing::ValuesIn(cases()),
                         [](const ::testing::TestParamInfo<Case>& p) { return p.param.model; });

}  // namespace
}  // namespace riccati
