// Maximum likelihood's exact derivatives (likelihood_sensitivity.hpp) against
// central differences of the same residuals computed without them, on every
// shipped model, and the maximum-likelihood fits that use them.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <fstream>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "engine/estimation/binding.hpp"
#include "engine/estimation/likelihood_sensitivity.hpp"
#include "engine/estimation/max_likelihood.hpp"
#include "engine/estimation/online_runner.hpp"
#include "engine/models/plugin_loader.hpp"
#include "engine/models/text/text_model.hpp"

namespace riccati {
namespace {

const ModelRegistry& registry() {
  static const ModelRegistry r = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  return r;
}

std::string read_file(const std::string& path) {
  std::ifstream in(path);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

struct Case {
  std::string model;    // the plugin's name, and its text model's file
  std::string dataset;  // tests/data/<dataset>.csv
  ColumnMapping columns;
  bool text = false;  // the text model (models/text/<model>.yaml) instead of the plugin
};

void PrintTo(const Case& c, std::ostream* os) { *os << c.model << (c.text ? " (text)" : " (plugin)"); }

std::string case_name(const ::testing::TestParamInfo<Case>& info) {
  return info.param.model + (info.param.text ? "_text" : "_plugin");
}

std::vector<Case> cases() {
  std::vector<Case> out = {
      {"two_tank", "two_tank", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}},
      {"rotary_pendulum", "rotary_pendulum", ColumnMapping{"t", {"v"}, {"phi", "alpha"}}},
      {"rotating_arm", "rotating_arm", ColumnMapping{"t", {"i"}, {"q", "qdot"}}},
      {"flexible_manipulator", "flexible_manipulator", ColumnMapping{"t", {"T"}, {"s1", "s2"}}},
  };
  // The text models written with der: (the flexible manipulator's is in
  // mechanical form, whose text model has no second derivatives).
  for (std::size_t i = 0; i < 3; ++i) {
    Case text = out[i];
    text.text = true;
    out.push_back(text);
  }
  return out;
}

ModelPtr load(const Case& c) {
  if (!c.text) return registry().get(c.model).value();
  const std::string path = std::string(RICCATI_TEST_TEXT_MODEL_DIR) + "/" + c.model + ".yaml";
  auto text = compile_text_model(read_file(path), path);
  EXPECT_TRUE(text.is_ok()) << text.status().to_string();
  return text->model;
}

// The first `samples` of the case's record, with noise of 1 % of each output's
// spread added.
Experiment record(const Case& c, const Model& model, Eigen::Index samples) {
  const std::string base = std::string(RICCATI_TEST_DATA_DIR) + "/" + c.dataset;
  Dataset raw = read_csv_file(base + ".csv", c.columns).value();
  raw.t.conservativeResize(samples);
  raw.u.conservativeResize(Eigen::NoChange, samples);
  raw.y.conservativeResize(Eigen::NoChange, samples);
  Experiment e;
  e.data = bind_dataset(model, raw).value();
  std::mt19937_64 rng(7);
  std::normal_distribution<double> noise(0.0, 1.0);
  for (Eigen::Index i = 0; i < e.data.y.rows(); ++i) {
    const double spread = e.data.y.row(i).maxCoeff() - e.data.y.row(i).minCoeff();
    for (Eigen::Index k = 0; k < samples; ++k) e.data.y(i, k) += 0.01 * spread * noise(rng);
  }
  // States measured start at their first (noisy) measurement, the others at zero.
  const Eigen::VectorXd y0 = e.data.y.col(0);
  e.x0 = initial_state(model, InitialState::kFirstMeasurement, Eigen::VectorXd::Zero(model.nx()),
                       std::span<const double>(y0.data(), static_cast<std::size_t>(y0.size())))
             .value();
  return e;
}

class ExactLikelihoodGradient : public ::testing::TestWithParam<Case> {};

// The gradient of L along every direction (each parameter, initial state,
// process and measurement noise level) against central differences of L
// computed without sensitivities, at a point off the truth with process
// noise in the predictor; and the Fisher information symmetric and positive
// semi-definite.
TEST_P(ExactLikelihoodGradient, EqualsCentralDifferencesOfTheLikelihood) {
  const Case& c = GetParam();
  const ModelPtr model = load(c);
  ASSERT_NE(model, nullptr);
  ASSERT_TRUE(model->has_second_derivatives()) << model->name();
  const int nx = model->nx(), ny = model->ny(), ntheta = model->ntheta();
  const Experiment e = record(c, *model, 150);

  FilterSettings filter;
  LikelihoodPoint at;
  at.theta = model->theta_default() * 1.03;
  at.x0 = e.x0;
  at.Q = Eigen::MatrixXd::Identity(nx, nx) * 1e-4;
  at.R = Eigen::MatrixXd::Zero(ny, ny);
  for (int i = 0; i < ny; ++i) {
    const double spread = e.data.y.row(i).maxCoeff() - e.data.y.row(i).minCoeff();
    at.R(i, i) = std::pow(0.01 * spread, 2) + 1e-8;
  }
  auto made = LikelihoodSensitivity::create(model, filter, Eigen::MatrixXd::Identity(nx, nx) * 1e-4);
  ASSERT_TRUE(made.is_ok()) << made.status().to_string();
  LikelihoodSensitivity& sensitivity = *made;

  // Directions scaled to each unknown's size: theta_j and x0_j relative (or
  // absolute where zero), Q and R relative (as log-scaled unknowns move them).
  const int m = ntheta + 2 * nx + ny;
  LikelihoodDirections directions;
  directions.resize(*model, m);
  for (int j = 0; j < ntheta; ++j) directions.theta(j, j) = at.theta[j] != 0.0 ? at.theta[j] : 1.0;
  for (int j = 0; j < nx; ++j) directions.x0(j, ntheta + j) = std::max(std::abs(at.x0[j]), 0.1);
  for (int j = 0; j < nx; ++j) directions.q(j, ntheta + nx + j) = at.Q(j, j);
  for (int j = 0; j < ny; ++j) directions.r(j, ntheta + 2 * nx + j) = at.R(j, j);

  LikelihoodDerivatives exact;
  exact.reset(m);
  const Status run = sensitivity.accumulate(e, at, directions, true, &exact);
  ASSERT_TRUE(run.is_ok()) << run.to_string();
  const auto value = [&](const LikelihoodPoint& p) {
    LikelihoodDerivatives plain;
    plain.reset(0);
    const Status s = sensitivity.accumulate(e, p, directions, false, &plain);
    EXPECT_TRUE(s.is_ok()) << s.to_string();
    return plain.value();
  };
  EXPECT_EQ(value(at), exact.value()) << "L with and without its derivatives";

  const double h = 1e-5;
  for (int col = 0; col < m; ++col) {
    const auto moved = [&](double step) {
      LikelihoodPoint p = at;
      p.theta += step * directions.theta.col(col);
      p.x0 += step * directions.x0.col(col);
      p.Q.diagonal() += step * directions.q.col(col);
      p.R.diagonal() += step * directions.r.col(col);
      return p;
    };
    const double difference = (value(moved(h)) - value(moved(-h))) / (2.0 * h);
    // Relative to the derivative, or for a direction L hardly depends on to a
    // thousandth of the gradient's largest entry.
    EXPECT_NEAR(exact.gradient[col], difference,
                1e-6 * std::max(std::abs(difference), 1e-3 * exact.gradient.cwiseAbs().maxCoeff()))
        << model->name() << ": the derivative along direction " << col << " (of " << m << ")";
  }
  EXPECT_LT((exact.fisher - exact.fisher.transpose()).cwiseAbs().maxCoeff(), 1e-12 * exact.fisher.cwiseAbs().maxCoeff());
  const Eigen::VectorXd eigenvalues = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(exact.fisher).eigenvalues();
  EXPECT_GT(eigenvalues.minCoeff(), -1e-10 * eigenvalues.maxCoeff());
}

INSTANTIATE_TEST_SUITE_P(ShippedModels, ExactLikelihoodGradient, ::testing::ValuesIn(cases()), case_name);

// Maximum likelihood with Q and R estimated on a noisy two-tank record:
// Fisher scoring with the exact gradient and Ceres with central differences
// find the same optimum (two routes, one criterion), and the covariances
// (the Hessian from differences of the exact gradient, and from second
// differences of L) agree; each result says which gradient it used.
TEST(MaxLikelihoodGradient, ExactAndDifferencedFitsFindTheSameOptimum) {
  const Case c{"two_tank", "two_tank_noisy", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}};
  const ModelPtr model = load(c);
  const std::string base = std::string(RICCATI_TEST_DATA_DIR) + "/two_tank_noisy";
  Dataset raw = read_csv_file(base + ".csv", c.columns).value();
  const Eigen::Index samples = 600;
  raw.t.conservativeResize(samples);
  raw.u.conservativeResize(Eigen::NoChange, samples);
  raw.y.conservativeResize(Eigen::NoChange, samples);
  Experiment e;
  e.data = bind_dataset(*model, raw).value();
  e.x0 = e.data.y.col(0);
  MaxLikelihoodSettings s;
  s.filter.Q = Eigen::MatrixXd::Zero(6, 6);
  s.filter.Q.topLeftCorner(2, 2) = Eigen::Matrix2d::Identity() * 1e-6;
  s.filter.R = Eigen::Matrix2d::Identity() * 1e-3;
  s.P0x = Eigen::Matrix2d::Identity() * 1e-4;
  s.parameters = default_parameters(*model, model->theta_default() * 1.2);
  s.estimate_process_noise = true;
  s.estimate_measurement_noise = true;
  const auto exact = max_likelihood(model, {e}, s);
  ASSERT_TRUE(exact.is_ok()) << exact.status().to_string();
  s.differenced_gradient = true;
  const auto differenced = max_likelihood(model, {e}, s);
  ASSERT_TRUE(differenced.is_ok()) << differenced.status().to_string();
  const EstimationResult& a = exact->estimate;
  const EstimationResult& b = differenced->estimate;
  EXPECT_TRUE(a.converged) << a.termination;
  EXPECT_NE(a.gradient.find("exact"), std::string::npos) << a.gradient;
  EXPECT_NE(b.gradient.find("central differences"), std::string::npos) << b.gradient;
  // The same optimum: a hundredth of a standard error apart, and L equal.
  for (Eigen::Index j = 0; j < 4; ++j) {
    EXPECT_NEAR(a.theta[j], b.theta[j], 0.01 * a.theta_std[j]) << model->param_names()[static_cast<std::size_t>(j)];
    EXPECT_NEAR(a.theta_std[j], b.theta_std[j], 1e-3 * a.theta_std[j]) << model->param_names()[static_cast<std::size_t>(j)];
  }
  EXPECT_NEAR(a.cost, b.cost, 1e-8 * std::abs(b.cost));
  EXPECT_NEAR(std::log(exact->noise.r[0]), std::log(differenced->noise.r[0]), 1e-3);
  // And the exact route costs fewer filter runs.
  EXPECT_LT(a.evaluations, b.evaluations);
}

// A model without second derivatives (a text model in mechanical form) and
// the UKF as predictor keep central differences, and the result says why.
TEST(MaxLikelihoodGradient, WithoutSecondDerivativesTheFitDifferencesAndSaysWhy) {
  const Case manipulator{"flexible_manipulator", "flexible_manipulator", ColumnMapping{"t", {"T"}, {"s1", "s2"}}, true};
  const ModelPtr text = load(manipulator);
  ASSERT_NE(text, nullptr);
  EXPECT_FALSE(text->has_second_derivatives());
  const Case tank{"two_tank", "two_tank", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}};
  const ModelPtr plugin = load(tank);
  for (const auto& [model, c, kind, why] :
       {std::tuple{text, manipulator, FilterKind::kEkf, std::string("gives no second derivatives")},
        std::tuple{plugin, tank, FilterKind::kUkf, std::string("UKF")}}) {
    const Experiment e = record(c, *model, 40);
    MaxLikelihoodSettings s;
    s.filter.kind = kind;
    s.filter.Q = Eigen::MatrixXd::Zero(model->nz(), model->nz());
    s.filter.R = Eigen::MatrixXd::Identity(model->ny(), model->ny()) * 1e-4;
    s.P0x = Eigen::MatrixXd::Zero(model->nx(), model->nx());
    s.parameters = default_parameters(*model, model->theta_default());
    s.optimizer.max_iterations = 1;
    const auto fit = max_likelihood(model, {e}, s);
    ASSERT_TRUE(fit.is_ok()) << fit.status().to_string();
    EXPECT_NE(fit->estimate.gradient.find("central differences"), std::string::npos) << fit->estimate.gradient;
    EXPECT_NE(fit->estimate.gradient.find(why), std::string::npos) << fit->estimate.gradient;
  }
}

}  // namespace
}  // namespace riccati
