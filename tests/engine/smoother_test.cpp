// The fixed-interval smoothers (estimation/smoother.hpp).
//
// On a linear model the RTS smoother after the EKF and the unscented RTS
// smoother after the UKF must both be the exact discrete RTS smoother,
// written here from the matrix exponential, with and without process noise.
// On a record of the two-tank model simulated here from known parameters and
// states, smoothing must bring the states closer to the truth than filtering,
// and the two smoothers must agree on the parameters within their standard
// deviations. Then what the API promises: the optimal filter refused, a stop
// request, a sample range, errors that say where.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <fstream>
#include <iomanip>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <stop_token>
#include <string>
#include <unsupported/Eigen/MatrixFunctions>

#include "engine/estimation/smoother.hpp"
#include "engine/estimation/validation.hpp"
#include "engine/filters/filter_kinds.hpp"
#include "engine/models/model.hpp"
#include "engine/models/plugin_loader.hpp"
#include "riccati/model.hpp"

namespace riccati {
namespace {

// Numbers in messages, with 6 significant digits.
template <typename T>
std::string g6(const T& value) {
  std::ostringstream out;
  out << std::setprecision(6) << value;
  return out.str();
}

// A mass on a spring pushed by the input u and by an unknown constant force
// theta, of which only the position is measured:
//     p' = v,   v' = -2 p - 0.3 v + u + theta,   y = p.
// The augmented z = [p, v, theta] obeys z' = Ac z + Bc u, y = [1 0 0] z.
struct ForcedSpring {
  static constexpr ModelSpec<2, 1, 1, 1> spec{
      .name = "forced_spring",
      .states = {"p", "v"},
      .params = {"force"},
      .inputs = {"u"},
      .outputs = {"y"},
      .theta_default = {0.0},
  };
  template <typename T>
  void f(const T* x, const T* theta, const double* u, double /*t*/, T* dx) const {
    dx[0] = x[1];
    dx[1] = -2.0 * x[0] - 0.3 * x[1] + u[0] + theta[0];
  }
  template <typename T>
  void g(const T* x, const T* /*theta*/, const double* /*u*/, double /*t*/, T* y) const {
    y[0] = x[0];
  }
};

ModelPtr forced_spring() {
  auto m = Model::create(detail::Plugin<ForcedSpring>::entry(RICCATI_MODEL_ABI_VERSION), nullptr,
                         "forced_spring (in-process)");
  EXPECT_TRUE(m.is_ok()) << m.status().to_string();
  return m.value();
}

// The exact discrete model of ForcedSpring over a sample interval dt with the
// input held: z+ = Phi z + Gamma u, and the process noise covariance Qd
// the filter adds: exactly discretised (Van Loan) for the EKF, whose
// P' = A P + P A^T + Q integrates to it; Q dt for the UKF, which adds that.
struct DiscreteSpring {
  Eigen::Matrix3d Phi, Qd;
  Eigen::Vector3d Gamma;
  Eigen::RowVector3d C{1.0, 0.0, 0.0};

  DiscreteSpring(const Eigen::Matrix3d& Q, double dt, bool van_loan_noise) {
    Eigen::Matrix3d Ac;
    Ac << 0, 1, 0, -2, -0.3, 1, 0, 0, 0;
    Eigen::Matrix4d M = Eigen::Matrix4d::Zero();
    M.topLeftCorner(3, 3) = Ac;
    M(1, 3) = 1.0;  // Bc = [0 1 0]^T
    const Eigen::Matrix4d E = (M * dt).exp();
    Phi = E.topLeftCorner(3, 3);
    Gamma = E.topRightCorner(3, 1);
    if (van_loan_noise) {
      // exp([-A Q; 0 A^T] dt) = [. Phi^-1 Qd; 0 Phi^T].
      Eigen::Matrix<double, 6, 6> V = Eigen::Matrix<double, 6, 6>::Zero();
      V.topLeftCorner(3, 3) = -Ac;
      V.topRightCorner(3, 3) = Q;
      V.bottomRightCorner(3, 3) = Ac.transpose();
      const Eigen::Matrix<double, 6, 6> EV = (V * dt).exp();
      Qd = EV.bottomRightCorner(3, 3).transpose() * EV.topRightCorner(3, 3);
    } else {
      Qd = Q * dt;
    }
  }
};

// The exact discrete Kalman filter and RTS smoother (Rauch, Tung, Striebel
// 1965) of that model, in the textbook form, over measurements y_0 .. y_N-1
// with inputs u_0 .. u_N-1, starting from z0, P0 at the first one. The gain
// is G_k = P_k|k Phi^T P_k+1|k^+ with the minimum-norm pseudo-inverse (a
// complete orthogonal decomposition), which with a singular P_k+1|k (states
// known and no process noise) is one generalised inverse among those that
// give the same smoother.
struct ExactRts {
  std::vector<Eigen::Vector3d> z_filtered, z_smoothed;
  std::vector<Eigen::Matrix3d> P_filtered, P_smoothed;

  ExactRts(const DiscreteSpring& m, double R, const Eigen::Vector3d& z0, const Eigen::Matrix3d& P0,
           const Eigen::VectorXd& u, const Eigen::VectorXd& y) {
    const Eigen::Index N = y.size();
    std::vector<Eigen::Vector3d> z_prior(N);
    std::vector<Eigen::Matrix3d> P_prior(N);
    Eigen::Vector3d z = z0;
    Eigen::Matrix3d P = P0;
    for (Eigen::Index k = 0; k < N; ++k) {
      if (k > 0) {
        z = m.Phi * z + m.Gamma * u[k - 1];
        P = m.Phi * P * m.Phi.transpose() + m.Qd;
        z_prior[k] = z;
        P_prior[k] = P;
      }
      const double S = (m.C * P * m.C.transpose())(0, 0) + R;
      const Eigen::Vector3d K = P * m.C.transpose() / S;
      z += K * (y[k] - (m.C * z)(0, 0));
      P = (Eigen::Matrix3d::Identity() - K * m.C) * P;
      P = 0.5 * (P + P.transpose()).eval();
      z_filtered.push_back(z);
      P_filtered.push_back(P);
    }
    z_smoothed = z_filtered;
    P_smoothed = P_filtered;
    for (Eigen::Index k = N - 2; k >= 0; --k) {
      Eigen::CompleteOrthogonalDecomposition<Eigen::Matrix3d> cod(3, 3);
      cod.setThreshold(1e-9);  // before compute(), which decides the rank
      cod.compute(P_prior[k + 1]);
      const Eigen::Matrix3d G = cod.solve(m.Phi * P_filtered[k]).transpose();  // P_k+1|k symmetric
      z_smoothed[k] = z_filtered[k] + G * (z_smoothed[k + 1] - z_prior[k + 1]);
      P_smoothed[k] = P_filtered[k] + G * (P_smoothed[k + 1] - P_prior[k + 1]) * G.transpose();
    }
  }
};

struct LinearCase {
  const char* name;
  FilterKind kind;
  bool process_noise;  // Q > 0, or Q = 0
  bool states_known;   // P0's state variances zero (then with Q = 0 every P is singular)
};

void PrintTo(const LinearCase& c, std::ostream* os) { *os << c.name; }

class LinearSmoother : public ::testing::TestWithParam<LinearCase> {};

TEST_P(LinearSmoother, IsTheExactRtsSmoother) {
  const LinearCase c = GetParam();
  const double dt = 0.1, R = 0.01;
  const Eigen::Index N = 200;
  const Eigen::Matrix3d Q =
      c.process_noise ? Eigen::Vector3d(0.01, 0.02, 0.001).asDiagonal() : Eigen::Matrix3d(Eigen::Matrix3d::Zero());
  const Eigen::Matrix3d P0 = Eigen::Vector3d(c.states_known ? 0.0 : 0.5, c.states_known ? 0.0 : 0.3, 1.0).asDiagonal();
  const Eigen::Vector3d z0(0.2, -0.1, 0.0);

  // A record of the exact discrete model with force 0.3 (without process
  // noise), its position measured with noise of variance R.
  const DiscreteSpring exact(Q, dt, /*van_loan_noise=*/c.kind == FilterKind::kEkf);
  Dataset data;
  data.input_names = {"u"};
  data.output_names = {"y"};
  data.t.resize(N);
  data.u.resize(1, N);
  data.y.resize(1, N);
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, std::sqrt(R));
  Eigen::Vector3d truth(c.states_known ? 0.2 : 0.25, c.states_known ? -0.1 : 0.0, 0.3);
  for (Eigen::Index k = 0; k < N; ++k) {
    if (k > 0) truth = exact.Phi * truth + exact.Gamma * data.u(0, k - 1);
    data.t[k] = k * dt;
    data.u(0, k) = std::sin(0.05 * k) + (k % 40 < 20 ? 0.5 : -0.5);
    data.y(0, k) = truth[0] + noise(rng);
  }
  const ExactRts reference(exact, R, z0, P0, data.u.row(0).transpose(), data.y.row(0).transpose());

  SmootherSettings s;
  s.filter.kind = c.kind;
  s.filter.Q = Q;
  s.filter.R = Eigen::MatrixXd::Constant(1, 1, R);
  s.filter.integrator.kind = IntegratorKind::kRk4;
  // The EKF's P_k+1|k comes from its Riccati equation and its C_k from Phi,
  // which RK4 makes agree only to its truncation error, and where P_k+1|k is
  // singular (states known, Q = 0) the backward pass amplifies that: the
  // worst difference below is 2.7e-10 with 100 substeps per sample, 1.7e-11
  // with 200, 1.7e-12 with 400 (RK4's fourth order). With h = dt / 400 the
  // local error of the covariance, (h |L|)^5 / 120 with |L| <= 2 |A| ~ 5 the
  // norm of P -> A P + P A^T, is 2e-17 per substep: below rounding.
  s.filter.integrator.substeps = 400;
  s.initial.x0 = z0.head(2);
  s.initial.theta0 = z0.tail(1);
  s.initial.P0 = P0;
  const auto smoothed = smooth(forced_spring(), data, s);
  ASSERT_TRUE(smoothed.is_ok()) << smoothed.status().to_string();
  const SmootherResult& r = smoothed.value();
  ASSERT_EQ(r.z_smoothed.cols(), N);
  ASSERT_EQ(r.P_smoothed.cols(), 3 * N);

  // Rounding only (worst differences 7e-15 to 2e-12, in the test's
  // properties). P_k|N is P_k|k plus a correction, so its rounding is
  // relative to the larger of the two (early on P_k|k is 5000 times larger
  // than P_k|N when the states start known): the error is measured so.
  const double tolerance = 1e-10;
  double worst = 0.0;
  for (Eigen::Index k = 0; k < N; ++k) {
    const double ef =
        (r.z_filtered.col(k) - reference.z_filtered[k]).norm() / std::max(1.0, reference.z_filtered[k].norm());
    const double ez =
        (r.z_smoothed.col(k) - reference.z_smoothed[k]).norm() / std::max(1.0, reference.z_smoothed[k].norm());
    const double eP = (r.smoothed_covariance(k) - reference.P_smoothed[k]).norm() /
                      std::max(reference.P_smoothed[k].norm(), reference.P_filtered[k].norm());
    worst = std::max({worst, ef, ez, eP});
    ASSERT_LT(ef, tolerance) << "filtered state differs at sample " << k + 1;
    ASSERT_LT(ez, tolerance) << "smoothed state differs at sample " << k + 1 << ": "
                             << g6(r.z_smoothed.col(k).transpose()) << " against "
                             << g6(reference.z_smoothed[k].transpose());
    ASSERT_LT(eP, tolerance) << "smoothed covariance differs at sample " << k + 1 << ":\n"
                             << g6(r.smoothed_covariance(k)) << "\nagainst\n"
                             << g6(reference.P_smoothed[k]);
    const Eigen::VectorXd std_smoothed = r.smoothed_covariance(k).diagonal().cwiseSqrt();
    EXPECT_TRUE(r.std_smoothed.col(k).isApprox(std_smoothed)) << "sample " << k + 1;
    EXPECT_NEAR(r.y_model(0, k), r.z_smoothed(0, k), 1e-15) << "y = p";
  }
  // The comparison must be about something: smoothing changed the early
  // estimates by far more than the tolerance.
  EXPECT_GT((r.z_smoothed.col(10) - r.z_filtered.col(10)).norm(), 1e-3);
  RecordProperty("worst_relative_difference", g6(worst));
}

INSTANTIATE_TEST_SUITE_P(
    EkfAndUkf, LinearSmoother,
    ::testing::Values(LinearCase{"ekf", FilterKind::kEkf, true, false},
                      LinearCase{"ekf_no_process_noise", FilterKind::kEkf, false, false},
                      LinearCase{"ekf_no_process_noise_states_known", FilterKind::kEkf, false, true},
                      LinearCase{"ukf", FilterKind::kUkf, true, false},
                      LinearCase{"ukf_no_process_noise", FilterKind::kUkf, false, false},
                      LinearCase{"ukf_no_process_noise_states_known", FilterKind::kUkf, false, true}),
    [](const auto& param) { return std::string(param.param.name); });

// A two-tank record with known true states: the inputs and sample times of
// tests/data/two_tank_noisy.csv, the states simulated here from its JSON's
// true parameters and initial levels (RK4 with 100 substeps, far finer than
// the filters' 10), and the levels measured with Gaussian noise of the
// JSON's standard deviation, drawn with a fixed seed.
struct TwoTankRecord {
  ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  ModelPtr model = registry.find("two_tank");
  nlohmann::json meta;
  Eigen::VectorXd theta_true;
  Eigen::MatrixXd x_true;  // [2 x N]
  double sigma = 0.0;
  Dataset data;

  TwoTankRecord() {
    std::ifstream in(RICCATI_TEST_DATA_DIR "/two_tank_noisy.json");
    meta = nlohmann::json::parse(in);
    theta_true.resize(4);
    for (int i = 0; i < 4; ++i) {
      theta_true[i] = meta["parameters"][meta["parameter_order"][i].get<std::string>()].get<double>();
    }
    const Eigen::Vector2d x0(meta["true_initial_state"][0].get<double>(), meta["true_initial_state"][1].get<double>());
    sigma = meta["noise_std"][0].get<double>();
    data = read_csv_file(RICCATI_TEST_DATA_DIR "/two_tank_noisy.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}})
               .value();
    SimulationSettings simulation;
    simulation.integrator.substeps = 100;
    auto y = simulate(*model, data.t, data.u, x0, theta_true, simulation, &x_true);
    EXPECT_TRUE(y.is_ok()) << y.status().to_string();
    std::mt19937 rng(2024);
    std::normal_distribution<double> noise(0.0, sigma);
    data.y = y.value().unaryExpr([&](double v) { return v + noise(rng); });
  }

  // The EKF or the UKF as Hensen ran it (RK4, 10 substeps, Q = 0), with R the
  // noise's true variance, from the first measurement (its variance sigma^2)
  // and parameters 30 % off the truth with a standard deviation of 50 % of
  // them: one pass must learn them.
  SmootherSettings settings(FilterKind kind) const {
    SmootherSettings s;
    s.filter.kind = kind;
    s.filter.integrator.substeps = 10;
    s.filter.Q = Eigen::MatrixXd::Zero(6, 6);
    s.filter.R = Eigen::Matrix2d::Identity() * sigma * sigma;
    s.initial.mode = InitialState::kFirstMeasurement;
    s.initial.theta0 = 1.3 * theta_true;
    Eigen::VectorXd p0(6);
    p0 << sigma * sigma, sigma * sigma, (0.5 * theta_true).cwiseAbs2();
    s.initial.P0 = p0.asDiagonal();
    return s;
  }
};

const TwoTankRecord& two_tank() {
  static const TwoTankRecord record;
  return record;
}

// The root mean square error of estimated levels [2 x N] against the truth.
double rms_error(const Eigen::MatrixXd& x, const Eigen::MatrixXd& x_true) {
  return std::sqrt((x - x_true).squaredNorm() / static_cast<double>(x.size()));
}

class TwoTankSmoother : public ::testing::TestWithParam<FilterKind> {};

TEST_P(TwoTankSmoother, SmoothedLevelsAreCloserToTheTruthThanFiltered) {
  const TwoTankRecord& rec = two_tank();
  const auto result = smooth(rec.model, rec.data, rec.settings(GetParam()));
  ASSERT_TRUE(result.is_ok()) << result.status().to_string();
  const SmootherResult& r = result.value();
  const double filtered = rms_error(r.z_filtered.topRows(2), rec.x_true);
  const double smoothed = rms_error(r.z_smoothed.topRows(2), rec.x_true);
  RecordProperty("rms_error_filtered", g6(filtered));
  RecordProperty("rms_error_smoothed", g6(smoothed));
  EXPECT_LT(smoothed, filtered);
  // And by a margin that matters: with Q = 0 every smoothed level follows
  // from the six values of [x0; theta] estimated from all 4000 measurements,
  // so its error is a small fraction of the measurement noise, while the
  // filter's early estimates use parameters still far off.
  EXPECT_LT(smoothed, 0.25 * rec.sigma) << "filtered " << g6(filtered);
  // The smoothed outputs are the model's at the smoothed estimate: here y = x.
  EXPECT_TRUE(r.y_model.isApprox(r.z_smoothed.topRows(2), 1e-15));
}

INSTANTIATE_TEST_SUITE_P(EkfAndUkf, TwoTankSmoother, ::testing::Values(FilterKind::kEkf, FilterKind::kUkf),
                         [](const auto& param) { return std::string(filter_kind_name(param.param)); });

TEST(TwoTankSmoother, EkfAndUkfAgreeOnTheParametersWithinTheirStandardDeviations) {
  const TwoTankRecord& rec = two_tank();
  const auto ekf = smooth(rec.model, rec.data, rec.settings(FilterKind::kEkf));
  const auto ukf = smooth(rec.model, rec.data, rec.settings(FilterKind::kUkf));
  ASSERT_TRUE(ekf.is_ok()) << ekf.status().to_string();
  ASSERT_TRUE(ukf.is_ok()) << ukf.status().to_string();
  const Eigen::Index N = rec.data.size();
  for (Eigen::Index k : {Eigen::Index(0), N / 2, N - 1}) {
    for (int i = 2; i < 6; ++i) {
      const double a = ekf->z_smoothed(i, k), b = ukf->z_smoothed(i, k);
      const double std = std::min(ekf->std_smoothed(i, k), ukf->std_smoothed(i, k));
      EXPECT_LT(std::abs(a - b), std) << ekf->names[i] << " at sample " << k + 1 << ": EKF " << g6(a) << ", UKF "
                                      << g6(b) << ", standard deviations " << g6(ekf->std_smoothed(i, k)) << " and "
                                      << g6(ukf->std_smoothed(i, k));
      // Both are near the truth too (4 standard deviations).
      EXPECT_LT(std::abs(a - rec.theta_true[i - 2]), 4 * ekf->std_smoothed(i, k)) << ekf->names[i];
    }
  }
  RecordProperty("theta_ekf", g6(ekf->z_smoothed.bottomRows(4).col(0).transpose()));
  RecordProperty("theta_ukf", g6(ukf->z_smoothed.bottomRows(4).col(0).transpose()));
  RecordProperty("theta_std_ekf", g6(ekf->std_smoothed.bottomRows(4).col(0).transpose()));
  RecordProperty("theta_std_ukf", g6(ukf->std_smoothed.bottomRows(4).col(0).transpose()));
  // With no process noise on theta, theta_k|N is the final estimate at every k.
  EXPECT_TRUE(ekf->z_smoothed.bottomRows(4).col(0).isApprox(ekf->z_filtered.bottomRows(4).col(N - 1), 1e-9));
}

TEST(Smoother, RefusedForTheOptimalFilter) {
  auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  ModelPtr manipulator = registry.find("flexible_manipulator");
  ASSERT_NE(manipulator, nullptr);
  FilterSettings f;
  f.kind = FilterKind::kOptimal;
  f.optimal.V = Eigen::VectorXd::Constant(optimal_equation_count(*manipulator), 1.0).asDiagonal();
  f.optimal.W = Eigen::VectorXd::Constant(manipulator->nz(), 1.0).asDiagonal();
  ASSERT_TRUE(validate(f, *manipulator).is_ok()) << validate(f, *manipulator).to_string();
  f.smoothing = true;
  const auto filter = make_filter(manipulator, f);
  ASSERT_FALSE(filter.is_ok());
  EXPECT_EQ(filter.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(filter.status().message().find("the optimal filter does not support smoothing"), std::string::npos)
      << filter.status().message();

  // smooth() turns the setting on itself, so the optimal filter is refused there too.
  SmootherSettings s;
  s.filter = f;
  s.filter.smoothing = false;
  s.initial.x0 = Eigen::VectorXd::Zero(manipulator->nx());
  s.initial.theta0 = manipulator->theta_default();
  s.initial.P0 = Eigen::MatrixXd::Identity(manipulator->nz(), manipulator->nz());
  const Dataset data =
      read_csv_file(RICCATI_TEST_DATA_DIR "/flexible_manipulator.csv", ColumnMapping{"t", {"T"}, {"s1", "s2"}}).value();
  const auto smoothed = smooth(manipulator, data, s);
  ASSERT_FALSE(smoothed.is_ok());
  EXPECT_EQ(smoothed.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(smoothed.status().message().find("does not support smoothing"), std::string::npos)
      << smoothed.status().message();
}

TEST(Smoother, AStopRequestEndsTheRun) {
  const TwoTankRecord& rec = two_tank();
  for (const SmootherProgress::Pass pass : {SmootherProgress::Pass::kForward, SmootherProgress::Pass::kBackward}) {
    std::stop_source stop;
    SmootherHooks hooks;
    hooks.stop = stop.get_token();
    Eigen::Index calls = 0;
    hooks.progress = [&](const SmootherProgress& p) {
      ++calls;
      if (p.pass == pass && p.sample == 100) stop.request_stop();
    };
    const auto r = smooth(rec.model, rec.data, rec.settings(FilterKind::kEkf), hooks);
    ASSERT_FALSE(r.is_ok());
    EXPECT_EQ(r.status().code(), StatusCode::kCancelled);
    const std::string where = pass == SmootherProgress::Pass::kForward ? "forward pass at sample 101 (t = 100"
                                                                       : "backward pass at sample 99 (t = 98";
    EXPECT_NE(r.status().message().find(where), std::string::npos) << r.status().message();
    // Every sample is reported once, forward then backward, and none after the stop.
    const Eigen::Index N = rec.data.size();
    EXPECT_EQ(calls, pass == SmootherProgress::Pass::kForward ? 100 : N + (N - 1 - 99));
  }
}

TEST(Smoother, ASampleRangeIsTheRangeAlone) {
  // Smoothing samples [first, end) of a record is smoothing a record of only
  // those samples, bit for bit.
  const TwoTankRecord& rec = two_tank();
  SmootherSettings s = rec.settings(FilterKind::kUkf);
  s.first_sample = 300;
  s.end_sample = 900;
  const auto ranged = smooth(rec.model, rec.data, s);
  ASSERT_TRUE(ranged.is_ok()) << ranged.status().to_string();
  Dataset slice = rec.data;
  slice.t = rec.data.t.segment(300, 600);
  slice.u = rec.data.u.middleCols(300, 600);
  slice.y = rec.data.y.middleCols(300, 600);
  s.first_sample = 0;
  s.end_sample = -1;
  const auto whole = smooth(rec.model, slice, s);
  ASSERT_TRUE(whole.is_ok()) << whole.status().to_string();
  EXPECT_EQ(ranged->t.size(), 600);
  EXPECT_TRUE((ranged->t.array() == slice.t.array()).all());
  EXPECT_TRUE((ranged->z_smoothed.array() == whole->z_smoothed.array()).all());
  EXPECT_TRUE((ranged->P_smoothed.array() == whole->P_smoothed.array()).all());
  EXPECT_TRUE((ranged->innovations.array() == whole->innovations.array()).all());

  s.first_sample = 1999;
  s.end_sample = 2000;
  const auto one = smooth(rec.model, rec.data, s);
  ASSERT_FALSE(one.is_ok());
  EXPECT_EQ(one.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(one.status().message().find("at least two"), std::string::npos) << one.status().message();
}

TEST(Smoother, AnErrorSaysWhere) {
  // A huge initial variance of A1 with near-exact measurements sends A1
  // negative, as in online_runner_test: the filter diverges at a sample,
  // which the error names.
  const TwoTankRecord& rec = two_tank();
  SmootherSettings s = rec.settings(FilterKind::kEkf);
  s.initial.theta0[0] = 1e-3;
  s.initial.P0(2, 2) = 1e12;
  s.filter.R = Eigen::Matrix2d::Identity() * 1e-12;
  const auto r = smooth(rec.model, rec.data, s);
  ASSERT_FALSE(r.is_ok());
  EXPECT_NE(r.status().code(), StatusCode::kInvalidArgument) << r.status().message();
  EXPECT_NE(r.status().message().find("sample "), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("(t = "), std::string::npos) << r.status().message();
}

}  // namespace
}  // namespace riccati
