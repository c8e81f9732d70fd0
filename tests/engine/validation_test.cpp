// Validation: simulate a model over a dataset's inputs and compare outputs.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>

#include "engine/plugin_loader.hpp"
#include "engine/validation.hpp"

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
