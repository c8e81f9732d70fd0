// Text models (server/engine/models/text): each shipped model written as text
// (models/text/*.yaml) against its C++ plugin, f, g and the Jacobians at
// random points; their Jacobians against finite differences; an
// identification with the text model against the plugin's; and the bad
// inputs, each refused with its own message and place.
#include <gtest/gtest.h>

#include <bit>
#include <cstdint>

#include <cmath>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "engine/estimation/identification.hpp"
#include "engine/models/jacobian_check.hpp"
#include "engine/models/plugin_loader.hpp"
#include "engine/models/text/text_model.hpp"

namespace riccati {
namespace {

const ModelRegistry& builtins() {
  static const ModelRegistry registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value();
  return registry;
}

std::string read_file(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

Result<TextModel> shipped_text_model(const std::string& plugin_name) {
  const std::string path = std::string(RICCATI_TEST_TEXT_MODEL_DIR) + "/" + plugin_name + ".yaml";
  return compile_text_model(read_file(path), path);
}

struct Range {
  double lo, hi;
};

// Where to compare a model with its plugin: ranges for x, theta and u.
struct Case {
  std::string plugin;
  std::vector<Range> x, theta, u;
};

std::ostream& operator<<(std::ostream& os, const Case& c) { return os << c.plugin; }

const std::vector<Case>& cases() {
  static const std::vector<Case> all = {
      // Levels on both sides of 0: the text's if(h > 0, sqrt(h), 0) must
      // follow the plugin's branch, value and derivative.
      {"two_tank", {{-0.2, 3}, {-0.2, 3}}, {{1, 30}, {1, 30}, {0.01, 2}, {0.01, 2}}, {{0, 0.5}, {0, 0.5}}},
      {"rotary_pendulum",
       {{-3, 3}, {-3.2, 3.2}, {-10, 10}, {-10, 10}},
       {{0.02, 0.1}, {0.1, 0.3}, {0.1, 0.3}},
       {{-5, 5}}},
      {"rotating_arm",
       {{-3, 3}, {-20, 20}},
       {{-1, 1}, {-20, 20}, {-1, 1}, {-3, 3}, {-3, 3}, {-1, 1}, {-1, 1}, {1, 60}},
       {{-2, 2}}},
      // Velocities inside and outside the friction's linear zone |v| < 0.05.
      {"flexible_manipulator",
       {{-1, 1}, {-1, 1}, {-0.2, 0.2}, {-0.2, 0.2}},
       {{0, 0.01}, {0, 0.01}, {1, 10}, {0, 0.05}, {0.001, 0.01}, {0.001, 0.01}},
       {{-0.5, 0.5}}},
  };
  return all;
}

Eigen::VectorXd draw(const std::vector<Range>& ranges, std::mt19937_64& rng) {
  Eigen::VectorXd v(static_cast<Eigen::Index>(ranges.size()));
  for (std::size_t i = 0; i < ranges.size(); ++i) {
    v[static_cast<Eigen::Index>(i)] = std::uniform_real_distribution<double>(ranges[i].lo, ranges[i].hi)(rng);
  }
  return v;
}

// |a - b| within 1e-12 of the larger magnitude: agreement to rounding. A
// Jacobian's entry is compared at the scale of its row (`floor`): an entry
// that is a difference of large terms (d/dl of the pendulum's Cramer's rule)
// carries their rounding, which the plugin's dual numbers and the text's
// symbolic derivative commit in a different order.
::testing::AssertionResult close(double text, double plugin, const std::string& what, double floor = 0.0) {
  const double scale = std::max({std::abs(text), std::abs(plugin), floor, 1e-300});
  if (std::abs(text - plugin) <= 1e-12 * scale) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << what << ": text " << text << ", plugin " << plugin << " (relative "
                                       << std::abs(text - plugin) / scale << ")";
}

class ShippedTextModel : public ::testing::TestWithParam<Case> {};

TEST_P(ShippedTextModel, DescribesTheSameModelAsThePlugin) {
  const ModelPtr plugin = builtins().get(GetParam().plugin).value();
  auto text = shipped_text_model(GetParam().plugin);
  ASSERT_TRUE(text.is_ok()) << text.status().to_string();
  const Model& m = *text->model;
  EXPECT_EQ(m.name(), plugin->name() + "_text");
  EXPECT_EQ(m.state_names(), plugin->state_names());
  EXPECT_EQ(m.param_names(), plugin->param_names());
  EXPECT_EQ(m.input_names(), plugin->input_names());
  EXPECT_EQ(m.output_names(), plugin->output_names());
  EXPECT_EQ(m.theta_default(), plugin->theta_default());
  EXPECT_EQ(m.theta_lower(), plugin->theta_lower());
  EXPECT_EQ(m.theta_upper(), plugin->theta_upper());
  EXPECT_TRUE(m.has_f_jacobian());
  EXPECT_TRUE(m.has_g_jacobian());
}

TEST_P(ShippedTextModel, FGAndTheirDerivativesEqualThePluginsAtAThousandRandomPoints) {
  const Case& c = GetParam();
  const ModelPtr plugin = builtins().get(c.plugin).value();
  auto text = shipped_text_model(c.plugin);
  ASSERT_TRUE(text.is_ok()) << text.status().to_string();
  const Model& m = *text->model;
  const int nx = m.nx(), ny = m.ny(), nz = m.nz();
  constexpr int kPoints = 1000;
  std::mt19937_64 rng(17);
  // All points in one batched call for f and g (variable-major, ld = kPoints).
  Eigen::MatrixXd X(nx, kPoints), Theta(m.ntheta(), kPoints);
  std::vector<Eigen::VectorXd> us;
  for (int p = 0; p < kPoints; ++p) {
    X.col(p) = draw(c.x, rng);
    Theta.col(p) = draw(c.theta, rng);
  }
  // Batches share u and t: one u for the batch, and u per point below.
  const Eigen::VectorXd u = draw(c.u, rng);
  const double t = 1.25;
  Eigen::MatrixXd XT = X.transpose(), ThetaT = Theta.transpose();  // column-major: value i of point p at i*ld + p
  Eigen::MatrixXd f_text(kPoints, nx), f_plugin(kPoints, nx), g_text(kPoints, ny), g_plugin(kPoints, ny);
  ASSERT_TRUE(m.f(t, u.data(), kPoints, kPoints, XT.data(), ThetaT.data(), f_text.data()).is_ok());
  ASSERT_TRUE(plugin->f(t, u.data(), kPoints, kPoints, XT.data(), ThetaT.data(), f_plugin.data()).is_ok());
  ASSERT_TRUE(m.g(t, u.data(), kPoints, kPoints, XT.data(), ThetaT.data(), g_text.data()).is_ok());
  ASSERT_TRUE(plugin->g(t, u.data(), kPoints, kPoints, XT.data(), ThetaT.data(), g_plugin.data()).is_ok());
  int failures = 0;
  for (int p = 0; p < kPoints && failures < 10; ++p) {
    for (int i = 0; i < nx; ++i) failures += !close(f_text(p, i), f_plugin(p, i), "f") ? 1 : 0;
    for (int i = 0; i < ny; ++i) failures += !close(g_text(p, i), g_plugin(p, i), "g") ? 1 : 0;
  }
  double worst_entry = 0.0;  // entry by entry, for the record
  for (int p = 0; p < kPoints && failures < 10; ++p) {
    const Eigen::VectorXd x = X.col(p), theta = Theta.col(p), up = draw(c.u, rng);
    Eigen::VectorXd ft(nx), fp(nx), gt(ny), gp(ny);
    Eigen::MatrixXd jft(nx, nz), jfp(nx, nz), jgt(ny, nz), jgp(ny, nz);
    ASSERT_TRUE(m.f_jacobian(t, up.data(), x.data(), theta.data(), ft.data(), jft.data()).is_ok());
    ASSERT_TRUE(plugin->f_jacobian(t, up.data(), x.data(), theta.data(), fp.data(), jfp.data()).is_ok());
    ASSERT_TRUE(m.g_jacobian(t, up.data(), x.data(), theta.data(), gt.data(), jgt.data()).is_ok());
    ASSERT_TRUE(plugin->g_jacobian(t, up.data(), x.data(), theta.data(), gp.data(), jgp.data()).is_ok());
    for (int i = 0; i < nx; ++i) {
      const auto at = [&](const std::string& what) {
        std::ostringstream s;
        s << what << " row " << m.state_names()[static_cast<std::size_t>(i)] << " at x = " << x.transpose()
          << ", theta = " << theta.transpose() << ", u = " << up.transpose();
        return s.str();
      };
      EXPECT_TRUE(close(ft[i], fp[i], at("f"))) << ++failures;
      const double row = jfp.row(i).cwiseAbs().maxCoeff();
      for (int j = 0; j < nz; ++j) {
        EXPECT_TRUE(close(jft(i, j), jfp(i, j), at("df/dz" + std::to_string(j)), row)) << ++failures;
        worst_entry = std::max(worst_entry, std::abs(jft(i, j) - jfp(i, j)) / std::max(std::abs(jfp(i, j)), 1e-300));
      }
    }
    for (int i = 0; i < ny; ++i) {
      EXPECT_TRUE(close(gt[i], gp[i], "g")) << ++failures;
      const double row = jgp.row(i).cwiseAbs().maxCoeff();
      for (int j = 0; j < nz; ++j) EXPECT_TRUE(close(jgt(i, j), jgp(i, j), "dg/dz", row)) << ++failures;
    }
  }
  // The mechanical form, where the plugin has one: c = [h; g], Fc = [-H M; R G] and their Jacobians.
  ASSERT_EQ(m.ndof(), plugin->ndof());
  ASSERT_EQ(m.has_mechanical_form(), plugin->has_mechanical_form());
  if (plugin->has_mechanical_form()) {
    const int rows = m.ndof() + ny, cols = m.nu() + m.ndof();
    for (int p = 0; p < 200 && failures < 10; ++p) {
      const Eigen::VectorXd x = X.col(p), theta = Theta.col(p);
      Eigen::VectorXd ct(rows), cp(rows), Ft(rows * cols), Fp(rows * cols);
      Eigen::MatrixXd jct(rows, nz), jcp(rows, nz), jFt(rows * cols, nz), jFp(rows * cols, nz);
      ASSERT_TRUE(m.mechanical(t, x.data(), theta.data(), ct.data(), Ft.data(), jct.data(), jFt.data()).is_ok());
      ASSERT_TRUE(plugin->mechanical(t, x.data(), theta.data(), cp.data(), Fp.data(), jcp.data(), jFp.data()).is_ok());
      for (int i = 0; i < rows; ++i) EXPECT_TRUE(close(ct[i], cp[i], "c")) << ++failures;
      for (int i = 0; i < rows * cols; ++i) EXPECT_TRUE(close(Ft[i], Fp[i], "Fc")) << ++failures;
      for (int i = 0; i < rows; ++i) {
        for (int j = 0; j < nz; ++j) EXPECT_TRUE(close(jct(i, j), jcp(i, j), "dc/dz", jcp.row(i).cwiseAbs().maxCoeff())) << ++failures;
      }
      for (int i = 0; i < rows * cols; ++i) {
        for (int j = 0; j < nz; ++j) EXPECT_TRUE(close(jFt(i, j), jFp(i, j), "dFc/dz", jFp.row(i).cwiseAbs().maxCoeff())) << ++failures;
      }
    }
  }
  // The second derivatives (symbolic, the Jacobian differentiated again),
  // for a model written with der:; the mechanical form's text model has none.
  EXPECT_EQ(m.has_second_derivatives(), !plugin->has_mechanical_form()) << c.plugin;
  if (m.has_second_derivatives()) {
    for (int p = 0; p < 200 && failures < 10; ++p) {
      const Eigen::VectorXd x = X.col(p), theta = Theta.col(p);
      for (const bool is_f : {true, false}) {
        const int rows = is_f ? nx : ny;
        Eigen::VectorXd vt(rows), vp(rows);
        Eigen::MatrixXd jt(rows, nz), jp(rows, nz), ht(rows * nz, nz), hp(rows * nz, nz);
        ASSERT_TRUE((is_f ? m.f_hessian(t, u.data(), x.data(), theta.data(), vt.data(), jt.data(), ht.data())
                          : m.g_hessian(t, u.data(), x.data(), theta.data(), vt.data(), jt.data(), ht.data()))
                        .is_ok());
        ASSERT_TRUE((is_f ? plugin->f_hessian(t, u.data(), x.data(), theta.data(), vp.data(), jp.data(), hp.data())
                          : plugin->g_hessian(t, u.data(), x.data(), theta.data(), vp.data(), jp.data(), hp.data()))
                        .is_ok());
        for (Eigen::Index r = 0; r < hp.rows(); ++r) {
          const double row = std::max(hp.row(r).cwiseAbs().maxCoeff(), jp.cwiseAbs().maxCoeff());
          for (Eigen::Index b = 0; b < nz; ++b) {
            EXPECT_TRUE(close(ht(r, b), hp(r, b), is_f ? "d2f/dz2" : "d2g/dz2", row)) << ++failures;
          }
        }
      }
    }
  }
  RecordProperty("worst_jacobian_entry_relative_difference", std::to_string(worst_entry));
  std::printf("%s: worst Jacobian entry relative difference %.3g\n", c.plugin.c_str(), worst_entry);
}

// A batch (the tapes run 16 points per instruction) gives, to the bit,
// what each point gives alone (the one-point tape): 37 points, so two full
// groups of lanes and a part.
TEST_P(ShippedTextModel, BatchedEvaluationEqualsSinglePointsBitForBit) {
  const Case& c = GetParam();
  auto text = shipped_text_model(c.plugin);
  ASSERT_TRUE(text.is_ok()) << text.status().to_string();
  const Model& m = *text->model;
  const int nx = m.nx(), ny = m.ny();
  constexpr int kPoints = 37;
  std::mt19937_64 rng(29);
  Eigen::MatrixXd XT(kPoints, nx), ThetaT(kPoints, m.ntheta());  // value i of point p at i * kPoints + p
  for (int p = 0; p < kPoints; ++p) {
    XT.row(p) = draw(c.x, rng).transpose();
    ThetaT.row(p) = draw(c.theta, rng).transpose();
  }
  const Eigen::VectorXd u = draw(c.u, rng);
  const double t = 0.75;
  Eigen::MatrixXd f(kPoints, nx), g(kPoints, ny);
  ASSERT_TRUE(m.f(t, u.data(), kPoints, kPoints, XT.data(), ThetaT.data(), f.data()).is_ok());
  ASSERT_TRUE(m.g(t, u.data(), kPoints, kPoints, XT.data(), ThetaT.data(), g.data()).is_ok());
  for (int p = 0; p < kPoints; ++p) {
    const Eigen::VectorXd x = XT.row(p).transpose(), theta = ThetaT.row(p).transpose();
    Eigen::VectorXd f1(nx), g1(ny);
    ASSERT_TRUE(m.f(t, u.data(), 1, 1, x.data(), theta.data(), f1.data()).is_ok());
    ASSERT_TRUE(m.g(t, u.data(), 1, 1, x.data(), theta.data(), g1.data()).is_ok());
    for (int i = 0; i < nx; ++i) {
      EXPECT_EQ(std::bit_cast<std::uint64_t>(f(p, i)), std::bit_cast<std::uint64_t>(f1[i]))
          << "f row " << i << " point " << p << ": batched " << f(p, i) << ", alone " << f1[i];
    }
    for (int i = 0; i < ny; ++i) {
      EXPECT_EQ(std::bit_cast<std::uint64_t>(g(p, i)), std::bit_cast<std::uint64_t>(g1[i]))
          << "g row " << i << " point " << p << ": batched " << g(p, i) << ", alone " << g1[i];
    }
  }
}

TEST_P(ShippedTextModel, JacobiansAgreeWithFiniteDifferences) {
  auto text = shipped_text_model(GetParam().plugin);
  ASSERT_TRUE(text.is_ok()) << text.status().to_string();
  std::mt19937_64 rng(3);
  std::vector<JacobianPoint> points = generic_points(*text->model);
  for (int k = 0; k < 20; ++k) {
    JacobianPoint p;
    p.t = 0.5;
    p.x = draw(GetParam().x, rng);
    p.theta = draw(GetParam().theta, rng);
    p.u = draw(GetParam().u, rng);
    // Away from the kinks (an empty tank, the edge of the friction's zone),
    // where finite differences straddle two branches.
    bool smooth = true;
    for (Eigen::Index i = 0; i < p.x.size(); ++i) smooth = smooth && std::abs(p.x[i]) > 0.01;
    if (GetParam().plugin == "flexible_manipulator") {
      for (const double v : {p.x[2], p.x[3]}) smooth = smooth && std::abs(std::abs(v) - 0.05) > 0.005;
    }
    if (smooth) points.push_back(p);
  }
  auto check = check_jacobians(*text->model, points);
  ASSERT_TRUE(check.is_ok()) << check.status().to_string();
  EXPECT_TRUE(check->checked) << check->detail;
  EXPECT_GT(check->points, 5);
  EXPECT_TRUE(check->agrees()) << (check->disagreements.empty() ? "" : check->disagreements.front());
}

INSTANTIATE_TEST_SUITE_P(Models, ShippedTextModel, ::testing::ValuesIn(cases()),
                         [](const auto& param_info) { return param_info.param.plugin; });

// Hensen's two-tank identification (EKF, 10 passes over the shipped record)
// with the text model and with the plugin: the same numbers.
TEST(TextModel, TwoTankIdentificationEqualsThePlugins) {
  const ModelPtr plugin = builtins().get("two_tank").value();
  auto text = shipped_text_model("two_tank");
  ASSERT_TRUE(text.is_ok()) << text.status().to_string();
  ColumnMapping mapping;
  mapping.inputs = {"F1", "F2"};
  mapping.outputs = {"h1", "h2"};
  const Dataset data = read_csv_file(std::string(RICCATI_TEST_DATA_DIR) + "/two_tank.csv", mapping).value();
  for (const FilterKind kind : {FilterKind::kEkf, FilterKind::kUkf}) {
    IdentificationSettings s;
    s.filter.kind = kind;
    s.filter.integrator.kind = IntegratorKind::kRk4;
    s.filter.integrator.substeps = 10;
    s.filter.Q = Eigen::MatrixXd::Zero(6, 6);
    s.filter.R = Eigen::Vector2d::Constant(1e-3).asDiagonal();
    s.initial.mode = InitialState::kFirstMeasurement;
    s.initial.theta0 = Eigen::Vector4d(20, 20, 1, 1);
    Eigen::VectorXd p0(6);
    p0 << 0, 0, 10, 10, 10, 10;
    s.initial.P0 = p0.asDiagonal();
    s.passes = 3;
    auto a = identify(text->model, data, s);
    auto b = identify(plugin, data, s);
    ASSERT_TRUE(a.is_ok()) << a.status().to_string();
    ASSERT_TRUE(b.is_ok()) << b.status().to_string();
    ASSERT_EQ(a->theta.size(), b->theta.size());
    for (Eigen::Index i = 0; i < a->theta.size(); ++i) {
      EXPECT_NEAR(a->theta[i], b->theta[i], 1e-9 * std::abs(b->theta[i])) << a->param_names[static_cast<std::size_t>(i)];
      EXPECT_NEAR(a->theta_std[i], b->theta_std[i], 1e-9 * std::abs(b->theta_std[i]));
    }
    EXPECT_LE((a->y_model - b->y_model).cwiseAbs().maxCoeff(), 1e-9 * b->y_model.cwiseAbs().maxCoeff());
  }
}

// Second derivatives are compiled for a model of a size that maximum
// likelihood handles, and left out (the model still compiles, with its
// Jacobians) when (nx + ny) nz^2 passes 65,536: a chain of 40 tanks with 10
// parameters has 41 x 50^2 = 102,500. The small one's are exact: for
// h' = F - k h^2, d2f/dh2 = -2k and d2f/dh dk = -2h.
TEST(TextModel, SecondDerivativesAreCompiledUpToTheirBound) {
  auto small = compile_text_model(R"(model: leak
states: {h: {}}
inputs: {F: {}}
parameters: {k: {value: 0.3}}
der: {h: F - k * h^2}
outputs: {h: h}
)", "leak.yaml");
  ASSERT_TRUE(small.is_ok()) << small.status().to_string();
  ASSERT_TRUE(small->model->has_second_derivatives());
  const double u = 1.0, h = 2.0, k = 0.3;
  double f = 0, jac[2] = {0, 0}, hess[4] = {0, 0, 0, 0};
  ASSERT_TRUE(small->model->f_hessian(0.0, &u, &h, &k, &f, jac, hess).is_ok());
  EXPECT_DOUBLE_EQ(hess[0], -2.0 * k);  // d2f/dh2
  EXPECT_DOUBLE_EQ(hess[1], -2.0 * h);  // d2f/dk dh
  EXPECT_DOUBLE_EQ(hess[2], -2.0 * h);  // d2f/dh dk
  EXPECT_DOUBLE_EQ(hess[3], 0.0);       // d2f/dk2

  std::string yaml = "model: chain\nstates: {";
  for (int i = 0; i < 40; ++i) yaml += (i ? ", " : "") + std::string("h") + std::to_string(i) + ": {}";
  yaml += "}\ninputs: {F: {}}\nparameters: {";
  for (int j = 0; j < 10; ++j) yaml += (j ? ", " : "") + std::string("k") + std::to_string(j) + ": {value: 0.1}";
  yaml += "}\nder:\n";
  for (int i = 0; i < 40; ++i) {
    yaml += "  h" + std::to_string(i) + ": " + (i ? "k" + std::to_string((i - 1) % 10) + " * h" + std::to_string(i - 1) : std::string("F")) +
            " - k" + std::to_string(i % 10) + " * h" + std::to_string(i) + "\n";
  }
  yaml += "outputs: {y: h39}\n";
  auto large = compile_text_model(yaml, "chain.yaml");
  ASSERT_TRUE(large.is_ok()) << large.status().to_string();
  EXPECT_FALSE(large->model->has_second_derivatives());
  EXPECT_TRUE(large->model->has_f_jacobian());
}

// The issue's example, with sqrt(max(h, 0)): an empty tank has outflow 0 and
// derivative 0 (the chain rule gives 0 where max(h, 0) does not move).
TEST(TextModel, SqrtOfMaxIsDifferentiableBelowZero) {
  const std::string yaml = R"(model: tank
states: {h: {unit: m}}
inputs: {F: {}}
parameters: {k: {value: 0.1, min: 0}}
define:
  q: k * sqrt(max(h, 0))
der: {h: F - q}
outputs: {h: h}
)";
  auto m = compile_text_model(yaml, "tank.yaml");
  ASSERT_TRUE(m.is_ok()) << m.status().to_string();
  const double u = 0.5, theta = 0.1;
  for (const double h : {-0.5, 2.0}) {
    double f = 0, jac[2] = {0, 0};
    ASSERT_TRUE(m->model->f_jacobian(0.0, &u, &h, &theta, &f, jac).is_ok());
    const double root = h > 0 ? std::sqrt(h) : 0.0;
    EXPECT_DOUBLE_EQ(f, u - theta * root);
    EXPECT_DOUBLE_EQ(jac[0], h > 0 ? -theta * 0.5 / root : 0.0);
    EXPECT_DOUBLE_EQ(jac[1], -root);
  }
}

// Every function and operator against its C++ definition and its derivative
// against central differences, at one point each.
TEST(TextModel, EveryFunctionHasItsValueAndDerivative) {
  struct F {
    const char* expr;
    double (*value)(double a, double b);
  };
  const std::vector<F> functions = {
      {"a + b", [](double a, double b) { return a + b; }},
      {"a - b", [](double a, double b) { return a - b; }},
      {"a * b", [](double a, double b) { return a * b; }},
      {"a / b", [](double a, double b) { return a / b; }},
      {"a ^ b", [](double a, double b) { return std::pow(a, b); }},
      {"a ^ 3", [](double a, double) { return std::pow(a, 3.0); }},
      {"-a ^ 2", [](double a, double) { return -(a * a); }},
      {"2 ^ b", [](double, double b) { return std::pow(2.0, b); }},
      {"sqrt(a)", [](double a, double) { return std::sqrt(a); }},
      {"exp(a)", [](double a, double) { return std::exp(a); }},
      {"log(a)", [](double a, double) { return std::log(a); }},
      {"sin(a)", [](double a, double) { return std::sin(a); }},
      {"cos(a)", [](double a, double) { return std::cos(a); }},
      {"tan(a)", [](double a, double) { return std::tan(a); }},
      {"asin(a - 0.5)", [](double a, double) { return std::asin(a - 0.5); }},
      {"acos(a - 0.5)", [](double a, double) { return std::acos(a - 0.5); }},
      {"atan(a)", [](double a, double) { return std::atan(a); }},
      {"atan2(a, b)", [](double a, double b) { return std::atan2(a, b); }},
      {"sinh(a)", [](double a, double) { return std::sinh(a); }},
      {"cosh(a)", [](double a, double) { return std::cosh(a); }},
      {"tanh(a)", [](double a, double) { return std::tanh(a); }},
      {"abs(a - b)", [](double a, double b) { return std::abs(a - b); }},
      {"sign(a - b) * a", [](double a, double b) { return (a > b ? 1.0 : -1.0) * a; }},
      {"min(a, b)", [](double a, double b) { return std::min(a, b); }},
      {"max(a, b)", [](double a, double b) { return std::max(a, b); }},
      {"pow(a, b)", [](double a, double b) { return std::pow(a, b); }},
      {"hypot(a, b)", [](double a, double b) { return std::hypot(a, b); }},
      {"sat(a - 0.5)", [](double a, double) { return std::clamp(a - 0.5, -1.0, 1.0); }},
      {"if(a < b, a * a, b)", [](double a, double b) { return a < b ? a * a : b; }},
      {"if(a >= b, a, 2 * b)", [](double a, double b) { return a >= b ? a : 2 * b; }},
      {"(a <= b) + (a > b) * 2 + (a == b) * 4 + (a != b) * 8", [](double a, double b) { return a <= b ? 9.0 : 10.0; }},
      {"a * t + pi", [](double a, double) { return a * 2.0 + 3.14159265358979323846; }},
  };
  for (const double a : {0.7, 1.2}) {
    for (const F& fn : functions) {
      const std::string yaml = std::string("model: m\nstates: [a]\nparameters: {b: 1.3}\nder: {a: \"") + fn.expr +
                               "\"}\noutputs: {y: a}\n";
      auto m = compile_text_model(yaml, "m.yaml");
      ASSERT_TRUE(m.is_ok()) << fn.expr << ": " << m.status().to_string();
      const double b = 1.3, t = 2.0;
      double f = 0, jac[2] = {0, 0};
      ASSERT_TRUE(m->model->f_jacobian(t, nullptr, &a, &b, &f, jac).is_ok()) << fn.expr;
      EXPECT_NEAR(f, fn.value(a, b), 1e-14 * std::max(1.0, std::abs(f))) << fn.expr << " at a = " << a;
      const double h = 1e-6;
      const double da = (fn.value(a + h, b) - fn.value(a - h, b)) / (2 * h);
      const double db = (fn.value(a, b + h) - fn.value(a, b - h)) / (2 * h);
      EXPECT_NEAR(jac[0], da, 1e-7 * std::max(1.0, std::abs(da))) << "d(" << fn.expr << ")/da at a = " << a;
      EXPECT_NEAR(jac[1], db, 1e-7 * std::max(1.0, std::abs(db))) << "d(" << fn.expr << ")/db at a = " << a;
    }
  }
}

// Subexpressions written twice, or reached through two helpers, are computed
// once; constants are folded.
TEST(TextModel, CommonSubexpressionsAreSharedAndConstantsFolded) {
  const std::string once = "model: m\nstates: [x]\nparameters: {k: 2}\nder: {x: \"sin(k*x) * sin(k*x) * 3\"}\noutputs: {y: x}\n";
  const std::string twice =
      "model: m\nstates: [x]\nparameters: {k: 2}\ndefine: {a: sin(k*x), b: \"sin(k * x)\", c: 2 * 0.5 + 2}\n"
      "der: {x: a * b * c}\noutputs: {y: x}\n";
  auto m1 = compile_text_model(once, "once.yaml");
  auto m2 = compile_text_model(twice, "twice.yaml");
  ASSERT_TRUE(m1.is_ok() && m2.is_ok());
  // The same tape: a and b are one node, c is the constant 3.
  EXPECT_EQ(m2->summary.tape_length, m1->summary.tape_length);
  EXPECT_EQ(m2->summary.f_sparsity, std::vector<std::string>{"xx"});
}

// The tape folds a negation into the sum, difference or product that reads
// it, and computes a / b as a * (1 / b) where the Jacobian needs 1 / b anyway,
// as the SDK's dual numbers do. Neither changes a value: the two-tank's
// Jacobian call gives the plugin's f to the bit (both a * (1 / A)), its f
// call the plugin's f to the bit (both a true division), and the tape is
// shorter than one instruction per node would be.
TEST(TextModel, FoldedNegationsAndSharedReciprocalsGiveThePluginsValuesToTheBit) {
  const ModelPtr plugin = builtins().get("two_tank").value();
  auto text = shipped_text_model("two_tank");
  ASSERT_TRUE(text.is_ok()) << text.status().to_string();
  const Model& m = *text->model;
  std::mt19937_64 rng(5);
  const Case& c = cases()[0];
  int differ = 0;
  for (int p = 0; p < 1000; ++p) {
    const Eigen::VectorXd x = draw(c.x, rng), theta = draw(c.theta, rng), u = draw(c.u, rng);
    Eigen::Vector2d ft, fp, f1t, f1p;
    Eigen::MatrixXd jt(2, 6), jp(2, 6);
    ASSERT_TRUE(m.f_jacobian(0.0, u.data(), x.data(), theta.data(), ft.data(), jt.data()).is_ok());
    ASSERT_TRUE(plugin->f_jacobian(0.0, u.data(), x.data(), theta.data(), fp.data(), jp.data()).is_ok());
    ASSERT_TRUE(m.f(0.0, u.data(), 1, 1, x.data(), theta.data(), f1t.data()).is_ok());
    ASSERT_TRUE(plugin->f(0.0, u.data(), 1, 1, x.data(), theta.data(), f1p.data()).is_ok());
    differ += (ft.array() != fp.array()).count() + (f1t.array() != f1p.array()).count();
  }
  EXPECT_EQ(differ, 0) << "values that are not the plugin's to the bit, of 4000";
  // f and its 2 x 6 Jacobian: 32 instructions and constants (38 with the
  // six negations as instructions of their own).
  EXPECT_LE(text->summary.tape_length, 32u);
}

TEST(TextModel, SparsityShowsTheStructuralZeros) {
  auto text = shipped_text_model("two_tank");
  ASSERT_TRUE(text.is_ok());
  // z = [h1 h2 A1 A2 k1 k2]: h1' depends on h1, A1, k1; h2' on all but A1.
  EXPECT_EQ(text->summary.f_sparsity, (std::vector<std::string>{"x.x.x.", "xx.xxx"}));
  EXPECT_EQ(text->summary.g_sparsity, (std::vector<std::string>{"x.....", ".x...."}));
  EXPECT_EQ(text->summary.equations.front(), "h1' = (F1 - q1) / A1");
}

// A domain error in the equations (log of a negative level) is the same
// FAILED_PRECONDITION naming the state as a plugin's NaN.
TEST(TextModel, ADomainErrorIsReportedLikeAPlugins) {
  auto m = compile_text_model("model: m\nstates: [h]\nder: {h: log(h)}\noutputs: {y: h}\n", "m.yaml");
  ASSERT_TRUE(m.is_ok()) << m.status().to_string();
  const double x = -1.0;
  double f = 0;
  const Status s = m->model->f(0.0, nullptr, 1, 1, &x, nullptr, &f);
  EXPECT_EQ(s.code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(s.message().find("non-finite derivative of state h"), std::string::npos) << s.message();
}

// ---------------------------------------------------------------------------
// Bad input: one clear INVALID_ARGUMENT each, naming the place.

struct Bad {
  std::string name;
  std::string yaml;
  std::string message;  // a part of the message
  std::string place;    // "file:line:col", or "" when the message has none
};

std::ostream& operator<<(std::ostream& os, const Bad& b) { return os << b.name; }

const std::string kHead = "model: m\nstates: {x: {}}\nparameters: {k: 1}\n";

std::vector<Bad> bad_inputs() {
  std::string deep = "x";
  for (int i = 0; i < 200; ++i) deep = "(" + deep + ")";
  std::string huge = "model: m\n" + std::string(kMaxTextModelBytes, '#') + "\n";
  // 2^n terms if expanded, n helpers if shared: fine; but n nested squares
  // of sin differentiate to a graph that grows with n, bounded.
  return {
      {"NotYaml", "model: m\nstates: [x\n", "not valid YAML", "bad.yaml:3:1"},
      {"NotAMapping", "- x\n- y\n", "a text model is a YAML mapping", "bad.yaml:1:1"},
      {"UnknownKey", kHead + "der: {x: -x}\noutputs: {y: x}\nequations: {}\n", "unknown key \"equations\"", "bad.yaml:6:1"},
      {"NoName", "states: [x]\nder: {x: -x}\noutputs: {y: x}\n", "no name", ""},
      {"BadModelName", "model: My Model\nstates: [x]\nder: {x: -x}\noutputs: {y: x}\n", "only a-z", "bad.yaml:1:8"},
      {"SyntaxError", kHead + "der:\n  x: (k * x +) / 2\noutputs: {y: x}\n", "unexpected ')'", "bad.yaml:5:14"},
      {"Unclosed", kHead + "der: {x: \"(k * (x + 1)\"}\noutputs: {y: x}\n", "is not closed", "bad.yaml:4:11"},
      {"Trailing", kHead + "der:\n  x: k x\noutputs: {y: x}\n", "unexpected 'x'", "bad.yaml:5:8"},
      {"NumberThenName", kHead + "der:\n  x: 2x\noutputs: {y: x}\n", "a name cannot follow a number", "bad.yaml:5:7"},
      {"UnknownName", kHead + "der:\n  x: k * z\noutputs: {y: x}\n", "unknown name \"z\"", "bad.yaml:5:10"},
      {"UnknownFunction", kHead + "der:\n  x: sqr(x)\noutputs: {y: x}\n", "unknown function 'sqr'", "bad.yaml:5:6"},
      {"WrongArity", kHead + "der:\n  x: atan2(x)\noutputs: {y: x}\n", "atan2 takes 2 arguments, not 1", "bad.yaml:5:6"},
      {"MissingDerivative", "model: m\nstates: [x, v]\nder: {x: v}\noutputs: {y: x}\n", "state v has no derivative", "bad.yaml:2:13"},
      {"DerOfNoState", kHead + "der: {x: -x, w: 1}\noutputs: {y: x}\n", "\"w\" is not a state", "bad.yaml:4:14"},
      {"DuplicateName", kHead + "inputs: [k]\nder: {x: -x}\noutputs: {y: x}\n", "duplicate name \"k\": it is already a parameter", "bad.yaml:4:10"},
      {"DuplicateKey", kHead + "der: {x: -x, x: x}\noutputs: {y: x}\n", "\"x\" appears twice in der", "bad.yaml:4:14"},
      {"ReservedName", "model: m\nstates: [t]\nder: {t: 1}\noutputs: {y: t}\n", "\"t\" is reserved", "bad.yaml:2:10"},
      {"FunctionAsName", "model: m\nstates: [x]\nparameters: {sin: 1}\nder: {x: 1}\noutputs: {y: x}\n", "name of a function", "bad.yaml:3:14"},
      {"Cycle", kHead + "define:\n  a: b + 1\n  b: c * x\n  c: a\nder: {x: a}\noutputs: {y: x}\n", "cycle: a -> b -> c -> a", "bad.yaml:5:3"},
      {"SelfReference", kHead + "define:\n  a: a + 1\nder: {x: a}\noutputs: {y: x}\n", "cycle: a -> a", "bad.yaml:5:3"},
      {"NoOutputs", "model: m\nstates: [x]\nder: {x: -x}\n", "no outputs", ""},
      {"NoStates", "model: m\nder: {}\noutputs: {y: 1}\n", "no states", ""},
      {"ParameterWithoutValue", "model: m\nstates: [x]\nparameters: {k: {min: 0}}\nder: {x: -x}\noutputs: {y: x}\n", "has no value", "bad.yaml:3:14"},
      {"ParameterNotANumber", "model: m\nstates: [x]\nparameters: {k: ten}\nder: {x: -x}\noutputs: {y: x}\n", "must be a finite number", "bad.yaml:3:17"},
      {"ParameterOutOfBounds", "model: m\nstates: [x]\nparameters: {k: {value: -1, min: 0}}\nder: {x: -x}\noutputs: {y: x}\n", "outside [min, max]", "bad.yaml:3:14"},
      {"TooDeep", kHead + "der: {x: \"" + deep + "\"}\noutputs: {y: x}\n", "nested too deeply", "bad.yaml:4:"},
      {"TooLarge", huge, "more than the limit", ""},
      {"ChainedComparison", kHead + "der:\n  x: if(0 < x < 1, 1, 0)\noutputs: {y: x}\n", "comparisons do not chain", "bad.yaml:5:15"},
      {"PowerOperator", kHead + "der:\n  x: x ** 2\noutputs: {y: x}\n", "'**' is not an operator", "bad.yaml:5:8"},
      {"EmptyExpression", kHead + "der:\n  x: \"\"\noutputs: {y: x}\n", "empty expression", ""},
      {"DerAndMechanical", "model: m\nstates: [s, v]\nder: {s: v, v: 0}\nmechanical: {M: [[1]], h: [s]}\noutputs: {y: s}\n",
       "give der or mechanical, not both", "bad.yaml:3:7"},
      {"MechanicalOddStates", "model: m\nstates: [s, v, w]\nmechanical: {M: [[1]], h: [s]}\noutputs: {y: s}\n",
       "positions, then as many velocities", "bad.yaml:3:13"},
      {"MechanicalShape", "model: m\nstates: [s, v]\nmechanical: {M: [[1, 0]], h: [s]}\noutputs: {y: s}\n",
       "row 1 of mechanical M must have 1 entries", "bad.yaml:3:18"},
      {"MechanicalNoH", "model: m\nstates: [s, v]\nmechanical: {M: [[1]]}\noutputs: {y: s}\n", "has no h", "bad.yaml:3:13"},
      {"MechanicalInputInH", "model: m\nstates: [s, v]\ninputs: [F]\nmechanical: {M: [[1]], h: [s - F], H: [[1]]}\noutputs: {y: s}\n",
       "the inputs enter only as H u and R u", ""},
      {"MechanicalUnknownName", "model: m\nstates: [s, v]\nmechanical: {M: [[m]], h: [s]}\noutputs: {y: s}\n",
       "unknown name \"m\"", "bad.yaml:3:19"},
  };
}

class BadTextModel : public ::testing::TestWithParam<Bad> {};

TEST_P(BadTextModel, IsRefusedWithOneClearMessage) {
  const Bad& b = GetParam();
  auto m = compile_text_model(b.yaml, "bad.yaml");
  ASSERT_FALSE(m.is_ok()) << b.yaml;
  EXPECT_EQ(m.status().code(), StatusCode::kInvalidArgument);
  const std::string& msg = m.status().message();
  EXPECT_NE(msg.find(b.message), std::string::npos) << msg;
  if (!b.place.empty()) {
    EXPECT_EQ(msg.rfind(b.place, 0), 0u) << msg;
  }
  // The caret sits under the place the message names.
  if (!b.place.empty() && b.place.back() != ':') {
    const auto line_end = msg.find('\n');
    ASSERT_NE(line_end, std::string::npos) << msg;
    const std::string rest = msg.substr(line_end + 1);
    const auto second = rest.find('\n');
    ASSERT_NE(second, std::string::npos) << msg;
    const std::string caret = rest.substr(second + 1);
    const int column = std::stoi(b.place.substr(b.place.rfind(':') + 1));
    EXPECT_EQ(caret.find('^'), static_cast<std::size_t>(column - 1 + 2)) << msg;  // two spaces of indent
  }
}

INSTANTIATE_TEST_SUITE_P(Inputs, BadTextModel, ::testing::ValuesIn(bad_inputs()),
                         [](const auto& param_info) { return param_info.param.name; });

// A model built to be slow (every helper the square of the one before: 2^n
// terms if expanded) is compiled in a graph that grows with n, not 2^n.
TEST(TextModel, RepeatedSubexpressionsDoNotExplode) {
  std::string yaml = "model: m\nstates: [x]\ndefine:\n  h0: sin(x)\n";
  for (int i = 1; i <= 200; ++i) {
    yaml += "  h" + std::to_string(i) + ": h" + std::to_string(i - 1) + " * h" + std::to_string(i - 1) + " + x\n";
  }
  yaml += "der: {x: h200}\noutputs: {y: x}\n";
  auto m = compile_text_model(yaml, "slow.yaml");
  ASSERT_TRUE(m.is_ok()) << m.status().to_string();
  EXPECT_LT(m->summary.graph_nodes, 2000u);
}

}  // namespace
}  // namespace riccati

namespace riccati {
namespace {

// A models directory holding text models loads them as it loads plugins,
// with their checksum, their Jacobian check and their summary; a bad one is
// refused with its message, the others load.
TEST(TextModel, AModelsDirectoryLoadsTextModels) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("riccati_text_models_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  fs::permissions(dir, fs::perms::owner_all | fs::perms::group_read | fs::perms::group_exec |
                           fs::perms::others_read | fs::perms::others_exec);
  for (const auto& entry : fs::directory_iterator(RICCATI_TEST_TEXT_MODEL_DIR)) {
    fs::copy_file(entry.path(), dir / entry.path().filename());
    fs::permissions(dir / entry.path().filename(), fs::perms::owner_read | fs::perms::owner_write | fs::perms::group_read |
                                                        fs::perms::others_read);
  }
  std::ofstream(dir / "broken.yml") << "model: broken\nstates: [x]\nder: {x: y}\noutputs: {y: x}\n";
  fs::permissions(dir / "broken.yml", fs::perms::owner_read | fs::perms::owner_write);
  auto registry = ModelRegistry::load_directory(dir.string());
  fs::remove_all(dir);
  ASSERT_TRUE(registry.is_ok()) << registry.status().to_string();
  EXPECT_EQ(registry->models().size(), 4u);
  ASSERT_EQ(registry->refused().size(), 1u);
  EXPECT_NE(registry->refused()[0].reason.find("broken.yml:3:10: unknown name \"y\""), std::string::npos)
      << registry->refused()[0].reason;
  for (const ModelPtr& m : registry->models()) {
    EXPECT_EQ(registry->sha256(*m).size(), 64u);
    EXPECT_TRUE(registry->jacobian_check(*m).checked) << m->name();
    EXPECT_TRUE(registry->jacobian_check(*m).agrees()) << m->name();
    ASSERT_NE(registry->text_summary(*m), nullptr);
    EXPECT_EQ(registry->text_summary(*m)->f_sparsity.size(), static_cast<std::size_t>(m->nx()));
  }
  EXPECT_EQ(builtins().text_summary(*builtins().get("two_tank").value()), nullptr);
}

}  // namespace
}  // namespace riccati

namespace riccati {
namespace {

// docs/text-models.md's worked example (examples/two_tank_rig.yaml): it
// compiles, its Jacobians agree with finite differences away from its kinks,
// and its non-smooth terms behave as the page says.
TEST(TextModel, TheDocumentedRigExample) {
  auto rig = compile_text_model(read_file(std::string(RICCATI_EXAMPLES_DIR) + "/two_tank_rig.yaml"), "rig.yaml");
  ASSERT_TRUE(rig.is_ok()) << rig.status().to_string();
  const Model& m = *rig->model;
  ASSERT_EQ(m.nx(), 2);
  ASSERT_EQ(m.ny(), 1);
  std::vector<JacobianPoint> points;
  for (const auto& [h1, h2, offset] : {std::tuple{0.3, 0.25, 0.01}, {0.7, 0.5, -0.02}, {0.2, 0.85, 0.0}}) {
    JacobianPoint p;
    p.t = 0;
    p.x = Eigen::Vector2d(h1, h2);
    p.theta = m.theta_default();
    p.theta[5] = offset;
    p.u = Eigen::VectorXd::Constant(1, 1e-4);
    points.push_back(p);
  }
  auto check = check_jacobians(m, points);
  ASSERT_TRUE(check.is_ok()) << check.status().to_string();
  EXPECT_TRUE(check->agrees()) << (check->disagreements.empty() ? "" : check->disagreements.front());
  const Eigen::VectorXd theta = m.theta_default();
  const double u = 1e-4;
  double f[2], jf[16], y, jg[8];
  // Below the rim no overflow: dh1'/dkover = 0; above it, -(h1 - rim) / A1.
  for (const double h1 : {0.5, 0.7}) {
    const double x[2] = {h1, 0.3};
    ASSERT_TRUE(m.f_jacobian(0, &u, x, theta.data(), f, jf).is_ok());
    EXPECT_DOUBLE_EQ(jf[0 + 2 * (2 + 4)], h1 > 0.6 ? -(h1 - 0.6) / theta[0] : 0.0);
  }
  // The sensor: inside its range dy/dh2 = 1 and dy/doffset = 1; saturated, 0.
  for (const double h2 : {0.4, 0.9}) {
    const double x[2] = {0.3, h2};
    ASSERT_TRUE(m.g_jacobian(0, &u, x, theta.data(), &y, jg).is_ok());
    EXPECT_DOUBLE_EQ(y, std::min(h2, 0.8));
    EXPECT_EQ(jg[1], h2 < 0.8 ? 1.0 : 0.0);
    EXPECT_EQ(jg[2 + 5], h2 < 0.8 ? 1.0 : 0.0);
  }
}

}  // namespace
}  // namespace riccati

namespace riccati {
namespace {

// The optimal filter on the manipulator written as text (the mechanical
// form): an identification as OptimalFilter.MultiPassIdentificationRunsThe-
// OptimalFilterToo runs it, with the text model and with the plugin, equal.
TEST(TextModel, OptimalFilterIdentificationOnTheMechanicalFormEqualsThePlugins) {
  const ModelPtr plugin = builtins().get("flexible_manipulator").value();
  auto text = shipped_text_model("flexible_manipulator");
  ASSERT_TRUE(text.is_ok()) << text.status().to_string();
  const Dataset data = read_csv_file(std::string(RICCATI_TEST_DATA_DIR) + "/flexible_manipulator.csv",
                                     ColumnMapping{"t", {"T"}, {"s1", "s2"}})
                           .value();
  auto vec = [](std::initializer_list<double> v) {
    Eigen::VectorXd out(static_cast<Eigen::Index>(v.size()));
    Eigen::Index i = 0;
    for (const double x : v) out[i++] = x;
    return out;
  };
  // Case C of docs/optimal-filter.md.
  IdentificationSettings s;
  s.filter.kind = FilterKind::kOptimal;
  s.filter.integrator.kind = IntegratorKind::kRk4;
  s.filter.integrator.substeps = 1;
  s.filter.optimal.V = vec({1e6, 1e6, 1e4, 1e6, 1e6}).asDiagonal();
  s.filter.optimal.W = vec({1e4, 1e4, 1e4, 1e4, 1e10, 1e10, 1e10, 1e10, 1e10, 1e10}).asDiagonal();
  const Eigen::VectorXd z0 = vec({0, 0, 0, 0, .001, .001, 6.5, .01, .005, .0025});
  s.initial.x0 = z0.head(4);
  s.initial.theta0 = z0.tail(6);
  s.initial.P0 = vec({1e12, 1e12, 1e12, 1e12, 1e1, 1e2, 5e-4, 1e1, 5e3, 5e3}).cwiseInverse().asDiagonal();
  s.passes = 1;
  s.end_sample = 800;  // 2 s
  const auto a = identify(text->model, data, s);
  const auto b = identify(plugin, data, s);
  ASSERT_TRUE(a.is_ok()) << a.status().to_string();
  ASSERT_TRUE(b.is_ok()) << b.status().to_string();
  for (Eigen::Index i = 0; i < b->theta.size(); ++i) {
    EXPECT_NEAR(a->theta[i], b->theta[i], 1e-9 * std::abs(b->theta[i])) << i;
  }
}

}  // namespace
}  // namespace riccati
