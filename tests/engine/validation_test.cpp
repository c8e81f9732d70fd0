// Validation: simulate a model over a dataset's inputs and compare outputs.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>

#include "engine/models/plugin_loader.hpp"
#include "engine/estimation/validation.hpp"

namespace riccati {
namespace {

const std::string kData = RICCATI_TEST_DATA_DIR;

ModelPtr builtin(const std::string& name) {
  auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR);
  EXPECT_TRUE(registry.is_ok());
  return registry.value().find(name);
}

Dataset load(const std::string& file, std::vector<std::string> inputs, std::vector<std::string> outputs) {
  auto data = read_csv_file(kData + "/" + file, ColumnMapping{"t", std::move(inputs), std::move(outputs)});
  EXPECT_TRUE(data.is_ok()) << data.status().to_string();
  return data.value();
}

Eigen::VectorXd true_parameters(const std::string& json) {
  std::ifstream in(kData + "/" + json);
  const auto meta = nlohmann::json::parse(in);
  Eigen::VectorXd v(meta["parameter_order"].size());
  for (std::size_t i = 0; i < meta["parameter_order"].size(); ++i) {
    v[i] = meta["parameters"][meta["parameter_order"][i].get<std::string>()].get<double>();
  }
  return v;
}

TEST(Validation, TwoTankTrueParametersFitAbove99Point9Percent) {
  const Dataset data = load("two_tank.csv", {"F1", "F2"}, {"h1", "h2"});
  ValidationSettings s;
  s.theta = true_parameters("two_tank.json");
  s.initial_state = InitialState::kFirstMeasurement;
  auto r = validate_model(*builtin("two_tank"), data, s);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  ASSERT_EQ(r.value().fits.size(), 2u);
  for (const auto& fit : r.value().fits) {
    EXPECT_GT(fit.fit_percent, 99.9) << fit.name;
    EXPECT_GT(fit.vaf_percent, 99.9) << fit.name;
    EXPECT_LT(fit.rmse, 1e-4) << fit.name;
  }
  EXPECT_EQ(r.value().fits[0].name, "h1");
}

TEST(Validation, WrongParametersFitWorse) {
  const Dataset data = load("two_tank.csv", {"F1", "F2"}, {"h1", "h2"});
  ValidationSettings s;
  s.theta = true_parameters("two_tank.json");
  s.theta[2] *= 1.1;  // k1 10% off
  auto r = validate_model(*builtin("two_tank"), data, s);
  ASSERT_TRUE(r.is_ok());
  EXPECT_LT(r.value().fits[0].fit_percent, 95.0);
}

TEST(Validation, RotaryPendulumWithEveryIntegrator) {
  // Noise-free data simulated with scipy at tight tolerance: every integrator
  // at its settings must reproduce it (the fixed-step ones with enough
  // substeps for an 8.7 ms sample on a pendulum of period ~1 s).
  const Dataset data = load("rotary_pendulum.csv", {"v"}, {"phi", "alpha"});
  for (auto kind : {IntegratorKind::kRk4, IntegratorKind::kRk3, IntegratorKind::kCvodeBdf,
                    IntegratorKind::kCvodeAdams, IntegratorKind::kArkodeErk}) {
    ValidationSettings s;
    s.theta = true_parameters("rotary_pendulum.json");
    s.initial_state = InitialState::kGiven;
    s.x0 = Eigen::VectorXd::Zero(4);
    s.simulation.integrator.kind = kind;
    s.simulation.integrator.substeps = 20;
    auto r = validate_model(*builtin("rotary_pendulum"), data, s);
    ASSERT_TRUE(r.is_ok()) << integrator_kind_name(kind) << ": " << r.status().to_string();
    for (const auto& fit : r.value().fits) EXPECT_GT(fit.fit_percent, 99.9) << integrator_kind_name(kind) << " " << fit.name;
  }
}

TEST(Validation, RejectsWrongParameterCount) {
  const Dataset data = load("two_tank.csv", {"F1", "F2"}, {"h1", "h2"});
  ValidationSettings s;
  s.theta = Eigen::Vector2d(1, 2);
  auto r = validate_model(*builtin("two_tank"), data, s);
  ASSERT_FALSE(r.is_ok());
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("theta must hold 4"), std::string::npos) << r.status().message();
}

}  // namespace
}  // namespace riccati

namespace riccati {
namespace {

TEST(Simulation, ZeroAndFirstOrderHoldIntegrateTheInputsExactly) {
  // With k1 = k2 = 0 the two-tank model is h' = F / A: the levels are the
  // integrals of the inputs. Under zero-order hold each interval adds
  // F_k dt / A, under first-order hold (F_k + F_k+1) dt / (2 A); RK4 is
  // exact for both (the right-hand side is at most linear in t).
  const ModelPtr model = builtin("two_tank");
  const int N = 6;
  Eigen::VectorXd t(N);
  Eigen::MatrixXd u(2, N);
  for (int k = 0; k < N; ++k) {
    t[k] = 0.5 * k;
    u(0, k) = 1.0 + k;        // a ramp
    u(1, k) = 2.0 - 0.5 * k;  // another
  }
  const Eigen::Vector2d x0(1.0, 2.0);
  const Eigen::Vector4d theta(2.0, 4.0, 0.0, 0.0);
  SimulationSettings zoh;
  zoh.integrator.substeps = 1;
  SimulationSettings foh = zoh;
  foh.hold = HoldOrder::kFirst;
  auto yz = simulate(*model, t, u, x0, theta, zoh);
  auto yf = simulate(*model, t, u, x0, theta, foh);
  ASSERT_TRUE(yz.is_ok() && yf.is_ok());
  Eigen::Vector2d hz = x0, hf = x0;
  for (int k = 1; k < N; ++k) {
    for (int i = 0; i < 2; ++i) {
      hz[i] += u(i, k - 1) * 0.5 / theta[i];
      hf[i] += 0.5 * (u(i, k - 1) + u(i, k)) * 0.5 / theta[i];
      EXPECT_NEAR(yz.value()(i, k), hz[i], 1e-12) << "zoh, sample " << k;
      EXPECT_NEAR(yf.value()(i, k), hf[i], 1e-12) << "foh, sample " << k;
    }
  }
  EXPECT_GT(std::abs(hz[0] - hf[0]), 0.5);  // the two holds really differ here
}

}  // namespace
}  // namespace riccati
