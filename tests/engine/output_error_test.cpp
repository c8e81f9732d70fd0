// Output error against the truth of the reference datasets.
#include <gtest/gtest.h>

#include <fstream>
#include <optional>
#include <random>
#include <nlohmann/json.hpp>

#include "engine/estimation/binding.hpp"
#include "engine/estimation/identification.hpp"
#include "engine/estimation/output_error.hpp"
#include "engine/estimation/sensitivity.hpp"
#include "engine/models/plugin_loader.hpp"

namespace riccati {
namespace {

const ModelRegistry& registry() {
  static const ModelRegistry r = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  return r;
}

nlohmann::json meta(const std::string& name) {
  std::ifstream in(std::string(RICCATI_TEST_DATA_DIR) + "/" + name + ".json");
  return nlohmann::json::parse(in);
}

Eigen::VectorXd truth_of(const nlohmann::json& m) {
  Eigen::VectorXd t(static_cast<Eigen::Index>(m["parameter_order"].size()));
  for (std::size_t i = 0; i < m["parameter_order"].size(); ++i) t[static_cast<Eigen::Index>(i)] = m["parameters"][m["parameter_order"][i].get<std::string>()];
  return t;
}

double worst_relative_error(const Eigen::VectorXd& a, const Eigen::VectorXd& truth) {
  return ((a - truth).array() / truth.array()).abs().maxCoeff();
}

// The shipped noise-free two-tank record, bound to the model, from its first
// measurement.
Experiment two_tank_experiment(const Model& model) {
  Experiment e;
  e.data = bind_dataset(model, read_csv_file(RICCATI_TEST_DATA_DIR "/two_tank.csv",
                                             ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value()).value();
  e.x0 = e.data.y.col(0);
  return e;
}

TEST(OutputError, TwoTankFromHensensStartRecoversTheTruth) {
  const ModelPtr model = registry().get("two_tank").value();
  const Experiment e = two_tank_experiment(*model);
  OutputErrorSettings s;
  s.parameters = default_parameters(*model, Eigen::Vector4d(20, 20, 1, 1));
  auto r = output_error(model, {e}, s);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  const Eigen::VectorXd truth = truth_of(meta("two_tank"));
  RecordProperty("iterations", r->iterations);
  EXPECT_TRUE(r->converged) << r->termination;
  EXPECT_TRUE(r->warnings.empty());
  EXPECT_LT(worst_relative_error(r->theta, truth), 1e-8);
}

// The same with Dormand and Prince's 8th-order method, one step a sample:
// the two-tank model's time constants are minutes against 1 s samples, so
// one step of order 8 integrates more accurately than RK4's ten (the
// estimate is closer to the truth, not merely as close).
TEST(OutputError, TwoTankWithTheEighthOrderMethodOneStepASampleRecoversTheTruth) {
  const ModelPtr model = registry().get("two_tank").value();
  const Experiment e = two_tank_experiment(*model);
  OutputErrorSettings s;
  s.parameters = default_parameters(*model, Eigen::Vector4d(20, 20, 1, 1));
  s.simulation.integrator.kind = IntegratorKind::kDop853;
  s.simulation.integrator.substeps = 1;
  auto r = output_error(model, {e}, s);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  EXPECT_TRUE(r->converged) << r->termination;
  const double error = worst_relative_error(r->theta, truth_of(meta("two_tank")));
  RecordProperty("worst_relative_error", std::to_string(error));
  EXPECT_LT(error, 1e-13);  // RK4 with 10 substeps: 1.6e-13
}

// From 30 % off, the simulation error of the pendulum has other minima (r
// runs to 0 from there; from within 10 % it converges): the chain the
// toolbox's users know, a few passes of the UKF to get close (Zheng et al.'s
// setting), then output error from where they end, finds the truth.
TEST(OutputError, RotaryPendulumFrom30PercentOffAfterUkfPassesRecoversTheTruth) {
  const ModelPtr model = registry().get("rotary_pendulum").value();
  const nlohmann::json m = meta("rotary_pendulum");
  const Dataset raw = read_csv_file(RICCATI_TEST_DATA_DIR "/rotary_pendulum.csv", ColumnMapping{"t", {"v"}, {"phi", "alpha"}}).value();
  const Eigen::VectorXd truth = truth_of(m);
  const Eigen::VectorXd start = truth.cwiseProduct(Eigen::Vector3d(1.3, 0.7, 1.3));

  OutputErrorSettings s;
  s.simulation.integrator.substeps = 20;
  s.parameters = default_parameters(*model, start);
  Experiment e;
  e.data = bind_dataset(*model, raw).value();
  e.x0 = Eigen::VectorXd::Zero(4);
  const auto alone = output_error(model, {e}, s);
  ASSERT_TRUE(alone.is_ok()) << alone.status().to_string();
  EXPECT_GT(worst_relative_error(alone->theta, truth), 0.1) << "the start is outside output error's basin";

  IdentificationSettings ukf;
  ukf.filter.kind = FilterKind::kUkf;
  ukf.filter.Q = Eigen::MatrixXd::Zero(7, 7);
  ukf.filter.R = Eigen::Vector2d(1e-8, 1e-8).asDiagonal();
  ukf.initial.x0 = e.x0;
  ukf.initial.theta0 = start;
  Eigen::VectorXd p0(7);
  p0 << 0, 0, 0, 0, (0.3 * truth).cwiseAbs2();
  ukf.initial.P0 = p0.asDiagonal();
  ukf.passes = 2;
  const auto passes = identify(model, raw, ukf);
  ASSERT_TRUE(passes.is_ok()) << passes.status().to_string();
  s.parameters.theta0 = passes->theta;
  const auto r = output_error(model, {e}, s);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  EXPECT_LT(worst_relative_error(r->theta, truth), 1e-6)
      << "after the UKF: " << worst_relative_error(passes->theta, truth);
}

// A record of the model itself: its outputs over a reference record's inputs.
Experiment simulated_experiment(const ModelPtr& model, const std::string& csv, const ColumnMapping& mapping,
                                const Eigen::VectorXd& x0, const Eigen::VectorXd& theta, const SimulationSettings& sim,
                                Eigen::Index samples) {
  Dataset d = read_csv_file(std::string(RICCATI_TEST_DATA_DIR) + "/" + csv, mapping).value();
  d.t.conservativeResize(samples);
  d.u.conservativeResize(Eigen::NoChange, samples);
  d.y = simulate(*model, d.t, d.u, x0, theta, sim).value();
  Experiment e;
  e.data = bind_dataset(*model, d).value();
  e.x0 = x0;
  return e;
}

// The arm's record is noisy and its true friction is not the model's, so the
// test record is the model's own simulation over the record's input current.
// The truth is a friction the data can tell apart: the arm moving at up to 6
// rad/s as the real one does, each neuron working in its nonlinear range.
// (Hensen's published values give a Coulomb level of 1.5 against a current
// of at most 0.49: the simulated arm hardly moves, and the data then cannot
// separate the near-linear neurons from b; see the identifiability test.)
TEST(OutputError, RotatingArmFrom30PercentOffRecoversItsOwnSimulation) {
  const ModelPtr model = registry().get("rotating_arm").value();
  Eigen::VectorXd truth(8);
  truth << 0.6, 12.8, 2.5, 0.3, -0.2, -0.1, 0.05, 34.4;
  OutputErrorSettings s;
  s.simulation.integrator.substeps = 4;
  Experiment e = simulated_experiment(model, "rotating_arm.csv", ColumnMapping{"t", {"i"}, {"q", "qdot"}},
                                      Eigen::Vector2d(0.0, 0.0), truth, s.simulation, 3000);
  Eigen::VectorXd start = truth;
  for (Eigen::Index i = 0; i < start.size(); ++i) start[i] *= i % 2 == 0 ? 1.3 : 0.7;
  s.parameters = default_parameters(*model, start);
  auto r = output_error(model, {e}, s);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  EXPECT_LT(worst_relative_error(r->theta, truth), 1e-6);
}

TEST(OutputError, FlexibleManipulatorRecoversItsParametersAndInitialStates) {
  const ModelPtr model = registry().get("flexible_manipulator").value();
  const Eigen::VectorXd truth = model->theta_default();
  const Eigen::Vector4d x0_true(0.01, -0.02, 0.0, 0.0);
  OutputErrorSettings s;
  s.simulation.integrator.substeps = 2;
  Experiment e = simulated_experiment(model, "flexible_manipulator.csv", ColumnMapping{"t", {"T"}, {"s1", "s2"}},
                                      x0_true, truth, s.simulation, 4000);
  e.x0 = Eigen::Vector4d(0.0, 0.0, 0.0, 0.0);
  e.estimate_x0.assign(4, true);
  Eigen::VectorXd start = truth;
  for (Eigen::Index i = 0; i < start.size(); ++i) start[i] *= i % 2 == 0 ? 1.3 : 0.7;
  s.parameters = default_parameters(*model, start);
  auto r = output_error(model, {e}, s);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  Eigen::VectorXd all(10), all_truth(10);
  all << r->experiments[0].x0, r->theta;
  all_truth << x0_true, truth;
  const double x0_error = (r->experiments[0].x0 - x0_true).cwiseAbs().maxCoeff();
  EXPECT_LT(worst_relative_error(r->theta, truth), 1e-6);
  EXPECT_LT(x0_error, 1e-6 * 0.02);  // the states to 1e-6 of their size
}

// Noisy data: over 100 realisations of measurement noise of a known level on
// the two-tank record (simulated here from the truth), each parameter's 95 %
// interval must hold the truth in 90-99 of them (the binomial 95 % range for
// p = 0.95, n = 100 is 90-99).
TEST(OutputError, ConfidenceIntervalsCoverTheTruthAtTheirLevel) {
  const ModelPtr model = registry().get("two_tank").value();
  const Eigen::VectorXd truth = model->theta_default();
  SimulationSettings sim;
  const Experiment clean = simulated_experiment(model, "two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}},
                                                Eigen::Vector2d(0.4, 0.15), truth, sim, 2000);
  // Under the sanitizers (tens of times slower) a few runs check the code
  // path; the coverage needs the hundred.
#ifdef RICCATI_SANITIZED
  constexpr int kRuns = 4;
#else
  constexpr int kRuns = 100;
#endif
  constexpr double kSigma = 0.005;
  std::mt19937_64 rng(20261124);
  std::normal_distribution<double> noise(0.0, kSigma);
  Eigen::VectorXi covered = Eigen::VectorXi::Zero(4);
  double mean_sigma = 0.0;
  int white = 0;
  for (int run = 0; run < kRuns; ++run) {
    Experiment e = clean;
    for (Eigen::Index k = 0; k < e.data.size(); ++k) {
      for (Eigen::Index i = 0; i < 2; ++i) e.data.y(i, k) += noise(rng);
    }
    OutputErrorSettings s;
    s.simulation = sim;
    s.parameters = default_parameters(*model, truth.cwiseProduct(Eigen::Vector4d(1.1, 0.9, 1.1, 0.9)));
    auto r = output_error(model, {e}, s);
    ASSERT_TRUE(r.is_ok()) << r.status().to_string();
    for (Eigen::Index i = 0; i < 4; ++i) covered[i] += truth[i] >= r->ci_lower[i] && truth[i] <= r->ci_upper[i];
    mean_sigma += std::sqrt(r->sigma2) / kRuns;
    white += r->experiments[0].diagnostics.white();
  }
  std::printf("covered %d %d %d %d of %d; mean sigma-hat %.6g (true %.6g)\n", covered[0], covered[1], covered[2],
              covered[3], kRuns, mean_sigma, kSigma);
  if (kRuns < 100) {
    GTEST_SKIP() << "the coverage needs 100 runs; under the sanitizers " << kRuns
                 << " ran, for the code path only, and nothing is asserted of them";
  }
  for (Eigen::Index i = 0; i < 4; ++i) {
    EXPECT_GE(covered[i], 90) << model->param_names()[static_cast<std::size_t>(i)];
    EXPECT_LE(covered[i], 99) << model->param_names()[static_cast<std::size_t>(i)];
  }
  EXPECT_NEAR(mean_sigma, kSigma, 0.02 * kSigma);
  // Both outputs' residuals pass the whiteness test with probability 0.95^2
  // when the model is right: 90 of 100, binomial 95 % range 84-96.
  EXPECT_GE(white, 83);
  EXPECT_LE(white, 97);
  std::printf("white in %d of %d\n", white, kRuns);
}

// Coloured noise: AR(1) output noise with phi = 0.9 and the same variance,
// over 100 realisations. The residuals fail the whiteness test, so the
// intervals come from the covariance robust to autocorrelation, and hold the
// truth in 90-99 of them for every parameter; the white covariance's, on
// the same fits, hold it far less often.
TEST(OutputError, RobustIntervalsCoverTheTruthUnderAutocorrelatedNoise) {
  const ModelPtr model = registry().get("two_tank").value();
  const Eigen::VectorXd truth = model->theta_default();
  SimulationSettings sim;
  const Experiment clean = simulated_experiment(model, "two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}},
                                                Eigen::Vector2d(0.4, 0.15), truth, sim, 2000);
#ifdef RICCATI_SANITIZED
  constexpr int kRuns = 4;
#else
  constexpr int kRuns = 100;
#endif
  constexpr double kSigma = 0.005, kPhi = 0.9;
  std::mt19937_64 rng(20261128);
  std::normal_distribution<double> normal(0.0, 1.0);
  Eigen::VectorXi robust = Eigen::VectorXi::Zero(4), white = Eigen::VectorXi::Zero(4);
  int robust_chosen = 0;
  for (int run = 0; run < kRuns; ++run) {
    Experiment e = clean;
    for (Eigen::Index i = 0; i < 2; ++i) {
      double noise = kSigma * normal(rng);  // stationary from the first sample
      for (Eigen::Index k = 0; k < e.data.size(); ++k) {
        if (k > 0) noise = kPhi * noise + kSigma * std::sqrt(1.0 - kPhi * kPhi) * normal(rng);
        e.data.y(i, k) += noise;
      }
    }
    OutputErrorSettings s;
    s.simulation = sim;
    s.parameters = default_parameters(*model, truth.cwiseProduct(Eigen::Vector4d(1.1, 0.9, 1.1, 0.9)));
    auto r = output_error(model, {e}, s);  // covariance: auto
    ASSERT_TRUE(r.is_ok()) << r.status().to_string();
    robust_chosen += r->covariance_method.rfind("robust to autocorrelated residuals", 0) == 0;

    for (Eigen::Index i = 0; i < 4; ++i) robust[i] += truth[i] >= r->ci_lower[i] && truth[i] <= r->ci_upper[i];
    // The white covariance at the same estimate: started there, the fit stays.
    s.parameters.theta0 = r->theta;
    s.covariance = CovarianceChoice::kWhite;
    auto w = output_error(model, {e}, s);
    ASSERT_TRUE(w.is_ok()) << w.status().to_string();
    EXPECT_LT((w->theta - r->theta).cwiseAbs().maxCoeff(), 1e-6 * r->theta.cwiseAbs().maxCoeff());
    EXPECT_EQ(w->covariance_method, "white residuals: s2 (J'J)^-1");
    for (Eigen::Index i = 0; i < 4; ++i) white[i] += truth[i] >= w->ci_lower[i] && truth[i] <= w->ci_upper[i];
  }
  std::printf("robust chosen in %d; covered (robust) %d %d %d %d, (white) %d %d %d %d of %d\n", robust_chosen,
              robust[0], robust[1], robust[2], robust[3], white[0], white[1], white[2], white[3], kRuns);
  EXPECT_EQ(robust_chosen, kRuns) << "AR(1) residuals with phi = 0.9 pass the whiteness test";
  if (kRuns < 100) {
    GTEST_SKIP() << "the coverage needs 100 runs; under the sanitizers " << kRuns
                 << " ran, for the code path only, and nothing is asserted of them";
  }
  for (Eigen::Index i = 0; i < 4; ++i) {
    EXPECT_GE(robust[i], 90) << model->param_names()[static_cast<std::size_t>(i)];
    EXPECT_LE(robust[i], 99) << model->param_names()[static_cast<std::size_t>(i)];
    EXPECT_LT(white[i], 80) << model->param_names()[static_cast<std::size_t>(i)];
  }
}

// ln L, AIC, AICc and BIC against the residuals by hand: Gaussian with the
// outputs' given sigma, and with sigma unknown at its maximum-likelihood
// estimate RSS / n (one quantity more). k counts the free parameters and the
// estimated initial state; n the residuals the mask keeps.
TEST(OutputError, LogLikelihoodAndCriteriaAreThoseOfTheResidualsByHand) {
  const ModelPtr model = registry().get("two_tank").value();
  const Eigen::VectorXd truth = model->theta_default();
  Experiment e = simulated_experiment(model, "two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}},
                                      Eigen::Vector2d(0.4, 0.15), truth, SimulationSettings{}, 600);
  std::mt19937_64 rng(20261128);
  std::normal_distribution<double> noise(0.0, 0.01);
  for (Eigen::Index k = 0; k < e.data.size(); ++k) {
    for (Eigen::Index i = 0; i < 2; ++i) e.data.y(i, k) += noise(rng);
  }
  e.estimate_x0 = {true, false};
  e.mask = Eigen::ArrayXXd::Ones(2, e.data.size());
  e.mask.block(1, 100, 1, 50) = 0.0;  // h2 left out of 50 samples
  constexpr double kLog2Pi = 1.8378770664093454836;
  for (const bool sigma_given : {false, true}) {
    SCOPED_TRACE(sigma_given ? "sigma given" : "sigma estimated");
    OutputErrorSettings s;
    s.parameters = default_parameters(*model, truth.cwiseProduct(Eigen::Vector4d(1.1, 0.9, 1.1, 0.9)));
    const Eigen::Vector2d sigma(0.01, 0.02);
    if (sigma_given) s.output_sigma = sigma;
    auto r = output_error(model, {e}, s);
    ASSERT_TRUE(r.is_ok()) << r.status().to_string();
    const ExperimentResult& x = r->experiments[0];
    double n = 0.0, rss = 0.0, weighted = 0.0, log_sigma = 0.0;
    for (Eigen::Index k = 0; k < e.data.size(); ++k) {
      for (Eigen::Index i = 0; i < 2; ++i) {
        if (e.mask(i, k) == 0.0) continue;
        const double residual = x.y_measured(i, k) - x.y_model(i, k);
        n += 1.0;
        rss += residual * residual;
        weighted += residual * residual / (sigma[i] * sigma[i]);
        log_sigma += std::log(sigma[i]);
      }
    }
    const double log_likelihood = sigma_given ? -0.5 * weighted - log_sigma - 0.5 * n * kLog2Pi
                                              : -0.5 * n * (kLog2Pi + std::log(rss / n) + 1.0);
    const int k = 4 + 1 + (sigma_given ? 0 : 1);
    const InformationCriteria& c = r->criteria;
    EXPECT_EQ(n, 2.0 * 600 - 50);
    EXPECT_EQ(c.samples, n);
    EXPECT_EQ(c.estimated_quantities, k);
    EXPECT_NEAR(c.log_likelihood, log_likelihood, 1e-9 * std::abs(log_likelihood));
    EXPECT_NEAR(c.aic, 2.0 * k - 2.0 * log_likelihood, 1e-9 * std::abs(log_likelihood));
    EXPECT_NEAR(c.aicc, 2.0 * k - 2.0 * log_likelihood + 2.0 * k * (k + 1) / (n - k - 1),
                1e-9 * std::abs(log_likelihood));
    EXPECT_NEAR(c.bic, k * std::log(n) - 2.0 * log_likelihood, 1e-9 * std::abs(log_likelihood));
  }
}

// The likelihood-ratio test compare applies, over 100 realisations: with k2
// held at its true value (the smaller model true), 2 (ln L_free - ln L_held)
// stays below chi-square(1)'s 95 % quantile in 90-99 of them (the binomial
// 95 % range); held 2 % off, it exceeds it in every one.
TEST(OutputError, TheLikelihoodRatioPicksTheTrueNestedModel) {
  const ModelPtr model = registry().get("two_tank").value();
  const Eigen::VectorXd truth = model->theta_default();
  const Experiment clean = simulated_experiment(model, "two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}},
                                                Eigen::Vector2d(0.4, 0.15), truth, SimulationSettings{}, 600);
#ifdef RICCATI_SANITIZED
  constexpr int kRuns = 3;
#else
  constexpr int kRuns = 100;
#endif
  constexpr double kChiSquare1At95 = 3.841458820694124;
  std::mt19937_64 rng(20261129);
  std::normal_distribution<double> noise(0.0, 0.01);
  int smaller_kept = 0, wrong_rejected = 0;
  for (int run = 0; run < kRuns; ++run) {
    Experiment e = clean;
    for (Eigen::Index k = 0; k < e.data.size(); ++k) {
      for (Eigen::Index i = 0; i < 2; ++i) e.data.y(i, k) += noise(rng);
    }
    const auto fit = [&](std::optional<double> k2) {
      OutputErrorSettings s;
      Eigen::VectorXd start = truth.cwiseProduct(Eigen::Vector4d(1.05, 0.95, 1.05, 1.0));
      if (k2) start[3] = *k2;
      s.parameters = default_parameters(*model, start);
      if (k2) s.parameters.fixed[3] = true;
      auto r = output_error(model, {e}, s);
      EXPECT_TRUE(r.is_ok()) << r.status().to_string();
      return r.is_ok() ? r->criteria.log_likelihood : std::nan("");
    };
    const double free = fit(std::nullopt);
    smaller_kept += 2.0 * (free - fit(truth[3])) < kChiSquare1At95;
    wrong_rejected += 2.0 * (free - fit(0.98 * truth[3])) > kChiSquare1At95;
  }
  std::printf("the true smaller model kept in %d of %d; the wrong one rejected in %d\n", smaller_kept, kRuns,
              wrong_rejected);
  if (kRuns < 100) GTEST_SKIP() << "the rates need 100 runs; under the sanitizers " << kRuns << " ran, the code path only";
  EXPECT_GE(smaller_kept, 90);
  EXPECT_LE(smaller_kept, 99);
  EXPECT_EQ(wrong_rejected, kRuns);
}

// Hensen's published values for the arm: the simulated arm hardly moves
// (friction 1.5 against a current of 0.49), so the near-linear neurons and b
// are not told apart. The estimate says so rather than inventing a precision.
TEST(OutputError, ParametersTheDataCannotTellApartAreNamedNotGivenFalsePrecision) {
  const ModelPtr model = registry().get("rotating_arm").value();
  const Eigen::VectorXd hensen = model->theta_default();
  OutputErrorSettings s;
  s.simulation.integrator.substeps = 4;
  const Experiment e = simulated_experiment(model, "rotating_arm.csv", ColumnMapping{"t", {"i"}, {"q", "qdot"}},
                                            Eigen::Vector2d(0.0, 0.0), hensen, s.simulation, 3000);
  s.parameters = default_parameters(*model, hensen);
  s.optimizer.max_iterations = 5;
  const auto r = output_error(model, {e}, s);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  ASSERT_FALSE(r->warnings.empty());
  EXPECT_NE(r->warnings.front().find("not identifiable from these data"), std::string::npos) << r->warnings.front();
  int infinite = 0;
  for (Eigen::Index i = 0; i < r->theta_std.size(); ++i) {
    EXPECT_FALSE(std::isnan(r->theta_std[i]));
    infinite += std::isinf(r->theta_std[i]);
    for (Eigen::Index j = 0; j < r->theta_std.size(); ++j) EXPECT_FALSE(std::isnan(r->correlation(i, j)));
  }
  EXPECT_GT(infinite, 0) << "an unidentifiable parameter gets an infinite standard error";
}

TEST(OutputError, BadSettingsAreRefusedNamingTheParameter) {
  const ModelPtr model = registry().get("two_tank").value();
  const Experiment e = two_tank_experiment(*model);
  OutputErrorSettings s;
  s.parameters = default_parameters(*model, Eigen::Vector4d(20, 20, 1, 1));
  s.parameters.upper[1] = 10.0;  // theta0 of A2 = 20 is above it
  auto r = output_error(model, {e}, s);
  ASSERT_FALSE(r.is_ok());
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("theta0 of A2 = 20 is outside its bounds [0, 10]"), std::string::npos)
      << r.status().message();
  s.parameters = default_parameters(*model, Eigen::Vector4d(20, 20, 1, 1));
  s.parameters.lower[2] = 2.0;
  s.parameters.upper[2] = 1.0;
  r = output_error(model, {e}, s);
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().message().find("the bounds of k1 are not an interval: [2, 1]"), std::string::npos)
      << r.status().message();
  s.parameters = default_parameters(*model, Eigen::Vector4d(20, 20, 1, 1));
  s.parameters.log_scale[0] = true;  // A1's lower bound is 0
  r = output_error(model, {e}, s);
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().message().find("A1 is estimated on a log scale, so it needs a positive lower bound"),
            std::string::npos)
      << r.status().message();
}

// A start where the model cannot be simulated (A1 so small that the level's
// derivative overflows): no step can be taken, and the error says where and
// with which values.
TEST(OutputError, ASimulationThatFailsFromTheStartSaysWhereAndWithWhichValues) {
  const ModelPtr model = registry().get("two_tank").value();
  const Experiment e = two_tank_experiment(*model);
  OutputErrorSettings s;
  s.parameters = default_parameters(*model, Eigen::Vector4d(1e-308, 5, 0.08, 0.13));
  const auto r = output_error(model, {e}, s);
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().message().find("theta = [1e-308, 5, 0.08, 0.13]"), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("sample"), std::string::npos) << r.status().message();
}

// Bounds hold: an estimate that would leave them stays on the bound, and the
// result says which. Fixed parameters do not move; several experiments share
// the parameters and have their own initial states.
TEST(OutputError, BoundsFixedParametersAndSeveralExperiments) {
  const ModelPtr model = registry().get("two_tank").value();
  const Eigen::VectorXd truth = model->theta_default();
  SimulationSettings sim;
  const Experiment a = simulated_experiment(model, "two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}},
                                            Eigen::Vector2d(0.4, 0.15), truth, sim, 600);
  Experiment b = simulated_experiment(model, "two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}},
                                      Eigen::Vector2d(0.2, 0.3), truth, sim, 600);
  b.x0 = Eigen::Vector2d(0.25, 0.25);  // unknown: estimated
  b.estimate_x0 = {true, true};
  OutputErrorSettings s;
  s.parameters = default_parameters(*model, Eigen::Vector4d(12, 5, 0.07, 0.15));
  s.parameters.fixed[1] = true;   // A2 at its (true) start value
  s.parameters.upper[0] = 9.5;    // A1's truth, 10, is out of bounds
  s.parameters.theta0[0] = 9.0;
  s.parameters.log_scale[2] = true;
  s.parameters.lower[2] = 1e-3;
  const auto r = output_error(model, {a, b}, s);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  EXPECT_EQ(r->theta[0], 9.5) << "A1 held at its upper bound";
  EXPECT_EQ(r->theta[1], 5.0) << "A2 fixed";
  EXPECT_EQ(r->theta_std[1], 0.0);
  bool warned = false;
  for (const auto& w : r->warnings) warned |= w.find("A1 ended on its upper bound 9.5") != std::string::npos;
  EXPECT_TRUE(warned);
  ASSERT_EQ(r->experiments.size(), 2u);
  EXPECT_EQ(r->experiments[0].x0, Eigen::Vector2d(0.4, 0.15)) << "given, not estimated";
  // A1 held 5 % off its truth biases the fit, so b's initial state is not
  // checked against its truth here but below, where nothing is held.
  EXPECT_GT(r->experiments[1].x0_std[0], 0.0);
  EXPECT_NE(r->experiments[1].x0, Eigen::Vector2d(0.25, 0.25)) << "estimated: it moved from its start";
}

// Two experiments sharing the parameters, the second from an initial state
// that is estimated (started from (0.25, 0.25), truth (0.2, 0.3)): on the
// noise-free records it is the truth to the solver's precision; with noise
// of 5 mm on each level it is within 4 of its standard errors of the truth
// (a correct estimate and std fail that with probability 6e-5 per state,
// so the fixed seed passes or fails for good), and its std is below the
// noise of one sample (600 samples inform it).
TEST(OutputError, SeveralExperimentsEachRecoverTheirInitialState) {
  const ModelPtr model = registry().get("two_tank").value();
  const Eigen::VectorXd truth = model->theta_default();
  const Eigen::Vector2d x0_b(0.2, 0.3);
  SimulationSettings sim;
  const ColumnMapping mapping{"t", {"F1", "F2"}, {"h1", "h2"}};
  const Experiment a = simulated_experiment(model, "two_tank.csv", mapping, Eigen::Vector2d(0.4, 0.15), truth, sim, 600);
  Experiment b = simulated_experiment(model, "two_tank.csv", mapping, x0_b, truth, sim, 600);
  b.x0 = Eigen::Vector2d(0.25, 0.25);
  b.estimate_x0 = {true, true};
  OutputErrorSettings s;
  s.simulation = sim;
  s.parameters = default_parameters(*model, truth.cwiseProduct(Eigen::Vector4d(1.1, 0.9, 1.1, 0.9)));
  const auto clean = output_error(model, {a, b}, s);
  ASSERT_TRUE(clean.is_ok()) << clean.status().to_string();
  EXPECT_LT((clean->experiments[1].x0 - x0_b).cwiseAbs().maxCoeff(), 1e-8) << clean->experiments[1].x0.transpose();
  EXPECT_LT(worst_relative_error(clean->theta, truth), 1e-8);

  constexpr double kSigma = 0.005;
  std::mt19937_64 rng(31);
  std::normal_distribution<double> noise(0.0, kSigma);
  Experiment noisy_a = a, noisy_b = b;
  for (Experiment* e : {&noisy_a, &noisy_b}) {
    for (Eigen::Index k = 0; k < e->data.size(); ++k) {
      for (Eigen::Index i = 0; i < 2; ++i) e->data.y(i, k) += noise(rng);
    }
  }
  const auto r = output_error(model, {noisy_a, noisy_b}, s);
  ASSERT_TRUE(r.is_ok()) << r.status().to_string();
  const ExperimentResult& eb = r->experiments[1];
  for (Eigen::Index i = 0; i < 2; ++i) {
    EXPECT_GT(eb.x0_std[i], 0.0);
    EXPECT_LT(eb.x0_std[i], kSigma);
    EXPECT_LT(std::abs(eb.x0[i] - x0_b[i]), 4.0 * eb.x0_std[i])
        << "state " << i << ": " << eb.x0[i] << " +- " << eb.x0_std[i] << ", truth " << x0_b[i];
  }
}

// Log scales. A log-scaled parameter is estimated as phi = log(theta): the
// conversions are exp and log, d theta / d phi = theta = exp(phi), and the
// Jacobian the optimiser sees is d y / d phi = d y / d theta * theta (the
// chain rule, as output_error forms it from the sensitivities), here
// against central differences of the simulation in phi.
TEST(OutputError, LogScaleConversionsAndTheirChainRule) {
  const ModelPtr model = registry().get("two_tank").value();
  ParameterSettings p = default_parameters(*model, model->theta_default());
  p.log_scale[2] = p.log_scale[3] = true;
  for (const double theta : {1e-3, 0.0791, 1.0, 42.0}) {
    EXPECT_DOUBLE_EQ(to_solver(p, 2, theta), std::log(theta));
    EXPECT_DOUBLE_EQ(from_solver(p, 2, std::log(theta)), theta);
    EXPECT_DOUBLE_EQ(from_solver(p, 2, to_solver(p, 2, theta)), theta);
    EXPECT_EQ(to_solver(p, 0, theta), theta) << "A1 is not log-scaled";
    EXPECT_EQ(from_solver(p, 0, theta), theta);
    EXPECT_EQ(theta_per_phi(p, 0, theta), 1.0);
    const double phi = std::log(theta), h = 1e-6;
    const double numeric = (from_solver(p, 2, phi + h) - from_solver(p, 2, phi - h)) / (2 * h);
    EXPECT_NEAR(theta_per_phi(p, 2, theta), numeric, 1e-8 * theta) << "d theta / d phi at theta = " << theta;
  }

  SimulationSettings sim;
  const Experiment e = simulated_experiment(model, "two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}},
                                            Eigen::Vector2d(0.4, 0.15), model->theta_default(), sim, 300);
  auto simulator = SensitivitySimulator::create(model, sim, false);
  ASSERT_TRUE(simulator.is_ok()) << simulator.status().to_string();
  const Eigen::VectorXd theta = model->theta_default().cwiseProduct(Eigen::Vector4d(1.1, 0.9, 1.2, 0.8));
  SimulatedRecord at;
  ASSERT_TRUE(simulator->simulate(e.data.t, e.data.u, e.x0, theta, true, &at).is_ok());
  for (const Eigen::Index j : {Eigen::Index{2}, Eigen::Index{3}}) {
    const double h = 1e-5;  // in log theta: a relative step of 1e-5
    SimulatedRecord plus, minus;
    Eigen::VectorXd tp = theta, tm = theta;
    tp[j] = from_solver(p, j, to_solver(p, j, theta[j]) + h);
    tm[j] = from_solver(p, j, to_solver(p, j, theta[j]) - h);
    ASSERT_TRUE(simulator->simulate(e.data.t, e.data.u, e.x0, tp, false, &plus).is_ok());
    ASSERT_TRUE(simulator->simulate(e.data.t, e.data.u, e.x0, tm, false, &minus).is_ok());
    const Eigen::MatrixXd numeric = (plus.y - minus.y) / (2 * h);  // [ny x N]
    const Eigen::Map<const Eigen::MatrixXd> numeric_rows(numeric.data(), numeric.size(), 1);
    const Eigen::VectorXd chain = at.dy_dtheta.col(j) * theta_per_phi(p, j, theta[j]);
    const double scale = numeric_rows.cwiseAbs().maxCoeff();
    ASSERT_GT(scale, 0.0);
    EXPECT_LT((chain - numeric_rows.col(0)).cwiseAbs().maxCoeff(), 1e-6 * scale)
        << model->param_names()[static_cast<std::size_t>(j)];
    // Without the factor theta the two differ by 1 / theta (k ~ 0.1: a factor 10).
    EXPECT_GT((at.dy_dtheta.col(j) - numeric_rows.col(0)).cwiseAbs().maxCoeff(), 0.5 * scale);
  }
}

// A fit with k1 and k2 on log scales finds what the fit in theta finds:
// the truth on the noise-free record; on a noisy one the same estimate, and
// the same standard errors, in theta's unit (the covariance is formed in
// theta: the delta method, std(theta) = theta std(log theta)). Its 95 %
// interval is the one of log theta mapped back, theta exp(+-1.96 std / theta):
// positive, and wider above than below.
TEST(OutputError, ALogScaledFitRecoversTheTruthAndReportsItsStdInTheParametersUnit) {
  const ModelPtr model = registry().get("two_tank").value();
  const Eigen::VectorXd truth = model->theta_default();
  SimulationSettings sim;
  const Experiment clean = simulated_experiment(model, "two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}},
                                                Eigen::Vector2d(0.4, 0.15), truth, sim, 800);
  OutputErrorSettings linear;
  linear.simulation = sim;
  linear.parameters = default_parameters(*model, truth.cwiseProduct(Eigen::Vector4d(1.1, 0.9, 1.3, 0.7)));
  OutputErrorSettings logs = linear;
  for (const Eigen::Index j : {Eigen::Index{2}, Eigen::Index{3}}) {
    logs.parameters.log_scale[static_cast<std::size_t>(j)] = true;
    logs.parameters.lower[j] = 1e-4;
  }
  const auto exact = output_error(model, {clean}, logs);
  ASSERT_TRUE(exact.is_ok()) << exact.status().to_string();
  EXPECT_TRUE(exact->converged) << exact->termination;
  EXPECT_LT(worst_relative_error(exact->theta, truth), 1e-8);

  Experiment noisy = clean;
  std::mt19937_64 rng(20261128);
  std::normal_distribution<double> noise(0.0, 0.005);
  for (Eigen::Index k = 0; k < noisy.data.size(); ++k) {
    for (Eigen::Index i = 0; i < 2; ++i) noisy.data.y(i, k) += noise(rng);
  }
  const auto in_theta = output_error(model, {noisy}, linear);
  const auto in_log = output_error(model, {noisy}, logs);
  ASSERT_TRUE(in_theta.is_ok()) << in_theta.status().to_string();
  ASSERT_TRUE(in_log.is_ok()) << in_log.status().to_string();
  for (Eigen::Index j = 0; j < 4; ++j) {
    const std::string& name = model->param_names()[static_cast<std::size_t>(j)];
    EXPECT_NEAR(in_log->theta[j], in_theta->theta[j], 1e-6 * std::abs(in_theta->theta[j])) << name;
    EXPECT_NEAR(in_log->theta_std[j], in_theta->theta_std[j], 1e-4 * in_theta->theta_std[j]) << name;
    EXPECT_LT(std::abs(in_log->theta[j] - truth[j]), 4.0 * in_log->theta_std[j]) << name;
  }
  for (const Eigen::Index j : {Eigen::Index{2}, Eigen::Index{3}}) {
    const double v = in_log->theta[j], sd = in_log->theta_std[j], z = 1.959963984540054;
    EXPECT_NEAR(in_log->ci_lower[j], v * std::exp(-z * sd / v), 1e-12 * v);
    EXPECT_NEAR(in_log->ci_upper[j], v * std::exp(z * sd / v), 1e-12 * v);
    EXPECT_GT(in_log->ci_upper[j] - v, v - in_log->ci_lower[j]) << "wider above";
    EXPECT_NEAR(in_theta->ci_upper[j], in_theta->theta[j] + z * in_theta->theta_std[j], 1e-12 * v) << "symmetric in theta";
  }
}

// Every parameter fixed and no initial state to estimate: nothing to
// iterate on. Ceres runs no iteration and lists none, which was reported as
// 0 - 1 (4294967295 once unsigned in the API).
TEST(OutputError, EveryParameterFixedReportsZeroIterations) {
  const ModelPtr model = registry().get("two_tank").value();
  const Experiment e = two_tank_experiment(*model);
  OutputErrorSettings s;
  s.parameters = default_parameters(*model, model->theta_default());
  s.parameters.fixed.assign(static_cast<std::size_t>(model->ntheta()), true);
  const auto r = output_error(model, {e}, s);
  if (!r.is_ok()) {
    // Refusing a problem with no unknowns would do as well; a result must say 0.
    EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument) << r.status().to_string();
    return;
  }
  EXPECT_EQ(r->iterations, 0);
  EXPECT_EQ(r->theta, model->theta_default());
}

}  // namespace
}  // namespace riccati
