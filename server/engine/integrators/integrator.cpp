#include "engine/integrators/integrator.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

namespace riccati {

const char* integrator_kind_name(IntegratorKind kind) {
  switch (kind) {
    case IntegratorKind::kRk4: return "rk4";
    case IntegratorKind::kRk3: return "rk3";
    case IntegratorKind::kDop853: return "dop853";
    case IntegratorKind::kCvodeBdf: return "cvode-bdf";
    case IntegratorKind::kCvodeAdams: return "cvode-adams";
    case IntegratorKind::kArkodeErk: return "arkode-erk";
  }
  return "unknown";
}

bool is_fixed_step(IntegratorKind kind) {
  return kind == IntegratorKind::kRk4 || kind == IntegratorKind::kRk3 || kind == IntegratorKind::kDop853;
}

Result<IntegratorKind> parse_integrator_kind(std::string_view name) {
  for (auto kind : {IntegratorKind::kRk4, IntegratorKind::kRk3, IntegratorKind::kDop853, IntegratorKind::kCvodeBdf,
                    IntegratorKind::kCvodeAdams, IntegratorKind::kArkodeErk}) {
    if (name == integrator_kind_name(kind)) return kind;
  }
  return invalid_argument("unknown integrator \"" + std::string(name) +
                          "\" (expected rk4, rk3, dop853, cvode-bdf, cvode-adams or arkode-erk)");
}

Status validate(const IntegratorSettings& s) {
  const bool fixed = is_fixed_step(s.kind);
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

thread_local Interrupt* current = nullptr;

}  // namespace

std::int64_t Interrupt::steps_allowed(std::int64_t own) const {
  std::int64_t allowed = own;
  if (max_steps_per_interval > 0) allowed = std::min(allowed, max_steps_per_interval);
  if (max_steps_total > 0) allowed = std::min(allowed, std::max<std::int64_t>(0, max_steps_total - steps));
  return allowed;
}

bool Interrupt::interval_bound_binds() const {
  return max_steps_per_interval > 0 && (max_steps_total <= 0 || max_steps_total - steps >= max_steps_per_interval);
}

Status Interrupt::exhausted_status(std::int64_t counted) const {
  if (exhausted) return exhausted(counted);
  return {StatusCode::kResourceExhausted, "integration stopped after " + std::to_string(counted) + " steps, its budget"};
}

InterruptScope::InterruptScope(Interrupt& interrupt) : previous_(current) { current = &interrupt; }
InterruptScope::~InterruptScope() { current = previous_; }

Interrupt* current_interrupt() { return current; }

bool is_interruption(const Status& status) {
  return status.code() == StatusCode::kCancelled || status.code() == StatusCode::kDeadlineExceeded ||
         status.code() == StatusCode::kResourceExhausted;
}

Status check_integration_arguments(double t0, double t1, std::span<const double> y) {
  if (!std::isfinite(t0) || !std::isfinite(t1) || !(t1 > t0)) {
    return invalid_argument("integration interval must be finite and increasing, got t0 = " + message_number(t0, 9) +
                            ", t1 = " + message_number(t1, 9));
  }
  if (y.empty()) return invalid_argument("cannot integrate an empty state vector");
  for (std::size_t i = 0; i < y.size(); ++i) {
    if (!std::isfinite(y[i])) {
      return failed_precondition("initial state y[" + std::to_string(i) + "] = " + message_number(y[i], 9) +
                                 " at t = " + message_number(t0, 9) + " is not finite");
    }
  }
  return Status::ok();
}

Status check_integration_result(const char* integrator_name, double t1, std::span<const double> y) {
  for (std::size_t i = 0; i < y.size(); ++i) {
    if (!std::isfinite(y[i])) {
      return failed_precondition(std::string(integrator_name) + " produced a non-finite state y[" +
                                 std::to_string(i) + "] at t = " + message_number(t1, 9));
    }
  }
  return Status::ok();
}

namespace {

// A fixed-step integration's substeps counted against an interrupt's budget
// before any is taken: they are known in advance.
Status charge_substeps(Interrupt* interrupt, int substeps) {
  if (interrupt == nullptr) return Status::ok();
  if (interrupt->steps_allowed(substeps) < substeps) {
    return interrupt->exhausted_status(interrupt->interval_bound_binds() ? substeps : interrupt->steps + substeps);
  }
  interrupt->steps += substeps;
  return Status::ok();
}

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
    Interrupt* interrupt = current_interrupt();
    RICCATI_RETURN_IF_ERROR(charge_substeps(interrupt, substeps_));
    const double h = (t1 - t0) / substeps_;
    double* yv = y.data();
    for (int s = 0; s < substeps_; ++s) {
      if (interrupt != nullptr) RICCATI_RETURN_IF_ERROR(interrupt->evaluated(order_));
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


// Dormand and Prince's 8th-order pair (Hairer, Norsett, Wanner, Solving ODEs I,
// sec. II.10; DOP853): the 12 stages of the 8th-order solution. The values
// are exact binary copies (hex) of the coefficients as scipy publishes them
// (scipy/integrate/_ivp/dop853_coefficients.py).
constexpr int kDop853Stages = 12;
constexpr double kDop853C[kDop853Stages] = {
    0x0.0p+0, 0x1.aee6838dae63ap-5, 0x1.432ce2aa42cacp-4, 0x1.e4c353ff64302p-4, 0x1.2068c499c08d9p-2, 0x1.5555555555555p-2, 0x1.0000000000000p-2, 0x1.3b13b13b13b14p-2, 0x1.4d74d74d74d75p-1, 0x1.3333333333333p-1, 0x1.b6db6db6db6dbp-1, 0x1.0000000000000p+0};
constexpr double kDop853A[kDop853Stages][kDop853Stages] = {
    {0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {0x1.aee6838dae63ap-5, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {0x1.432ce2aa42cacp-6, 0x1.e4c353ff64302p-5, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {0x1.e4c353ff64302p-6, 0x0.0p+0, 0x1.6b927eff8b241p-4, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {0x1.ee50d7ecde9fap-3, 0x0.0p+0, -0x1.c4e3ab5ad1507p-1, 0x1.d983d7ac79ef5p-1, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {0x1.2f684bda12f68p-5, 0x0.0p+0, 0x0.0p+0, 0x1.5ddb63bdb6d36p-3, 0x1.00f533f66f19ap-3, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {0x1.3000000000000p-5, 0x0.0p+0, 0x0.0p+0, 0x1.5cad30f3347edp-3, 0x1.ed4b3c332e04dp-5, -0x1.2000000000000p-6, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {0x1.2fdb8fee78792p-5, 0x0.0p+0, 0x0.0p+0, 0x1.5cf23f6595d72p-3, 0x1.b758640dea698p-4, -0x1.f5fcc20fcd32fp-7, 0x1.0f1d92efb0b71p-7, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {0x1.3f8b78b985813p-1, 0x0.0p+0, 0x0.0p+0, -0x1.ae31bacc6bc8ap+1, -0x1.bc873f08e11f9p-1, 0x1.b9793d88d1855p+4, 0x1.42770f892ad69p+4, -0x1.5beb4865c42f9p+5, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {0x1.e9205e321b655p-2, 0x0.0p+0, 0x0.0p+0, -0x1.3e7a8a34bd27fp+1, -0x1.2e3a9968c93c8p-1, 0x1.53ae4a6d655eep+4, 0x1.e8ef7b5f258b8p+3, -0x1.0a4e418d711b9p+5, -0x1.4d1b3d9b4a876p-6, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0},
    {-0x1.dfd121f1d399bp-1, 0x0.0p+0, 0x0.0p+0, 0x1.4bed869fb0b9dp+2, 0x1.1768702792ea9p+0, -0x1.04cb0e2110c1cp+3, -0x1.2852305e975a8p+4, 0x1.6bd4f06cb863ap+4, 0x1.3f2e777cf109dp+1, -0x1.85fc60d2b572cp+1, 0x0.0p+0, 0x0.0p+0},
    {0x1.22fbd3b09fcdcp+1, 0x0.0p+0, 0x0.0p+0, -0x1.511a963cafe55p+3, -0x1.001c935ac72acp+1, -0x1.1f57c8eff3006p+4, 0x1.bf2ea18b58a01p+4, -0x1.6df3a7d1cec13p+1, -0x1.1bee71a9f33a9p+3, 0x1.8b89c42c81861p+3, 0x1.496ac6253e202p-1, 0x0.0p+0},
};
constexpr double kDop853B[kDop853Stages] = {
    0x1.bcc6368d1177cp-5, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x0.0p+0, 0x1.1cd1ed2ad5ae2p+2, 0x1.e43a845d5ab9fp+0, -0x1.7346ecf96af43p+2, 0x1.3ea1df2f0eb98p-2, -0x1.37a028f43b002p-3, 0x1.9c657697fe72dp-3, 0x1.6e44f50ab6bc2p-5};

// The 8th-order explicit Runge-Kutta of Dormand and Prince with a fixed
// number of equal substeps per interval (no error control: the caller
// chooses the step, as with RK4). 12 evaluations a step; for a model whose
// time constants are long against the sample time, one step a sample is as
// accurate as RK4's ten (40 evaluations).
class FixedStepDop853 final : public Integrator {
 public:
  explicit FixedStepDop853(int substeps) : substeps_(substeps) {}

  Status integrate(OdeRhs& rhs, double t0, double t1, std::span<double> y) override {
    RICCATI_RETURN_IF_ERROR(check_integration_arguments(t0, t1, y));
    const std::size_t n = y.size();
    if (tmp_.size() != n) {
      k_.assign(kDop853Stages * n, 0.0);
      tmp_.assign(n, 0.0);
    }
    Interrupt* interrupt = current_interrupt();
    RICCATI_RETURN_IF_ERROR(charge_substeps(interrupt, substeps_));
    const double h = (t1 - t0) / substeps_;
    for (int s = 0; s < substeps_; ++s) {
      if (interrupt != nullptr) RICCATI_RETURN_IF_ERROR(interrupt->evaluated(kDop853Stages));
      RICCATI_RETURN_IF_ERROR(step(rhs, t0 + s * h, h, y.data(), n));
    }
    return check_integration_result("dop853", t1, y);
  }

 private:
  Status step(OdeRhs& rhs, double t, double h, double* __restrict y, std::size_t n) {
    double* __restrict k = k_.data();
    double* __restrict tmp = tmp_.data();
    RICCATI_RETURN_IF_ERROR(rhs.eval(t, y, k));
    for (int i = 1; i < kDop853Stages; ++i) {
      for (std::size_t v = 0; v < n; ++v) tmp[v] = y[v];
      for (int j = 0; j < i; ++j) {
        const double a = h * kDop853A[i][j];
        if (a == 0.0) continue;
        const double* kj = k + std::size_t(j) * n;
        for (std::size_t v = 0; v < n; ++v) tmp[v] += a * kj[v];
      }
      RICCATI_RETURN_IF_ERROR(rhs.eval(t + kDop853C[i] * h, tmp, k + std::size_t(i) * n));
    }
    for (int i = 0; i < kDop853Stages; ++i) {
      const double b = h * kDop853B[i];
      if (b == 0.0) continue;
      const double* ki = k + std::size_t(i) * n;
      for (std::size_t v = 0; v < n; ++v) y[v] += b * ki[v];
    }
    return Status::ok();
  }

  int substeps_;
  std::vector<double> k_, tmp_;  // the stages, one after the other; a stage's argument
};

}  // namespace

Result<std::unique_ptr<Integrator>> make_integrator(const IntegratorSettings& settings) {
  RICCATI_RETURN_IF_ERROR(validate(settings));
  switch (settings.kind) {
    case IntegratorKind::kRk4: return std::unique_ptr<Integrator>(new FixedStepRungeKutta(4, settings.substeps));
    case IntegratorKind::kRk3: return std::unique_ptr<Integrator>(new FixedStepRungeKutta(3, settings.substeps));
    case IntegratorKind::kDop853: return std::unique_ptr<Integrator>(new FixedStepDop853(settings.substeps));
    case IntegratorKind::kCvodeBdf:
    case IntegratorKind::kCvodeAdams: return make_cvode_integrator(settings);
    case IntegratorKind::kArkodeErk: return make_arkode_integrator(settings);
  }
  return invalid_argument("unknown integrator kind");
}

}  // namespace riccati
