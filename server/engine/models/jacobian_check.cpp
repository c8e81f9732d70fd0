#include "engine/models/jacobian_check.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>

namespace riccati {
namespace {

// A function of z = [x; theta] with `rows` values, as the plugin evaluates it.
using Values = std::function<Status(const Eigen::VectorXd& z, double* out)>;

// Fourth-order central differences of `values` at z,
//     (8 (f(z + h) - f(z - h)) - (f(z + 2h) - f(z - 2h))) / (12 h),
// with h = eps^(1/5) |z_j| (or eps^(1/5) where z_j = 0), the step that
// balances their truncation error O(h^4) against rounding O(eps / h): about
// 1e-12 relative for smooth f, far below the tolerance it is judged by. The
// step scales with |z_j| itself, not max(1, |z_j|): a moment of inertia of
// 0.0028 kg m^2 moved by 7e-4 is no derivative.
Status central_differences(const Values& values, const Eigen::VectorXd& z, Eigen::Index rows, Eigen::MatrixXd* jac) {
  const double step_scale = std::pow(std::numeric_limits<double>::epsilon(), 0.2);
  jac->resize(rows, z.size());
  Eigen::VectorXd zp = z, p1(rows), m1(rows), p2(rows), m2(rows);
  for (Eigen::Index j = 0; j < z.size(); ++j) {
    const double h = step_scale * (z[j] != 0.0 ? std::abs(z[j]) : 1.0);
    const std::pair<double, Eigen::VectorXd*> steps[] = {{h, &p1}, {-h, &m1}, {2 * h, &p2}, {-2 * h, &m2}};
    for (const auto& [step, out] : steps) {
      zp[j] = z[j] + step;
      RICCATI_RETURN_IF_ERROR(values(zp, out->data()));
    }
    zp[j] = z[j];
    jac->col(j) = (8.0 * (p1 - m1) - (p2 - m2)) / (12.0 * h);
  }
  return Status::ok();
}

std::string vector_text(const Eigen::VectorXd& v) {
  std::string s = "[";
  for (Eigen::Index i = 0; i < v.size(); ++i) {
    s += (i > 0 ? ", " : "") + message_number(v[i]);
  }
  return s + "]";
}

// The worst entry of one Jacobian against its finite differences.
struct Comparison {
  double error = 0.0;
  Eigen::Index row = 0, column = 0;
  double exact = 0.0, numeric = 0.0;
};

Comparison compare(const Eigen::MatrixXd& exact, const Eigen::MatrixXd& numeric) {
  Comparison worst;
  for (Eigen::Index i = 0; i < exact.rows(); ++i) {
    const double row_scale = numeric.row(i).cwiseAbs().maxCoeff();
    for (Eigen::Index j = 0; j < exact.cols(); ++j) {
      const double scale = std::max({std::abs(numeric(i, j)), 1e-3 * row_scale, 1e-6});
      const double error = std::abs(exact(i, j) - numeric(i, j)) / scale;
      if (error > worst.error) worst = {error, i, j, exact(i, j), numeric(i, j)};
    }
  }
  return worst;
}

// One Jacobian the plugin gives, named for messages.
struct Derivative {
  std::string name;                      // "df/dz"
  std::function<std::string(Eigen::Index)> row_name;
  Eigen::Index rows = 0;
  Values values;
  std::function<Status(const Eigen::VectorXd& z, Eigen::MatrixXd* jac)> exact;
};

std::vector<Derivative> derivatives(const Model& model, const JacobianPoint& p) {
  const int nx = model.nx();
  std::vector<Derivative> out;
  auto split = [nx](const Eigen::VectorXd& z) { return std::pair{z.head(nx).eval(), z.tail(z.size() - nx).eval()}; };
  if (model.has_f_jacobian()) {
    out.push_back({"df/d[x; theta]", [&model](Eigen::Index i) { return model.state_names()[std::size_t(i)] + "'"; },
                   nx,
                   [&model, &p, split](const Eigen::VectorXd& z, double* v) {
                     const auto [x, theta] = split(z);
                     return model.f(p.t, p.u.data(), 1, 1, x.data(), theta.data(), v);
                   },
                   [&model, &p, split, nx](const Eigen::VectorXd& z, Eigen::MatrixXd* jac) {
                     const auto [x, theta] = split(z);
                     Eigen::VectorXd value(nx);
                     jac->resize(nx, z.size());
                     return model.f_jacobian(p.t, p.u.data(), x.data(), theta.data(), value.data(), jac->data());
                   }});
  }
  if (model.has_g_jacobian()) {
    const int ny = model.ny();
    out.push_back({"dg/d[x; theta]", [&model](Eigen::Index i) { return model.output_names()[std::size_t(i)]; }, ny,
                   [&model, &p, split](const Eigen::VectorXd& z, double* v) {
                     const auto [x, theta] = split(z);
                     return model.g(p.t, p.u.data(), 1, 1, x.data(), theta.data(), v);
                   },
                   [&model, &p, split, ny](const Eigen::VectorXd& z, Eigen::MatrixXd* jac) {
                     const auto [x, theta] = split(z);
                     Eigen::VectorXd value(ny);
                     jac->resize(ny, z.size());
                     return model.g_jacobian(p.t, p.u.data(), x.data(), theta.data(), value.data(), jac->data());
                   }});
  }
  if (model.has_mechanical_form()) {
    // c = [h; g] and Fc = [-H M; R G] (model_abi.h), their Jacobians in one call.
    const Eigen::Index nc = model.ndof() + model.ny(), nfc = nc * (model.nu() + model.ndof());
    const int nz = model.nz();
    auto mech = [&model, &p, split, nc, nfc, nz](const Eigen::VectorXd& z, Eigen::VectorXd* c, Eigen::VectorXd* fc,
                                                 Eigen::MatrixXd* c_jac, Eigen::MatrixXd* fc_jac) {
      const auto [x, theta] = split(z);
      c->resize(nc);
      fc->resize(nfc);
      c_jac->resize(nc, nz);
      fc_jac->resize(nfc, nz);
      return model.mechanical(p.t, x.data(), theta.data(), c->data(), fc->data(), c_jac->data(), fc_jac->data());
    };
    out.push_back({"dc/d[x; theta] of the mechanical form", [](Eigen::Index i) { return "c[" + std::to_string(i) + "]"; },
                   nc,
                   [mech](const Eigen::VectorXd& z, double* v) {
                     Eigen::VectorXd c, fc;
                     Eigen::MatrixXd cj, fj;
                     RICCATI_RETURN_IF_ERROR(mech(z, &c, &fc, &cj, &fj));
                     std::copy(c.data(), c.data() + c.size(), v);
                     return Status::ok();
                   },
                   [mech](const Eigen::VectorXd& z, Eigen::MatrixXd* jac) {
                     Eigen::VectorXd c, fc;
                     Eigen::MatrixXd fj;
                     return mech(z, &c, &fc, jac, &fj);
                   }});
    out.push_back({"dFc/d[x; theta] of the mechanical form",
                   [](Eigen::Index i) { return "Fc[" + std::to_string(i) + "] (column-major)"; }, nfc,
                   [mech](const Eigen::VectorXd& z, double* v) {
                     Eigen::VectorXd c, fc;
                     Eigen::MatrixXd cj, fj;
                     RICCATI_RETURN_IF_ERROR(mech(z, &c, &fc, &cj, &fj));
                     std::copy(fc.data(), fc.data() + fc.size(), v);
                     return Status::ok();
                   },
                   [mech](const Eigen::VectorXd& z, Eigen::MatrixXd* jac) {
                     Eigen::VectorXd c, fc;
                     Eigen::MatrixXd cj;
                     return mech(z, &c, &fc, &cj, jac);
                   }});
  }
  return out;
}

}  // namespace

Result<JacobianCheck> check_jacobians(const Model& model, const std::vector<JacobianPoint>& points) {
  JacobianCheck check;
  if (!model.has_f_jacobian() && !model.has_g_jacobian() && !model.has_mechanical_form()) {
    check.detail = "the model gives no Jacobians: riccati differentiates it by finite differences";
    return check;
  }
  std::vector<std::string> column_names = model.state_names();
  column_names.insert(column_names.end(), model.param_names().begin(), model.param_names().end());

  std::vector<Comparison> worst;  // per derivative, over the points
  std::vector<std::string> worst_at;
  std::string first_failure;
  for (const JacobianPoint& p : points) {
    if (p.u.size() != model.nu() || p.x.size() != model.nx() || p.theta.size() != model.ntheta()) {
      return invalid_argument("Jacobian check of model " + model.name() + ": a point's sizes do not match the model");
    }
    Eigen::VectorXd z(model.nz());
    z << p.x, p.theta;
    const std::vector<Derivative> ds = derivatives(model, p);
    worst.resize(ds.size());
    worst_at.resize(ds.size());
    bool evaluated = true;
    std::vector<Comparison> here;
    for (const Derivative& d : ds) {
      Eigen::MatrixXd exact, numeric;
      Status s = d.exact(z, &exact);
      if (s.is_ok()) s = central_differences(d.values, z, d.rows, &numeric);
      if (!s.is_ok()) {
        if (first_failure.empty()) first_failure = s.message();
        evaluated = false;
        break;
      }
      here.push_back(compare(exact, numeric));
    }
    if (!evaluated) continue;  // a point outside the model's domain says nothing
    ++check.points;
    for (std::size_t k = 0; k < here.size(); ++k) {
      if (here[k].error > worst[k].error) {
        worst[k] = here[k];
        worst_at[k] = "t = " + std::to_string(p.t) + ", x = " + vector_text(p.x) + ", theta = " + vector_text(p.theta) +
                      ", u = " + vector_text(p.u);
      }
    }
  }
  if (check.points == 0) {
    check.detail = "not checked: the model could not be evaluated at any point (" + first_failure + ")";
    return check;
  }
  check.checked = true;
  // The derivatives' names and rows do not depend on the point.
  const std::vector<Derivative> ds = derivatives(model, points.front());
  for (std::size_t k = 0; k < worst.size(); ++k) {
    check.max_error = std::max(check.max_error, worst[k].error);
    if (worst[k].error <= kJacobianTolerance) continue;
    char values[160];
    std::snprintf(values, sizeof values, " is %.9g, finite differences give %.9g", worst[k].exact, worst[k].numeric);
    check.disagreements.push_back(ds[k].name + ": d " + ds[k].row_name(worst[k].row) + " / d " +
                                  column_names[std::size_t(worst[k].column)] + values + " at " + worst_at[k]);
  }
  char summary[160];
  std::snprintf(summary, sizeof summary, "compared with fourth-order central differences at %d point%s: largest scaled "
                "difference %.2g (tolerance %.0e)", check.points, check.points == 1 ? "" : "s", check.max_error,
                kJacobianTolerance);
  check.detail = summary;
  return check;
}

std::vector<JacobianPoint> generic_points(const Model& model) {
  std::vector<JacobianPoint> points;
  for (const double a : {0.3, 0.7, 1.3}) {
    JacobianPoint p;
    p.t = a;
    p.theta = model.theta_default();
    p.x.resize(model.nx());
    for (int i = 0; i < model.nx(); ++i) p.x[i] = a * (1.0 + 0.13 * i);
    p.u.resize(model.nu());
    for (int j = 0; j < model.nu(); ++j) p.u[j] = 0.5 * a * (1.0 + 0.17 * j);
    points.push_back(std::move(p));
  }
  return points;
}

}  // namespace riccati
