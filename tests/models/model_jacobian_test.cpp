// The built-in model plugins, loaded the way the daemon loads them: exact
// Jacobians against finite differences, batched against single evaluation,
// and noise-free datasets reproduced by simulating the plugin's f.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cmath>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "engine/models/model.hpp"
#include "engine/models/plugin_loader.hpp"

namespace riccati {
namespace {

const ModelRegistry& builtins() {
  static const ModelRegistry registry = [] {
    auto loaded = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR);
    if (!loaded.is_ok()) {
      ADD_FAILURE() << loaded.status().to_string();
      return ModelRegistry{};
    }
    return std::move(loaded).value();
  }();
  return registry;
}

ModelPtr builtin(const std::string& name) {
  ModelPtr m = builtins().find(name);
  EXPECT_NE(m, nullptr) << "built-in model " << name << " not found in " << RICCATI_TEST_PLUGIN_DIR;
  return m;
}

// ---------------------------------------------------------------------------
// Jacobians

struct Range {
  double lo, hi;
  // Typical magnitude of the variable: scales the finite-difference step and
  // the comparison (see jacobian_tolerance).
  double scale() const { return std::max(std::abs(lo), std::abs(hi)); }
};

// Where to test a model: physically sensible ranges for x, theta and u, and
// an optional filter that rejects points where f is not differentiable.
struct JacobianCase {
  std::string model;
  std::vector<Range> x, theta, u;
  std::function<bool(const std::vector<double>& x)> differentiable_at = [](const std::vector<double>&) { return true; };
};

std::ostream& operator<<(std::ostream& os, const JacobianCase& c) { return os << c.model; }

std::vector<JacobianCase> jacobian_cases() {
  return {
      {.model = "two_tank",
       .x = {{0.05, 1.0}, {0.05, 1.0}},  // levels stay positive: sqrt(h)
       .theta = {{5.0, 15.0}, {2.0, 8.0}, {0.03, 0.2}, {0.03, 0.2}},
       .u = {{0.0, 0.15}, {0.0, 0.15}}},
      {.model = "rotating_arm",
       .x = {{-3.0, 3.0}, {-2.0, 2.0}},
       .theta = {{-13.0, 13.0}, {-13.0, 13.0}, {-13.0, 13.0}, {-2.0, 2.0}, {-2.0, 2.0}, {-2.0, 2.0},
                 {-0.1, 0.1}, {20.0, 50.0}},
       .u = {{-1.0, 1.0}}},
      {.model = "rotary_pendulum",
       .x = {{-3.0, 3.0}, {-3.0, 3.0}, {-10.0, 10.0}, {-10.0, 10.0}},  // includes the upright pendulum
       .theta = {{0.02, 0.1}, {0.1, 0.3}, {0.1, 0.3}},
       .u = {{-5.0, 5.0}}},
      {.model = "flexible_manipulator",
       .x = {{-1.0, 1.0}, {-1.0, 1.0}, {-0.3, 0.3}, {-0.3, 0.3}},  // |v| both below and above vg = 0.05
       .theta = {{0.001, 0.01}, {0.001, 0.01}, {3.0, 9.0}, {0.005, 0.02}, {0.002, 0.008}, {0.001, 0.005}},
       .u = {{-0.2, 0.2}},
       // sat(v / vg) has kinks at |v| = vg; keep central differences off them.
       .differentiable_at = [](const std::vector<double>& x) {
         constexpr double kVg = 0.05;
         return std::abs(std::abs(x[2]) / kVg - 1.0) > 1e-3 && std::abs(std::abs(x[3]) / kVg - 1.0) > 1e-3;
       }},
  };
}

std::vector<double> draw(const std::vector<Range>& ranges, std::mt19937& rng) {
  std::vector<double> v;
  for (const Range& r : ranges) v.push_back(std::uniform_real_distribution<double>(r.lo, r.hi)(rng));
  return v;
}

// Central differences of f (is_f) or g in the test itself, through
// Model::f / Model::g, so that the Model's own fallback is not what is tested.
// Step h_j = cbrt(eps) * scale_j: balances truncation O(h^2) against
// rounding O(eps / h), relative to the variable's typical size.
std::vector<double> central_differences(const Model& m, bool is_f, double t, const std::vector<double>& u,
                                        std::vector<double> x, std::vector<double> theta,
                                        const std::vector<double>& step_scale) {
  const int rows = is_f ? m.nx() : m.ny();
  std::vector<double> jac(static_cast<std::size_t>(rows * m.nz())), plus(rows), minus(rows);
  auto eval = [&](std::vector<double>& out) {
    const Status s = is_f ? m.f(t, u.data(), 1, 1, x.data(), theta.data(), out.data())
                          : m.g(t, u.data(), 1, 1, x.data(), theta.data(), out.data());
    ASSERT_TRUE(s.is_ok()) << s.to_string();
  };
  const double cbrt_eps = std::cbrt(std::numeric_limits<double>::epsilon());
  for (int j = 0; j < m.nz(); ++j) {
    double& zj = j < m.nx() ? x[j] : theta[j - m.nx()];
    const double z0 = zj;
    const double h = cbrt_eps * step_scale[j];
    zj = z0 + h;
    eval(plus);
    zj = z0 - h;
    eval(minus);
    zj = z0;
    for (int i = 0; i < rows; ++i) jac[i + j * rows] = (plus[i] - minus[i]) / (2.0 * h);
  }
  return jac;
}

// Tolerance for entry (i, j). With the step above, central differences are
// accurate to about eps^(2/3) ~ 4e-11 relative to how much row i changes when
// z_j moves by its scale; 1e-6 leaves four orders of magnitude for curvature
// (tanh, sat, 1/J) and still catches any wrong derivative, which is off by
// O(1). row_scale_i = max(|f_i|, max_k |J_ik| scale_k) is that change.
// Observed: every error is below 1% of this tolerance.
constexpr double kJacobianRtol = 1e-6;

void expect_jacobian_matches(const Model& m, bool is_f, double t, const std::vector<double>& u,
                             const std::vector<double>& x, const std::vector<double>& theta,
                             const std::vector<double>& step_scale, const std::string& where) {
  const int rows = is_f ? m.nx() : m.ny();
  const char* which = is_f ? "f" : "g";
  std::vector<double> value(rows), jac(static_cast<std::size_t>(rows * m.nz()), std::nan("")), direct(rows);
  const Status sj = is_f ? m.f_jacobian(t, u.data(), x.data(), theta.data(), value.data(), jac.data())
                         : m.g_jacobian(t, u.data(), x.data(), theta.data(), value.data(), jac.data());
  ASSERT_TRUE(sj.is_ok()) << where << ": " << sj.to_string();
  const Status sv = is_f ? m.f(t, u.data(), 1, 1, x.data(), theta.data(), direct.data())
                         : m.g(t, u.data(), 1, 1, x.data(), theta.data(), direct.data());
  ASSERT_TRUE(sv.is_ok()) << where << ": " << sv.to_string();
  const std::vector<double> fd = central_differences(m, is_f, t, u, x, theta, step_scale);

  for (int i = 0; i < rows; ++i) {
    double row_scale = std::abs(direct[i]);
    for (int k = 0; k < m.nz(); ++k) row_scale = std::max(row_scale, std::abs(jac[i + k * rows]) * step_scale[k]);
    // The dual-number value is the same arithmetic up to rounding (a / b is
    // computed as a * (1 / b)), so equal to a few ulps of the row's scale.
    EXPECT_NEAR(value[i], direct[i], 1e-13 * std::max(row_scale, 1e-300))
        << where << ": value output of " << which << "_jacobian, row " << i;
    for (int j = 0; j < m.nz(); ++j) {
      const double ad = jac[i + j * rows];
      const double tol = kJacobianRtol * (std::abs(ad) + row_scale / step_scale[j]);
      EXPECT_NEAR(ad, fd[i + j * rows], tol) << where << ": d" << which << "_" << i << "/dz_" << j;
    }
  }
}

class ModelJacobianTest : public testing::TestWithParam<JacobianCase> {};

TEST_P(ModelJacobianTest, ExactJacobiansMatchCentralDifferences) {
  const JacobianCase& c = GetParam();
  const ModelPtr m = builtin(c.model);
  ASSERT_NE(m, nullptr);
  ASSERT_EQ(static_cast<int>(c.x.size()), m->nx());
  ASSERT_EQ(static_cast<int>(c.theta.size()), m->ntheta());
  ASSERT_EQ(static_cast<int>(c.u.size()), m->nu());
  EXPECT_TRUE(m->has_f_jacobian());
  EXPECT_TRUE(m->has_g_jacobian());

  std::vector<double> step_scale;
  for (const Range& r : c.x) step_scale.push_back(r.scale());
  for (const Range& r : c.theta) step_scale.push_back(r.scale());

  std::mt19937 rng(20240611);
  constexpr int kPoints = 25;
  for (int p = 0; p < kPoints; ++p) {
    std::vector<double> x;
    do {
      x = draw(c.x, rng);
    } while (!c.differentiable_at(x));
    const std::vector<double> theta = draw(c.theta, rng);
    const std::vector<double> u = draw(c.u, rng);
    const double t = 0.1 * p;
    const std::string where = c.model + " point " + std::to_string(p);
    expect_jacobian_matches(*m, true, t, u, x, theta, step_scale, where);
    expect_jacobian_matches(*m, false, t, u, x, theta, step_scale, where);
  }
}

// The second derivatives (second-order dual numbers in the SDK) against
// central differences of the exact Jacobian, at the same random points; the
// value and the Jacobian that come with them equal f_jacobian's to the bit
// or to rounding. A wrong entry is off by O(1) of its row's scale.
TEST_P(ModelJacobianTest, ExactSecondDerivativesMatchDifferencesOfTheJacobian) {
  const JacobianCase& c = GetParam();
  const ModelPtr m = builtin(c.model);
  ASSERT_NE(m, nullptr);
  ASSERT_TRUE(m->has_second_derivatives());
  const int nz = m->nz();
  std::vector<double> step_scale;
  for (const Range& r : c.x) step_scale.push_back(r.scale());
  for (const Range& r : c.theta) step_scale.push_back(r.scale());
  std::mt19937 rng(20261128);
  for (int p = 0; p < 10; ++p) {
    std::vector<double> x;
    do {
      x = draw(c.x, rng);
    } while (!c.differentiable_at(x));
    std::vector<double> theta = draw(c.theta, rng);
    const std::vector<double> u = draw(c.u, rng);
    const double t = 0.1 * p;
    for (const bool is_f : {true, false}) {
      const int rows = is_f ? m->nx() : m->ny();
      std::vector<double> value(rows), jac(static_cast<std::size_t>(rows * nz)), hess(static_cast<std::size_t>(rows * nz * nz));
      std::vector<double> value1(rows), jac1(static_cast<std::size_t>(rows * nz));
      const Status sh = is_f ? m->f_hessian(t, u.data(), x.data(), theta.data(), value.data(), jac.data(), hess.data())
                             : m->g_hessian(t, u.data(), x.data(), theta.data(), value.data(), jac.data(), hess.data());
      ASSERT_TRUE(sh.is_ok()) << sh.to_string();
      const Status sj = is_f ? m->f_jacobian(t, u.data(), x.data(), theta.data(), value1.data(), jac1.data())
                             : m->g_jacobian(t, u.data(), x.data(), theta.data(), value1.data(), jac1.data());
      ASSERT_TRUE(sj.is_ok()) << sj.to_string();
      for (int i = 0; i < rows; ++i) EXPECT_EQ(value[static_cast<std::size_t>(i)], value1[static_cast<std::size_t>(i)]);
      // (Dual2 divides through a reciprocal, Dual directly: rounding apart.)
      for (std::size_t k = 0; k < jac.size(); ++k) EXPECT_NEAR(jac[k], jac1[k], 1e-12 * (1.0 + std::abs(jac1[k])));
      // d(J)/dz_b by central differences of the exact Jacobian.
      const double cbrt_eps = std::cbrt(std::numeric_limits<double>::epsilon());
      std::vector<double> plus(static_cast<std::size_t>(rows * nz)), minus(plus.size()), scratch(rows);
      for (int b = 0; b < nz; ++b) {
        double& zb = b < m->nx() ? x[static_cast<std::size_t>(b)] : theta[static_cast<std::size_t>(b - m->nx())];
        const double z0 = zb, h = cbrt_eps * step_scale[static_cast<std::size_t>(b)];
        const auto jacobian_at = [&](double z, std::vector<double>& out) {
          zb = z;
          const Status s = is_f ? m->f_jacobian(t, u.data(), x.data(), theta.data(), scratch.data(), out.data())
                                : m->g_jacobian(t, u.data(), x.data(), theta.data(), scratch.data(), out.data());
          ASSERT_TRUE(s.is_ok()) << s.to_string();
        };
        jacobian_at(z0 + h, plus);
        jacobian_at(z0 - h, minus);
        zb = z0;
        for (int i = 0; i < rows; ++i) {
          // The scale of row i's second derivatives along z_b: its largest,
          // or its Jacobian's over the step's scale.
          double scale = 0.0;
          for (int a = 0; a < nz; ++a) {
            scale = std::max(scale, std::abs(hess[static_cast<std::size_t>(i + rows * (a + nz * b))]) * step_scale[static_cast<std::size_t>(a)]);
            scale = std::max(scale, std::abs(jac1[static_cast<std::size_t>(i + rows * a)]));
          }
          for (int a = 0; a < nz; ++a) {
            const double exact = hess[static_cast<std::size_t>(i + rows * (a + nz * b))];
            const double symmetric = hess[static_cast<std::size_t>(i + rows * (b + nz * a))];
            EXPECT_EQ(exact, symmetric) << c.model << ": second derivative not symmetric";
            const std::size_t k = static_cast<std::size_t>(i + rows * a);
            const double difference = (plus[k] - minus[k]) / (2.0 * h);
            EXPECT_NEAR(exact * step_scale[static_cast<std::size_t>(a)] * step_scale[static_cast<std::size_t>(b)],
                        difference * step_scale[static_cast<std::size_t>(a)] * step_scale[static_cast<std::size_t>(b)],
                        1e-6 * scale * step_scale[static_cast<std::size_t>(b)] + 1e-300)
                << c.model << (is_f ? " f" : " g") << " row " << i << ", d2/dz" << a << " dz" << b << " at point " << p;
          }
        }
      }
    }
  }
}

// f and g at n points stored with leading dimension ld, and at each point
// alone (n = 1, the one-point path of the SDK).
struct BatchAndSingles {
  std::vector<double> batch;                 // rows x ld
  std::vector<std::vector<double>> singles;  // one per point
};

BatchAndSingles evaluate_batch_and_singles(const Model& m, bool is_f, const std::vector<double>& u,
                                           const std::vector<std::vector<double>>& xs,
                                           const std::vector<std::vector<double>>& thetas, std::size_t ld) {
  constexpr double kUntouched = -12345.0;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const int n = static_cast<int>(xs.size());
  const int rows = is_f ? m.nx() : m.ny();
  // Padding is NaN: a plugin reading it would produce NaN in a real column.
  std::vector<double> x(m.nx() * ld, nan), theta(m.ntheta() * ld, nan);
  for (int p = 0; p < n; ++p) {
    for (int i = 0; i < m.nx(); ++i) x[i * ld + p] = xs[p][i];
    for (int j = 0; j < m.ntheta(); ++j) theta[j * ld + p] = thetas[p][j];
  }
  BatchAndSingles r;
  r.batch.assign(rows * ld, kUntouched);
  const Status s = is_f ? m.f(0.5, u.data(), n, ld, x.data(), theta.data(), r.batch.data())
                        : m.g(0.5, u.data(), n, ld, x.data(), theta.data(), r.batch.data());
  EXPECT_TRUE(s.is_ok()) << s.to_string();
  for (int p = 0; p < n; ++p) {
    std::vector<double> single(rows);
    const Status s1 = is_f ? m.f(0.5, u.data(), 1, 1, xs[p].data(), thetas[p].data(), single.data())
                           : m.g(0.5, u.data(), 1, 1, xs[p].data(), thetas[p].data(), single.data());
    EXPECT_TRUE(s1.is_ok()) << s1.to_string();
    r.singles.push_back(single);
  }
  for (int i = 0; i < rows; ++i) {
    for (std::size_t p = n; p < ld; ++p) EXPECT_EQ(r.batch[i * ld + p], kUntouched) << "padding written";
  }
  return r;
}

// The same value to the last bit (not merely within a few ulps).
void expect_same_bits(const BatchAndSingles& r, int rows, std::size_t ld, const std::string& what) {
  for (std::size_t p = 0; p < r.singles.size(); ++p) {
    for (int i = 0; i < rows; ++i) {
      const double batched = r.batch[i * ld + p], single = r.singles[p][i];
      EXPECT_EQ(std::bit_cast<std::uint64_t>(batched), std::bit_cast<std::uint64_t>(single))
          << what << " row " << i << " point " << p << ": batched " << batched << ", alone " << single;
    }
  }
}

// A batch of n points with ld > n gives, to the bit, what n single calls
// give, and leaves the padding between ld and n alone. 13 points: the SDK
// evaluates them in groups of lanes (lanes.hpp, vectorised), the last group
// overlapping the one before.
TEST_P(ModelJacobianTest, BatchedEvaluationMatchesSinglePointsBitForBit) {
  const JacobianCase& c = GetParam();
  const ModelPtr m = builtin(c.model);
  ASSERT_NE(m, nullptr);
  constexpr int kN = 13;
  constexpr std::size_t kLd = 16;
  std::mt19937 rng(7);
  const std::vector<double> u = draw(c.u, rng);
  std::vector<std::vector<double>> xs, thetas;
  for (int p = 0; p < kN; ++p) {
    xs.push_back(draw(c.x, rng));
    thetas.push_back(draw(c.theta, rng));
  }
  for (const bool is_f : {true, false}) {
    const BatchAndSingles r = evaluate_batch_and_singles(*m, is_f, u, xs, thetas, kLd);
    expect_same_bits(r, is_f ? m->nx() : m->ny(), kLd, std::string(is_f ? "f" : "g"));
  }
}

// Points of one group of lanes on both sides of a branch (a tank empty in
// some, filled in others: sqrt(h) for h > 0, else 0) are evaluated one at a
// time, and give what each gives alone; so do points on the same side.
TEST(ModelLanes, PointsOnBothSidesOfABranchGiveWhatEachGivesAlone) {
  const ModelPtr m = builtin("two_tank");
  ASSERT_NE(m, nullptr);
  const std::vector<double> u = {0.1, 0.05}, theta = {10.0, 5.0, 0.08, 0.13};
  // Pairs and quadruples (whatever the SDK's lane count) with mixed signs, all
  // empty, all filled.
  const std::vector<double> h1 = {0.3, -0.01, 0.2, 0.0, -0.1, -0.2, 0.0, -0.3,
                                  0.1, 0.2, 0.3, 0.4, 1e-300, -1e-300, 0.5, 0.6};
  std::vector<std::vector<double>> xs, thetas;
  for (std::size_t p = 0; p < h1.size(); ++p) {
    xs.push_back({h1[p], 0.25 - h1[p]});
    thetas.push_back(theta);
  }
  const BatchAndSingles r = evaluate_batch_and_singles(*m, true, u, xs, thetas, h1.size());
  expect_same_bits(r, m->nx(), h1.size(), "two_tank f");
  // An empty tank has no outflow (the branch was taken per point).
  EXPECT_EQ(r.batch[1], u[0] / theta[0]);
}

INSTANTIATE_TEST_SUITE_P(Builtins, ModelJacobianTest, testing::ValuesIn(jacobian_cases()),
                         [](const testing::TestParamInfo<JacobianCase>& param_info) { return param_info.param.model; });

// ---------------------------------------------------------------------------
// Dataset reproduction

// A CSV file with a header row, as columns by name.
std::map<std::string, std::vector<double>> read_csv_columns(const std::string& path) {
  std::map<std::string, std::vector<double>> columns;
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << "cannot open " << path;
  std::string line, cell;
  std::vector<std::string> names;
  std::getline(in, line);
  for (std::istringstream header(line); std::getline(header, cell, ',');) names.push_back(cell);
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::istringstream row(line);
    for (const std::string& name : names) {
      std::getline(row, cell, ',');
      columns[name].push_back(std::stod(cell));
    }
  }
  return columns;
}

// The outputs at every sample time of the dataset, simulated from x0 by
// classic RK4 with `substeps` steps per sample interval and the inputs held at
// their value at the start of the interval (zero-order hold), as the data
// were generated.
std::vector<std::vector<double>> simulate_outputs(const Model& m, const std::map<std::string, std::vector<double>>& data,
                                                  std::vector<double> x, const std::vector<double>& theta,
                                                  int substeps) {
  const std::vector<double>& t = data.at("t");
  const std::size_t samples = t.size();
  const int nx = m.nx();
  std::vector<double> u(m.nu()), y(m.ny()), k1(nx), k2(nx), k3(nx), k4(nx), xs(nx);
  std::vector<std::vector<double>> outputs;

  auto inputs_at = [&](std::size_t k) {
    for (int i = 0; i < m.nu(); ++i) u[i] = data.at(m.input_names()[i])[k];
  };
  auto rhs = [&](double tt, const std::vector<double>& xx, std::vector<double>& dx) {
    const Status s = m.f(tt, u.data(), 1, 1, xx.data(), theta.data(), dx.data());
    EXPECT_TRUE(s.is_ok()) << s.to_string();
  };
  auto stage = [&](const std::vector<double>& k, double a) {
    for (int i = 0; i < nx; ++i) xs[i] = x[i] + a * k[i];
    return xs;
  };

  for (std::size_t k = 0; k < samples; ++k) {
    inputs_at(k);
    const Status s = m.g(t[k], u.data(), 1, 1, x.data(), theta.data(), y.data());
    EXPECT_TRUE(s.is_ok()) << s.to_string();
    outputs.push_back(y);
    if (k + 1 == samples) break;
    const double h = (t[k + 1] - t[k]) / substeps;
    for (int step = 0; step < substeps; ++step) {
      const double ts = t[k] + step * h;
      rhs(ts, x, k1);
      rhs(ts + 0.5 * h, stage(k1, 0.5 * h), k2);
      rhs(ts + 0.5 * h, stage(k2, 0.5 * h), k3);
      rhs(ts + h, stage(k3, h), k4);
      for (int i = 0; i < nx; ++i) x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
  }
  return outputs;
}

// Largest |simulated - recorded| over all samples, per output.
std::vector<double> max_output_errors(const Model& m, const std::map<std::string, std::vector<double>>& data,
                                      const std::vector<std::vector<double>>& simulated) {
  std::vector<double> worst(m.ny(), 0.0);
  for (int i = 0; i < m.ny(); ++i) {
    const std::vector<double>& recorded = data.at(m.output_names()[i]);
    EXPECT_EQ(recorded.size(), simulated.size());
    for (std::size_t k = 0; k < std::min(recorded.size(), simulated.size()); ++k) {
      worst[i] = std::max(worst[i], std::abs(simulated[k][i] - recorded[k]));
    }
  }
  return worst;
}

struct ReproductionCase {
  std::string model;
  std::string csv;
  std::vector<double> theta_true;  // from the dataset's json
  std::vector<double> x0_true;     // from the dataset's json
  int substeps;
  double tolerance;                // on every output, in the output's unit
};

// The true values are the plugins' defaults for these models; the dataset
// must be reproduced with them.
void expect_reproduces(const ReproductionCase& c) {
  const ModelPtr m = builtin(c.model);
  ASSERT_NE(m, nullptr);
  ASSERT_EQ(static_cast<int>(c.theta_true.size()), m->ntheta());
  for (int j = 0; j < m->ntheta(); ++j) {
    EXPECT_DOUBLE_EQ(m->theta_default()[j], c.theta_true[j]) << "default of " << m->param_names()[j];
  }
  const auto data = read_csv_columns(std::string(RICCATI_TEST_DATA_DIR) + "/" + c.csv);
  ASSERT_FALSE(data.empty());
  const auto simulated = simulate_outputs(*m, data, c.x0_true, c.theta_true, c.substeps);
  const std::vector<double> worst = max_output_errors(*m, data, simulated);
  for (int i = 0; i < m->ny(); ++i) {
    EXPECT_LE(worst[i], c.tolerance) << c.model << " output " << m->output_names()[i];
  }
}

// The noise-free datasets were integrated by scipy at tight tolerance; RK4
// with these substeps is far more accurate than the tolerances below.
// rotating_arm is not here: its data come from a true system (Stribeck
// friction) that the model only approximates.
TEST(DatasetReproductionTest, TwoTank) {
  expect_reproduces({.model = "two_tank",
                     .csv = "two_tank.csv",
                     .theta_true = {10.0, 5.0, 0.0791, 0.1342},
                     .x0_true = {0.4, 0.15},
                     .substeps = 20,
                     .tolerance = 1e-9});
}

TEST(DatasetReproductionTest, RotaryPendulum) {
  expect_reproduces({.model = "rotary_pendulum",
                     .csv = "rotary_pendulum.csv",
                     .theta_true = {0.05, 0.175, 0.198},
                     .x0_true = {0.0, 0.0, 0.0, 0.0},
                     .substeps = 50,
                     .tolerance = 1e-9});
}

// Outputs are encoder angles rounded to the nearest 0.01 degree: allow half a
// quantisation step plus a margin for integration error. The rig starts at
// rest (the json gives no initial state; the first samples read zero).
TEST(DatasetReproductionTest, FlexibleManipulator) {
  constexpr double kQuantum = 0.01 * std::numbers::pi / 180.0;
  expect_reproduces({.model = "flexible_manipulator",
                     .csv = "flexible_manipulator.csv",
                     .theta_true = {0.004, 0.003, 5.8, 0.012, 0.0045, 0.0028},
                     .x0_true = {0.0, 0.0, 0.0, 0.0},
                     .substeps = 20,
                     .tolerance = 0.5 * kQuantum + 1e-6});
}

}  // namespace
}  // namespace riccati
