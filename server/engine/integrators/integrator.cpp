#include "engine/integrators/integrator.hpp"

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

namespace riccati {

const char* integrator_kind_name(IntegratorKind kind) {
  switch (kind) {
    case IntegratorKind::kRk4: return "rk4";
    case IntegratorKind::kRk3: return "rk3";
    case IntegratorKind::kCvodeBdf: return "cvode-bdf";
    case IntegratorKind::kCvodeAdams: return "cvode-adams";
    case IntegratorKind::kArkodeErk: return "arkode-erk";
  }
  return "unknown";
}

Result<IntegratorKind> parse_integrator_kind(std::string_view name) {
  for (auto kind : {IntegratorKind::kRk4, IntegratorKind::kRk3, IntegratorKind::kCvodeBdf,
                    IntegratorKind::kCvodeAdams, IntegratorKind::kArkodeErk}) {
    if (name == integrator_kind_name(kind)) return kind;
  }
  return invalid_argument("unknown integrator \"" + std::string(name) +
                          "\" (expected rk4, rk3, cvode-bdf, cvode-adams or arkode-erk)");
}

Status validate(const IntegratorSettings& s) {
  const bool fixed = s.kind == IntegratorKind::kRk4 || s.kind == IntegratorKind::kRk3;
  if (fixed && (s.substeps < 1 || s.substeps > 1000000)) {
    return invalid_argument("integrator substeps must be between 1 and 1000000, got " + std::to_string(s.substeps));
  }
  if (!fixed) {
    if (!(s.rtol > 0.0) || !std::isfinite(s.rtol)) return invalid_argument("integrator rtol must be positive");
    if (!(s.atol > 0.0) || !std::isfinite(s.atol)) return invalid_argument("integrator atol must be positive");
    if (s.max_steps < 1) return invalid_argument("integrator max_steps must be at least 1");
  }
  return Status::ok();
}

namespace {

std::string format_number(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.9g", value);
  return buffer;
}

}  // namespace

Status check_integration_arguments(double t0, double t1, std::span<const double> y) {
  if (!std::isfinite(t0) || !std::isfinite(t1) || !(t1 > t0)) {
    return invalid_argument("integration interval must be finite and increasing, got t0 = " + format_number(t0) +
                            ", t1 = " + format_number(t1));
  }
  if (y.empty()) return invalid_argument("cannot integrate an empty state vector");
  for (std::size_t i = 0; i < y.size(); ++i) {
    if (!std::isfinite(y[i])) {
      return failed_precondition("initial state y[" + std::to_string(i) + "] = " + format_number(y[i]) +
                                 " at t = " + format_number(t0) + " is not finite");
    }
  }
  return Status::ok();
}

Status check_integration_result(const char* integrator_name, double t1, std::span<const double> y) {
  for (std::size_t i = 0; i < y.size(); ++i) {
    if (!std::isfinite(y[i])) {
      return failed_precondition(std::string(integrator_name) + " produced a non-finite state y[" +
                                 std::to_string(i) + "] at t = " + format_number(t1));
    }
  }
  return Status::ok();
}

namespace {

// Explicit Runge-Kutta with a fixed number of equal substeps per interval.
// Work vectors are allocated for a system size once and reused.
class FixedStepRungeKutta final : public Integrator {
 public:
  FixedStepRungeKutta(int order, int substeps) : order_(order), substeps_(substeps) {}

  Status integrate(OdeRhs& rhs, double t0, double t1, std::span<double> y) override {
    RICCATI_RETURN_IF_ERROR(check_integration_arguments(t0, t1, y));
    const std::size_t n = y.size();
    if (k1_.size() != n) {
      for (auto* v : {&k1_, &k2_, &k3_, &k4_, &tmp_}) v->assign(n, 0.0);
    }
    const double h = (t1 - t0) / substeps_;
    double* yv = y.data();
    for (int s = 0; s < substeps_; ++s) {
      const double t = t0 + s * h;
      if (order_ == 4) {
        RICCATI_RETURN_IF_ERROR(rk4_step(rhs, t, h, yv, n));
      } else {
        RICCATI_RETURN_IF_ERROR(rk3_step(rhs, t, h, yv, n));
      }
    }
    return check_integration_result(order_ == 4 ? "rk4" : "rk3", t1, y);
  }

 private:
  // Classic RK4: y += h/6 (k1 + 2 k2 + 2 k3 + k4).
  Status rk4_step(OdeRhs& rhs, double t, double h, double* __restrict y, std::size_t n) {
    double* __restrict tmp = tmp_.data();
    double* __restrict k1 = k1_.data();
    double* __restrict k2 = k2_.data();
    double* __restrict k3 = k3_.data();
    double* __restrict k4 = k4_.data();
    RICCATI_RETURN_IF_ERROR(rhs.eval(t, y, k1));
    for (std::size_t i = 0; i < n; ++i) tmp[i] = y[i] + 0.5 * h * k1[i];
    RICCATI_RETURN_IF_ERROR(rhs.eval(t + 0.5 * h, tmp, k2));
    for (std::size_t i = 0; i < n; ++i) tmp[i] = y[i] + 0.5 * h * k2[i];
    RICCATI_RETURN_IF_ERROR(rhs.eval(t + 0.5 * h, tmp, k3));
    for (std::size_t i = 0; i < n; ++i) tmp[i] = y[i] + h * k3[i];
    RICCATI_RETURN_IF_ERROR(rhs.eval(t + h, tmp, k4));
    const double h6 = h / 6.0;
    for (std::size_t i = 0; i < n; ++i) y[i] += h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
    return Status::ok();
  }

  // Kutta's third-order method: y += h/6 (k1 + 4 k2 + k3),
  // k2 at (t + h/2, y + h/2 k1), k3 at (t + h, y - h k1 + 2 h k2).
  Status rk3_step(OdeRhs& rhs, double t, double h, double* __restrict y, std::size_t n) {
    double* __restrict tmp = tmp_.data();
    double* __restrict k1 = k1_.data();
    double* __restrict k2 = k2_.data();
    double* __restrict k3 = k3_.data();
    RICCATI_RETURN_IF_ERROR(rhs.eval(t, y, k1));
    for (std::size_t i = 0; i < n; ++i) tmp[i] = y[i] + 0.5 * h * k1[i];
    RICCATI_RETURN_IF_ERROR(rhs.eval(t + 0.5 * h, tmp, k2));
    for (std::size_t i = 0; i < n; ++i) tmp[i] = y[i] - h * k1[i] + 2.0 * h * k2[i];
    RICCATI_RETURN_IF_ERROR(rhs.eval(t + h, tmp, k3));
    const double h6 = h / 6.0;
    for (std::size_t i = 0; i < n; ++i) y[i] += h6 * (k1[i] + 4.0 * k2[i] + k3[i]);
    return Status::ok();
  }

  int order_;
  int substeps_;
  std::vector<double> k1_, k2_, k3_, k4_, tmp_;
};

}  // namespace

Result<std::unique_ptr<Integrator>> make_integrator(const IntegratorSettings& settings) {
  RICCATI_RETURN_IF_ERROR(validate(settings));
  switch (settings.kind) {
    case IntegratorKind::kRk4: return std::unique_ptr<Integrator>(new FixedStepRungeKutta(4, settings.substeps));
    case IntegratorKind::kRk3: return std::unique_ptr<Integrator>(new FixedStepRungeKutta(3, settings.substeps));
    case IntegratorKind::kCvodeBdf:
    case IntegratorKind::kCvodeAdams: return make_cvode_integrator(settings);
    case IntegratorKind::kArkodeErk: return make_arkode_integrator(settings);
  }
  return invalid_argument("unknown integrator kind");
}

}  // namespace riccati
