// SUNDIALS-backed integrators: CVODE (BDF with dense Newton, Adams with
// fixed-point iteration) and ARKODE ERKStep (adaptive explicit Runge-Kutta).
//
// Every SUNDIALS handle is owned by a unique_ptr. The solver is built the
// first time integrate() sees a system size and afterwards only re-initialised
// at the new (t0, y0): a filter calls integrate() at every sample, and
// re-allocating the solver each time would dominate its cost.
#include <cvode/cvode.h>
#include <arkode/arkode_erkstep.h>
#include <nvector/nvector_serial.h>
#include <sundials/sundials_context.h>
#include <sunlinsol/sunlinsol_dense.h>
#include <sunmatrix/sunmatrix_dense.h>
#include <sunnonlinsol/sunnonlinsol_fixedpoint.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <type_traits>
#include <utility>

#include "engine/integrators/integrator.hpp"

namespace riccati {
namespace {

// States are copied between std::span<double> and N_Vector data.
static_assert(std::is_same_v<sunrealtype, double>, "SUNDIALS must be built in double precision");

struct ContextDeleter {
  void operator()(SUNContext context) const { SUNContext_Free(&context); }
};
struct VectorDeleter {
  void operator()(N_Vector vector) const { N_VDestroy(vector); }
};
struct MatrixDeleter {
  void operator()(SUNMatrix matrix) const { SUNMatDestroy(matrix); }
};
struct LinearSolverDeleter {
  void operator()(SUNLinearSolver solver) const { SUNLinSolFree(solver); }
};
struct NonlinearSolverDeleter {
  void operator()(SUNNonlinearSolver solver) const { SUNNonlinSolFree(solver); }
};
struct CvodeMemoryDeleter {
  void operator()(void* memory) const { CVodeFree(&memory); }
};
struct ErkStepMemoryDeleter {
  void operator()(void* memory) const { ERKStepFree(&memory); }
};

using ContextPtr = std::unique_ptr<std::remove_pointer_t<SUNContext>, ContextDeleter>;
using VectorPtr = std::unique_ptr<std::remove_pointer_t<N_Vector>, VectorDeleter>;
using MatrixPtr = std::unique_ptr<std::remove_pointer_t<SUNMatrix>, MatrixDeleter>;
using LinearSolverPtr = std::unique_ptr<std::remove_pointer_t<SUNLinearSolver>, LinearSolverDeleter>;
using NonlinearSolverPtr = std::unique_ptr<std::remove_pointer_t<SUNNonlinearSolver>, NonlinearSolverDeleter>;
using CvodeMemoryPtr = std::unique_ptr<void, CvodeMemoryDeleter>;
using ErkStepMemoryPtr = std::unique_ptr<void, ErkStepMemoryDeleter>;


// What the C callbacks reach through user_data: the model being integrated
// and what went wrong during the current integrate() call, so that a failure
// is reported in the model's own words rather than as a bare solver flag.
struct CallbackState {
  OdeRhs* rhs = nullptr;
  Interrupt* interrupt = nullptr;  // the caller's, polled before each evaluation (or none)
  Status rhs_failure;          // last non-ok Status returned by rhs
  bool rhs_aborted = false;    // rhs failed unrecoverably in this call
  std::string solver_message;  // last error message SUNDIALS reported

  void begin(OdeRhs& model_rhs, Interrupt* caller_interrupt) {
    rhs = &model_rhs;
    interrupt = caller_interrupt;
    rhs_failure = Status::ok();
    rhs_aborted = false;
    solver_message.clear();
  }
};

// CVRhsFn and ARKRhsFn share this signature. Returning 1 tells the solver
// the failure is recoverable (it retries with a smaller step): that is what
// a NaN/Inf from the model (kFailedPrecondition) usually calls for.
int rhs_trampoline(sunrealtype t, N_Vector y, N_Vector ydot, void* user_data) {
  auto& state = *static_cast<CallbackState*>(user_data);
  // SUNDIALS 6.4's fixed-point solver (CVODE Adams) retries even after an
  // unrecoverable failure; refusing every later evaluation makes it give up
  // at once instead of creeping up to the failure until max_steps.
  if (state.rhs_aborted) return -1;
  Status status;
  try {
    // A cancellation (or deadline) is unrecoverable: the solver stops at once.
    if (state.interrupt != nullptr) status = state.interrupt->evaluated();
    if (status.is_ok()) status = state.rhs->eval(t, N_VGetArrayPointer(y), N_VGetArrayPointer(ydot));
  } catch (...) {
    // An exception must not unwind through SUNDIALS' C frames.
    status = internal_error("right-hand side threw an exception at t = " + message_number(t, 9));
  }
  if (status.is_ok()) return 0;
  state.rhs_aborted = status.code() != StatusCode::kFailedPrecondition;
  state.rhs_failure = std::move(status);
  return state.rhs_aborted ? -1 : 1;
}

// CVErrHandlerFn and ARKErrHandlerFn: keeps the message instead of printing
// it to stderr. Warnings (positive codes, e.g. "t + h = t") are not failures.
void store_error_message(int error_code, const char* /*module*/, const char* function, char* message,
                         void* handler_data) {
  if (error_code >= 0) return;
  static_cast<CallbackState*>(handler_data)->solver_message = std::string(function) + ": " + message;
}

using FlagNameFn = char* (*)(long int);

// The *GetReturnFlagName functions return a malloc'ed string.
std::string flag_name(FlagNameFn get_name, int flag) {
  std::unique_ptr<char, decltype(&std::free)> name(get_name(flag), &std::free);
  return name ? std::string(name.get()) : "flag " + std::to_string(flag);
}

// The part both SUNDIALS packages share: context, state vector, callbacks,
// argument checks, the allocate-once / re-initialise-after policy and error
// reporting. A subclass builds, re-initialises and runs its own solver.
class SundialsIntegrator : public Integrator {
 public:
  SundialsIntegrator(const SundialsIntegrator&) = delete;
  SundialsIntegrator& operator=(const SundialsIntegrator&) = delete;

  Status integrate(OdeRhs& rhs, double t0, double t1, std::span<double> y) final {
    RICCATI_RETURN_IF_ERROR(settings_status_);
    RICCATI_RETURN_IF_ERROR(check_integration_arguments(t0, t1, y));
    // The caller's budget bounds this call's internal steps (CVODE's and
    // ARKODE's mxstep counts the steps of one call to reach tout).
    Interrupt* interrupt = current_interrupt();
    long max_steps = settings_.max_steps;
    bool budget_binds = false, interval_binds = false;
    if (interrupt != nullptr) {
      const std::int64_t allowed = interrupt->steps_allowed(max_steps);
      interval_binds = interrupt->interval_bound_binds();
      if (allowed < 1) return interrupt->exhausted_status(interval_binds ? 0 : interrupt->steps);
      if (allowed < max_steps) {
        max_steps = static_cast<long>(allowed);
        budget_binds = true;
      }
    }
    callbacks_.begin(rhs, interrupt);
    RICCATI_RETURN_IF_ERROR(prepare(t0, y));
    if (max_steps != max_steps_set_) {
      RICCATI_RETURN_IF_ERROR(check_setup(set_max_steps(max_steps), "setting the most steps"));
      max_steps_set_ = max_steps;
    }

    double t_reached = t0;
    const long before = interrupt != nullptr ? steps_taken() : 0;  // 0 after a re-initialisation, but not relied on
    const int flag = advance(t1, y_.get(), &t_reached);
    if (interrupt != nullptr) {
      const long taken = steps_taken() - before;
      interrupt->steps += taken;
      // Too much work (CV_TOO_MUCH_WORK, ARK_TOO_MUCH_WORK: -1) when the budget
      // set the bound is the budget's to report.
      if (flag == -1 && budget_binds && callbacks_.rhs_failure.is_ok()) {
        return interrupt->exhausted_status(interval_binds ? taken : interrupt->steps);
      }
    }
    if (flag < 0) return solve_failure(flag, t_reached);

    const double* result = N_VGetArrayPointer(y_.get());
    std::copy(result, result + y.size(), y.begin());
    return check_integration_result(name_, t1, y);
  }

 protected:
  SundialsIntegrator(const IntegratorSettings& settings, const char* name, FlagNameFn get_flag_name)
      : settings_(settings), settings_status_(validate(settings)), name_(name), get_flag_name_(get_flag_name) {}

  // Builds the solver for the current y_ (its size is new) and initialises it at t0.
  virtual Status create_solver(SUNContext context, N_Vector y, double t0) = 0;
  // Frees what create_solver built (also after a partial build).
  virtual void destroy_solver() = 0;
  // Restarts the solver built for this size at (t0, y): no allocation.
  virtual int reinitialize(double t0, N_Vector y) = 0;
  // Integrates to exactly t1 (a stop time, no overshoot); returns a SUNDIALS flag.
  virtual int advance(double t1, N_Vector y, double* t_reached) = 0;
  // The most internal steps of one advance(); the internal steps since the last (re-)initialisation.
  virtual int set_max_steps(long max_steps) = 0;
  virtual long steps_taken() = 0;

  CallbackState& callbacks() { return callbacks_; }
  const IntegratorSettings& settings() const { return settings_; }

  // Setup calls are not expected to fail once the settings are valid.
  Status check_setup(int flag, const char* call) const {
    if (flag >= 0) return Status::ok();
    std::string message = std::string(name_) + ": " + call + " failed (flag " + std::to_string(flag) + ")";
    if (!callbacks_.solver_message.empty()) message += ": " + callbacks_.solver_message;
    return internal_error(std::move(message));
  }

 private:
  // Makes the solver ready to start at (t0, y): re-initialises it when it was
  // built for this size, otherwise (first call, or a new size) builds it.
  Status prepare(double t0, std::span<const double> y) {
    if (!context_) {
      SUNContext context = nullptr;
      if (SUNContext_Create(nullptr, &context) != 0 || context == nullptr) {
        return internal_error(std::string(name_) + ": could not create a SUNDIALS context");
      }
      context_.reset(context);
    }
    const auto n = static_cast<sunindextype>(y.size());
    if (n != size_) {
      // The solver is freed before the vector it was built from.
      destroy_solver();
      solver_ready_ = false;
      size_ = 0;
      y_.reset(N_VNew_Serial(n, context_.get()));
      if (!y_) return internal_error(std::string(name_) + ": could not allocate a state vector of size " + std::to_string(n));
      size_ = n;
    }
    std::copy(y.begin(), y.end(), N_VGetArrayPointer(y_.get()));

    if (solver_ready_) return check_setup(reinitialize(t0, y_.get()), "re-initialisation");
    max_steps_set_ = settings_.max_steps;  // what create_solver sets
    Status built = create_solver(context_.get(), y_.get(), t0);
    if (!built.is_ok()) {
      destroy_solver();  // a half-built solver is never reused
      return built;
    }
    solver_ready_ = true;
    return Status::ok();
  }

  Status solve_failure(int flag, double t_reached) const {
    const std::string where =
        std::string(name_) + " failed at t = " + message_number(t_reached, 9) + " (" + flag_name(get_flag_name_, flag) + ")";
    // The model's own error explains the failure better than the solver's flag.
    if (!callbacks_.rhs_failure.is_ok()) return callbacks_.rhs_failure.with_context(where);
    if (callbacks_.solver_message.empty()) return failed_precondition(where);
    return failed_precondition(where + ": " + callbacks_.solver_message);
  }

  IntegratorSettings settings_;
  Status settings_status_;  // make_cvode/arkode_integrator may be called without make_integrator's check
  const char* name_;
  FlagNameFn get_flag_name_;

  // The context precedes every other handle so that it is destroyed last;
  // the subclass's handles, created in it too, are destroyed before all of these.
  ContextPtr context_;
  VectorPtr y_;
  sunindextype size_ = 0;
  bool solver_ready_ = false;
  long max_steps_set_ = 0;  // the solver's bound on steps per advance() now
  CallbackState callbacks_;
};

class CvodeIntegrator final : public SundialsIntegrator {
 public:
  explicit CvodeIntegrator(const IntegratorSettings& settings)
      : SundialsIntegrator(settings, integrator_kind_name(kind_of(settings)), CVodeGetReturnFlagName),
        uses_adams_(settings.kind == IntegratorKind::kCvodeAdams) {}

 private:
  // Anything but Adams means BDF, so a stray kind cannot pick an unbuilt solver.
  static IntegratorKind kind_of(const IntegratorSettings& settings) {
    return settings.kind == IntegratorKind::kCvodeAdams ? IntegratorKind::kCvodeAdams : IntegratorKind::kCvodeBdf;
  }

  Status create_solver(SUNContext context, N_Vector y, double t0) override {
    memory_.reset(CVodeCreate(uses_adams_ ? CV_ADAMS : CV_BDF, context));
    if (!memory_) return internal_error("CVodeCreate failed");
    void* cvode = memory_.get();
    RICCATI_RETURN_IF_ERROR(check_setup(CVodeSetErrHandlerFn(cvode, store_error_message, &callbacks()),
                                        "CVodeSetErrHandlerFn"));
    RICCATI_RETURN_IF_ERROR(check_setup(CVodeInit(cvode, rhs_trampoline, t0, y), "CVodeInit"));
    RICCATI_RETURN_IF_ERROR(check_setup(CVodeSetUserData(cvode, &callbacks()), "CVodeSetUserData"));
    RICCATI_RETURN_IF_ERROR(
        check_setup(CVodeSStolerances(cvode, settings().rtol, settings().atol), "CVodeSStolerances"));
    RICCATI_RETURN_IF_ERROR(check_setup(CVodeSetMaxNumSteps(cvode, settings().max_steps), "CVodeSetMaxNumSteps"));

    if (uses_adams_) {
      // Adams targets non-stiff models, where fixed-point iteration converges
      // and needs no Jacobian.
      fixed_point_.reset(SUNNonlinSol_FixedPoint(y, 0, context));
      if (!fixed_point_) return internal_error("SUNNonlinSol_FixedPoint failed");
      return check_setup(CVodeSetNonlinearSolver(cvode, fixed_point_.get()), "CVodeSetNonlinearSolver");
    }
    // BDF with Newton iteration; no Jacobian function is set, so CVODE uses
    // its difference-quotient approximation.
    const sunindextype n = N_VGetLength(y);
    jacobian_.reset(SUNDenseMatrix(n, n, context));
    if (!jacobian_) return internal_error("SUNDenseMatrix failed");
    linear_solver_.reset(SUNLinSol_Dense(y, jacobian_.get(), context));
    if (!linear_solver_) return internal_error("SUNLinSol_Dense failed");
    return check_setup(CVodeSetLinearSolver(cvode, linear_solver_.get(), jacobian_.get()), "CVodeSetLinearSolver");
  }

  void destroy_solver() override {
    memory_.reset();  // first: it refers to the solvers and the matrix
    fixed_point_.reset();
    linear_solver_.reset();
    jacobian_.reset();
  }

  // CVodeReInit keeps the tolerances, limits and solvers attached to memory_.
  int reinitialize(double t0, N_Vector y) override { return CVodeReInit(memory_.get(), t0, y); }

  int advance(double t1, N_Vector y, double* t_reached) override {
    const int flag = CVodeSetStopTime(memory_.get(), t1);
    if (flag < 0) return flag;
    return CVode(memory_.get(), t1, y, t_reached, CV_NORMAL);
  }

  int set_max_steps(long max_steps) override { return CVodeSetMaxNumSteps(memory_.get(), max_steps); }
  long steps_taken() override {
    long steps = 0;
    return CVodeGetNumSteps(memory_.get(), &steps) == CV_SUCCESS ? steps : 0;
  }

  bool uses_adams_;
  // In dependency order: memory_ refers to the others, so it is destroyed first.
  MatrixPtr jacobian_;
  LinearSolverPtr linear_solver_;
  NonlinearSolverPtr fixed_point_;
  CvodeMemoryPtr memory_;
};

class ErkStepIntegrator final : public SundialsIntegrator {
 public:
  explicit ErkStepIntegrator(const IntegratorSettings& settings)
      : SundialsIntegrator(settings, integrator_kind_name(IntegratorKind::kArkodeErk), ERKStepGetReturnFlagName) {}

 private:
  Status create_solver(SUNContext context, N_Vector y, double t0) override {
    memory_.reset(ERKStepCreate(rhs_trampoline, t0, y, context));
    if (!memory_) return internal_error("ERKStepCreate failed");
    void* erk = memory_.get();
    RICCATI_RETURN_IF_ERROR(check_setup(ERKStepSetErrHandlerFn(erk, store_error_message, &callbacks()),
                                        "ERKStepSetErrHandlerFn"));
    RICCATI_RETURN_IF_ERROR(check_setup(ERKStepSetUserData(erk, &callbacks()), "ERKStepSetUserData"));
    RICCATI_RETURN_IF_ERROR(
        check_setup(ERKStepSStolerances(erk, settings().rtol, settings().atol), "ERKStepSStolerances"));
    return check_setup(ERKStepSetMaxNumSteps(erk, settings().max_steps), "ERKStepSetMaxNumSteps");
  }

  void destroy_solver() override { memory_.reset(); }

  // ERKStepReInit keeps the options set on memory_ (tolerances, limits, handlers).
  int reinitialize(double t0, N_Vector y) override { return ERKStepReInit(memory_.get(), rhs_trampoline, t0, y); }

  int advance(double t1, N_Vector y, double* t_reached) override {
    const int flag = ERKStepSetStopTime(memory_.get(), t1);
    if (flag < 0) return flag;
    return ERKStepEvolve(memory_.get(), t1, y, t_reached, ARK_NORMAL);
  }

  int set_max_steps(long max_steps) override { return ERKStepSetMaxNumSteps(memory_.get(), max_steps); }
  long steps_taken() override {
    long steps = 0;
    return ERKStepGetNumSteps(memory_.get(), &steps) == ARK_SUCCESS ? steps : 0;
  }

  ErkStepMemoryPtr memory_;
};

}  // namespace

std::unique_ptr<Integrator> make_cvode_integrator(const IntegratorSettings& settings) {
  return std::make_unique<CvodeIntegrator>(settings);
}

std::unique_ptr<Integrator> make_arkode_integrator(const IntegratorSettings& settings) {
  return std::make_unique<ErkStepIntegrator>(settings);
}

}  // namespace riccati
