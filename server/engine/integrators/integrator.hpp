// ODE integrators behind one interface: fixed-step RK4/RK3 with substeps for
// hard real-time use, fixed-step 8th-order Dormand-Prince for smooth, slow
// models where one step a sample is as accurate as ten of RK4, SUNDIALS CVODE (BDF, Adams) and ARKODE explicit adaptive
// Runge-Kutta. An integrator is created once per filter (or job) and reused at
// every sample: the SUNDIALS ones re-initialise, they do not re-allocate.
#pragma once

#include <cstdint>
#include <functional>
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

// What ends an integration before its end: the caller's cancellation (a
// client gone, a deadline passed, a job cancelled, a session closed, a
// shutdown), polled within a sample, and a budget of steps. Without one a
// single sample of a stiff model under an adaptive integrator could run for
// IntegratorSettings::max_steps (up to 1e9) internal steps, deaf to all of
// these. The caller installs it on its thread (InterruptScope) for as long as
// the work it starts runs there; every integrator finds it (current_interrupt())
// without the layers between (filters, the on-line runner, identification,
// output error's sensitivities, simulate) passing it on. Ceres evaluates on
// the calling thread (num_threads = 1), so an optimiser's runs are under it too.
struct Interrupt {
  // Polled every kPollEvaluations right-hand side evaluations; a non-ok status
  // (kCancelled, kDeadlineExceeded) ends the integration with it. Optional.
  std::function<Status()> poll;
  // Steps (an adaptive integrator's internal steps, a fixed-step one's
  // substeps) that one integrate() call may take, and that every call under
  // this interrupt may take together; 0: no bound but the integrator's own.
  std::int64_t max_steps_per_interval = 0;
  std::int64_t max_steps_total = 0;
  // The status when one of them is reached, given the steps counted against
  // it: names the caller's limit (kResourceExhausted). Optional.
  std::function<Status(std::int64_t steps)> exhausted;

  // Kept by the integrators.
  std::int64_t steps = 0;        // taken under it so far, every call together
  std::int64_t evaluations = 0;  // right-hand side evaluations so far

  static constexpr std::int64_t kPollEvaluations = 16;

  // For integrators: counts n evaluations and polls when one is due.
  Status evaluated(std::int64_t n = 1) {
    evaluations += n;
    if (evaluations < next_poll_) return Status::ok();
    next_poll_ = evaluations + kPollEvaluations;
    return poll ? poll() : Status::ok();
  }
  // The most steps the next integrate() call may take, its own bound being
  // `own` (0 when a bound is spent), and whether the per-interval bound is
  // the one that binds it (rather than what is left of the total).
  std::int64_t steps_allowed(std::int64_t own) const;
  bool interval_bound_binds() const;
  // The status for a bound reached, with the steps counted against it.
  Status exhausted_status(std::int64_t counted) const;

 private:
  std::int64_t next_poll_ = 0;  // polled at the first evaluation
};

// Installs an interrupt for the integrations this thread runs until the
// scope ends (scopes nest: the innermost counts).
class InterruptScope {
 public:
  explicit InterruptScope(Interrupt& interrupt);
  ~InterruptScope();
  InterruptScope(const InterruptScope&) = delete;
  InterruptScope& operator=(const InterruptScope&) = delete;

 private:
  Interrupt* previous_;
};

// The interrupt installed on this thread, or nullptr.
Interrupt* current_interrupt();

// An interruption (cancelled, past a deadline, a step budget spent) rather
// than a failure of the model or the filter: the work stopped, nothing diverged.
bool is_interruption(const Status& status);

class Integrator {
 public:
  virtual ~Integrator() = default;
  // Advances y from t0 to t1 (> t0) in place. On error y is unspecified.
  // Under an Interrupt (current_interrupt()) every kind counts its steps
  // against its budget and polls it: kCancelled, kDeadlineExceeded or
  // kResourceExhausted as it says, within kPollEvaluations evaluations.
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
