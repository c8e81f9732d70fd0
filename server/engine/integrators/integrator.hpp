// ODE integrators behind one interface: fixed-step RK4/RK3 with substeps for
// hard real-time use, fixed-step 8th-order Dormand-Prince for smooth, slow
// models where one step a sample is as accurate as ten of RK4, SUNDIALS CVODE (BDF, Adams) and ARKODE explicit adaptive
// Runge-Kutta. An integrator is created once per filter (or job) and reused at
// every sample: the SUNDIALS ones re-initialise, they do not re-allocate.
#pragma once

#include <memory>
#include <span>
#include <string>

#include "engine/status.hpp"

namespace riccati {

// Right-hand side y' = rhs(t, y) of the system being integrated.
class OdeRhs {
 public:
  virtual ~OdeRhs() = default;
  // Writes y'(t) into ydot (same size as y). A non-ok Status aborts the step;
  // kFailedPrecondition marks a numerical failure (NaN/Inf) that an adaptive
  // integrator may retry with a smaller step before giving up.
  virtual Status eval(double t, const double* y, double* ydot) = 0;
};

enum class IntegratorKind {
  kRk4,         // classic 4th-order Runge-Kutta, `substeps` equal steps per interval
  kRk3,         // Kutta's 3rd-order method, `substeps` equal steps per interval
  kDop853,      // Dormand-Prince 8th order (DOP853's 12 stages), `substeps` equal steps per interval
  kCvodeBdf,    // SUNDIALS CVODE, BDF with dense Newton (stiff models)
  kCvodeAdams,  // SUNDIALS CVODE, Adams-Moulton with fixed-point iteration
  kArkodeErk,   // SUNDIALS ARKODE ERKStep, adaptive explicit Runge-Kutta
};

struct IntegratorSettings {
  IntegratorKind kind = IntegratorKind::kRk4;
  int substeps = 10;         // fixed-step kinds: steps per sample interval
  double rtol = 1e-8;        // adaptive kinds: relative tolerance
  double atol = 1e-10;       // adaptive kinds: absolute tolerance
  long max_steps = 100000;   // adaptive kinds: internal steps per interval
};

const char* integrator_kind_name(IntegratorKind kind);
// The kinds that take `substeps` equal steps (rk4, rk3, dop853).
bool is_fixed_step(IntegratorKind kind);
// Parses "rk4", "rk3", "dop853", "cvode-bdf", "cvode-adams", "arkode-erk".
Result<IntegratorKind> parse_integrator_kind(std::string_view name);
Status validate(const IntegratorSettings& settings);

class Integrator {
 public:
  virtual ~Integrator() = default;
  // Advances y from t0 to t1 (> t0) in place. On error y is unspecified.
  virtual Status integrate(OdeRhs& rhs, double t0, double t1, std::span<double> y) = 0;
};

// Creates an integrator; state sized for a system is allocated on first use
// and reused while the size stays the same.
Result<std::unique_ptr<Integrator>> make_integrator(const IntegratorSettings& settings);

// For Integrator implementations, the checks every kind makes: a finite,
// increasing interval and a non-empty, finite y before; a finite y after
// (a NaN is never reported as a successful step).
Status check_integration_arguments(double t0, double t1, std::span<const double> y);
Status check_integration_result(const char* integrator_name, double t1, std::span<const double> y);

// Implemented in sundials_integrators.cpp.
std::unique_ptr<Integrator> make_cvode_integrator(const IntegratorSettings& settings);
std::unique_ptr<Integrator> make_arkode_integrator(const IntegratorSettings& settings);

}  // namespace riccati
