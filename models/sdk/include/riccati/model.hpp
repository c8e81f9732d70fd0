// riccati model SDK: write a model once, get a plugin with exact Jacobians.
//
// A worked example, the two-tank system of Hensen (1999) sec. 4.1:
//
//     #include <riccati/model.hpp>
//
//     struct TwoTank {
//       static constexpr riccati::ModelSpec<2, 4, 2, 2> spec{
//           .name = "two_tank",
//           .version = "1.0",
//           .description = "Two cascaded tanks, outflow k*sqrt(h)",
//           .states = {"h1", "h2"},
//           .params = {"A1", "A2", "k1", "k2"},
//           .inputs = {"F1", "F2"},
//           .outputs = {"h1", "h2"},
//           .theta_default = {10.0, 5.0, 0.0791, 0.1342},
//           .theta_lower = {0.0, 0.0, 0.0, 0.0},
//           .param_units = {"m^2", "m^2", "m^2.5/s", "m^2.5/s"},  // optional
//       };
//
//       // x' = f(x, theta, u, t): written once, for any scalar type T.
//       template <typename T>
//       void f(const T* x, const T* theta, const double* u, double /*t*/, T* dx) const {
//         using namespace riccati::math;      // sqrt, sin, tanh, sat, ... for T
//         const T q1 = theta[2] * sqrt(x[0]);
//         dx[0] = (u[0] - q1) / theta[0];
//         dx[1] = (u[1] + q1 - theta[3] * sqrt(x[1])) / theta[1];
//       }
//       // y = g(x, theta, u, t)
//       template <typename T>
//       void g(const T* x, const T* /*theta*/, const double* /*u*/, double /*t*/, T* y) const {
//         y[0] = x[0];
//         y[1] = x[1];
//       }
//     };
//     RICCATI_MODEL_PLUGIN(TwoTank)
//
// Build it as a shared library (CMake: riccati_add_model_plugin) and drop it
// into the daemon's models directory.
//
// What the SDK does with it: f and g are evaluated with T = double for values
// and with T = riccati::Dual<nx + ntheta> for the exact Jacobians with respect
// to [x; theta]; the macro emits the C entry point of model_abi.h and catches
// every exception at that boundary (a throw becomes an error message for that
// evaluation, never a crash of the host). When the host asks for many points
// at once (a UKF's sigma points), they are evaluated a few at a time with
// T = riccati::Lanes<W> (lanes.hpp): the same code, vectorised across the
// points, with results equal to the one-point evaluation's to the bit. A
// model whose code cannot take it (it needs a plain double somewhere)
// declares `static constexpr bool vectorize = false;`.
//
// Mechanical models (for the optimal filter, and for every other filter too)
// are written in their implicit form instead: declare the degrees of freedom
// and give the equations of motion and the measurement, M(s) a + h(s, v) =
// H(s, v) u and y = g + G a + R u (each matrix starts at zero: set only what
// is not). The states are the positions, then the velocities.
//
//     struct MassSpringDamper {
//       static constexpr int ndof = 1;
//       static constexpr riccati::ModelSpec<2, 1, 1, 1> spec{
//           .name = "mass_spring_damper",
//           .states = {"s", "v"}, .params = {"k"}, .inputs = {"F"}, .outputs = {"s"},
//           .theta_default = {40.0}};
//       template <typename T>
//       void equations_of_motion(const T* s, const T* v, const T* theta, double /*t*/, auto& eom) const {
//         eom.M(0, 0) = 2.0;                          // mass [kg]
//         eom.h(0) = 0.5 * v[0] + theta[0] * s[0];    // damper and spring forces
//         eom.H(0, 0) = 1.0;                          // F acts on the mass
//       }
//       template <typename T>
//       void measurement(const T* s, const T* /*v*/, const T* /*theta*/, double /*t*/, auto& y) const {
//         y.g(0) = s[0];                              // the position is measured
//       }
//     };
//     RICCATI_MODEL_PLUGIN(MassSpringDamper)
//
// The SDK derives the explicit model from it, x' = [v; a] with a solved from
// M a = H u - h (Gaussian elimination with partial pivoting, never an
// inverse) and y = g + G a + R u, so the EKF and the UKF run on it as on any
// model, and gives the optimal filter the stacked equations and their exact
// Jacobians (model_abi.h, riccati_mech_fn).
//
// Common mistakes
//  - Calling std::sqrt (or std::sin ...) on a T: it does not accept a Dual.
//    Call the unqualified name after `using namespace riccati::math;`.
//  - Keeping state in the model object: f and g must be const and
//    thread-safe; the host calls them from many threads at once.
//  - Branching on a T: comparisons work (they compare values), but the
//    derivative is that of the branch taken; prefer riccati::sat, min, max.
//    (Points of a vectorised group that take different branches are
//    evaluated one at a time instead: correct, a little slower.)
//  - Inputs u are plain doubles: the Jacobians are with respect to x and
//    theta only.
//  - Mechanical models: a mass matrix M that is singular somewhere (a zero
//    inertia parameter) makes f fail there with an error.
#pragma once

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstring>
#include <exception>
#include <stdexcept>
#include <utility>
#include <limits>
#include <type_traits>

#include "riccati/dual.hpp"
#include "riccati/lanes.hpp"
#include "riccati/model_abi.h"

namespace riccati {

namespace detail {
template <std::size_t N>
constexpr std::array<double, N> filled(double v) {
  std::array<double, N> a{};
  for (auto& x : a) x = v;
  return a;
}
}  // namespace detail

// Names, sizes, defaults and bounds of a model. Bounds default to none.
template <int NX, int NTHETA, int NU, int NY>
struct ModelSpec {
  static constexpr int nx = NX;
  static constexpr int ntheta = NTHETA;
  static constexpr int nu = NU;
  static constexpr int ny = NY;

  const char* name = "";
  const char* version = "1.0";
  const char* description = "";
  std::array<const char*, NX> states{};
  std::array<const char*, NTHETA> params{};
  std::array<const char*, NU> inputs{};
  std::array<const char*, NY> outputs{};
  std::array<double, NTHETA> theta_default{};
  std::array<double, NTHETA> theta_lower = detail::filled<NTHETA>(-std::numeric_limits<double>::infinity());
  std::array<double, NTHETA> theta_upper = detail::filled<NTHETA>(std::numeric_limits<double>::infinity());
  // Units, optional (nullptr: none), free text: .param_units = {"m^2", ...}.
  std::array<const char*, NX> state_units{};
  std::array<const char*, NTHETA> param_units{};
  std::array<const char*, NU> input_units{};
  std::array<const char*, NY> output_units{};
};

// The equations of motion M a + h = H u of a mechanical model, at one point,
// as the model writes them: every entry starts at zero.
template <typename T, int N, int NU>
struct EquationsOfMotion {
  std::array<T, N * N> mass{};                       // M, column-major
  std::array<T, N> forces{};                         // h
  std::array<T, (NU > 0 ? N * NU : 1)> input_map{};  // H, column-major

  T& M(int i, int j) { return mass[i + j * N]; }
  T& h(int i) { return forces[i]; }
  T& H(int i, int j) { return input_map[i + j * N]; }
  const T& M(int i, int j) const { return mass[i + j * N]; }
  const T& h(int i) const { return forces[i]; }
  const T& H(int i, int j) const { return input_map[i + j * N]; }
};

// The measurement y = g + G a + R u of a mechanical model, at one point.
template <typename T, int N, int NU, int NY>
struct MeasurementEquation {
  std::array<T, NY> direct{};                           // g
  std::array<T, NY * N> acceleration_map{};             // G, column-major
  std::array<T, (NU > 0 ? NY * NU : 1)> input_map{};    // R, column-major

  T& g(int i) { return direct[i]; }
  T& G(int i, int j) { return acceleration_map[i + j * NY]; }
  T& R(int i, int j) { return input_map[i + j * NY]; }
  const T& g(int i) const { return direct[i]; }
  const T& G(int i, int j) const { return acceleration_map[i + j * NY]; }
  const T& R(int i, int j) const { return input_map[i + j * NY]; }
};

// A model written in the mechanical form (it declares its degrees of freedom).
template <typename M>
concept MechanicalModel = requires { M::ndof; };

namespace detail {

// Gaussian elimination with partial pivoting of M a = b (n x n), the one
// algorithm of the SDK's mechanical models (solve() below) and of the host's
// text models (run-time sizes and dual widths), so that both pivot alike and
// agree to rounding. `s` holds M, b and a and does their arithmetic:
//   s.value(i, k)       the value of M(i, k) (pivots are chosen by value)
//   s.swap(k, p)        rows k and p of M (columns k..n-1) and of b
//   s.eliminate(i, k)   f = M(i, k) / M(k, k); M(i, j) -= f M(k, j) for j > k; b(i) -= f b(k)
//   s.substitute(k)     a(k) = (b(k) - sum_{j > k} M(k, j) a(j)) / M(k, k)
// False when M is singular (a zero pivot).
template <typename System>
bool gaussian_elimination(System& s, int n) {
  using std::abs;
  for (int k = 0; k < n; ++k) {
    int pivot = k;
    for (int i = k + 1; i < n; ++i) {
      if (abs(s.value(i, k)) > abs(s.value(pivot, k))) pivot = i;
    }
    if (s.value(pivot, k) == 0.0) return false;
    if (pivot != k) s.swap(k, pivot);
    for (int i = k + 1; i < n; ++i) {
      if (s.value(i, k) == 0.0) continue;  // nothing to eliminate (M is often sparse)
      s.eliminate(i, k);
    }
  }
  for (int k = n - 1; k >= 0; --k) s.substitute(k);
  return true;
}

// Solves M a = b (N x N, column-major, by value); T may be a dual number.
template <typename T, int N>
std::array<T, N> solve(std::array<T, N * N> M, std::array<T, N> b) {
  struct System {
    std::array<T, N * N>& M;
    std::array<T, N>& b;
    std::array<T, N> a;
    double value(int i, int k) const { return value_of(M[i + k * N]); }
    void swap(int k, int p) {
      for (int j = k; j < N; ++j) std::swap(M[k + j * N], M[p + j * N]);
      std::swap(b[k], b[p]);
    }
    void eliminate(int i, int k) {
      const T factor = M[i + k * N] / M[k + k * N];
      for (int j = k + 1; j < N; ++j) M[i + j * N] -= factor * M[k + j * N];
      b[i] -= factor * b[k];
    }
    void substitute(int k) {
      T sum = b[k];
      for (int j = k + 1; j < N; ++j) sum -= M[k + j * N] * a[j];
      a[k] = sum / M[k + k * N];
    }
  } system{M, b, {}};
  if (!gaussian_elimination(system, N)) throw std::domain_error("the mass matrix M is singular");
  return system.a;
}

inline void write_error(char* err, size_t err_len, const char* what) {
  if (err != nullptr && err_len > 0) std::snprintf(err, err_len, "%s", what);
}

// Runs `body`, turning any exception into an error code and message.
template <typename Body>
int guarded(char* err, size_t err_len, Body&& body) noexcept {
  try {
    body();
    return 0;
  } catch (const std::exception& e) {
    write_error(err, err_len, e.what());
  } catch (...) {
    write_error(err, err_len, "unknown exception in model");
  }
  return 1;
}

// Builds the C table for model M and implements its entry points.
template <typename M>
struct Plugin {
  static constexpr auto& spec = M::spec;
  static constexpr int nx = std::remove_cvref_t<decltype(spec)>::nx;
  static constexpr int ntheta = std::remove_cvref_t<decltype(spec)>::ntheta;
  static constexpr int nu = std::remove_cvref_t<decltype(spec)>::nu;
  static constexpr int ny = std::remove_cvref_t<decltype(spec)>::ny;
  static constexpr int nz = nx + ntheta;  // augmented state [x; theta]
  using Jet = Dual<nz>;

  static const M& model() {
    static const M instance{};
    return instance;
  }

  // Mechanical models: the equations of motion and the measurement at a point.
  static constexpr int ndof = [] {
    if constexpr (MechanicalModel<M>) return M::ndof;
    return 0;
  }();
  template <typename T>
  using Eom = EquationsOfMotion<T, (ndof > 0 ? ndof : 1), nu>;
  template <typename T>
  using Measurement = MeasurementEquation<T, (ndof > 0 ? ndof : 1), nu, ny>;
  static_assert(ndof == 0 || nx == 2 * ndof, "a mechanical model has nx = 2 ndof states: positions, then velocities");

  // The accelerations a from M a = H u - h.
  template <typename T>
  static std::array<T, (ndof > 0 ? ndof : 1)> accelerations(const Eom<T>& eom, const double* u) {
    std::array<T, (ndof > 0 ? ndof : 1)> rhs;
    for (int i = 0; i < ndof; ++i) {
      T sum = -eom.h(i);
      for (int j = 0; j < nu; ++j) sum += eom.H(i, j) * u[j];
      rhs[i] = sum;
    }
    return solve<T, (ndof > 0 ? ndof : 1)>(eom.mass, rhs);
  }

  // Calls model().f or .g (selected by `which_f`) on scalars of type T; for
  // a mechanical model, its explicit form.
  template <bool which_f, typename T>
  static void call(const T* x, const T* theta, const double* u, double t, T* out) {
    if constexpr (MechanicalModel<M>) {
      Eom<T> eom;
      model().template equations_of_motion<T>(x, x + ndof, theta, t, eom);
      const auto a = accelerations(eom, u);
      if constexpr (which_f) {
        for (int i = 0; i < ndof; ++i) {
          out[i] = x[ndof + i];
          out[ndof + i] = a[i];
        }
      } else {
        Measurement<T> y;
        model().template measurement<T>(x, x + ndof, theta, t, y);
        for (int i = 0; i < ny; ++i) {
          T sum = y.g(i);
          for (int j = 0; j < ndof; ++j) sum += y.G(i, j) * a[j];
          for (int j = 0; j < nu; ++j) sum += y.R(i, j) * u[j];
          out[i] = sum;
        }
      }
    } else if constexpr (which_f) {
      model().template f<T>(x, theta, u, t, out);
    } else {
      model().template g<T>(x, theta, u, t, out);
    }
  }

  // The stacked rows of the mechanical form and their Jacobians (model_abi.h).
  static int mech(double t, const double* x, const double* theta, double* c, double* Fc, double* c_jac,
                  double* Fc_jac, char* err, size_t err_len) {
    return guarded(err, err_len, [&] {
      if constexpr (MechanicalModel<M>) {
        constexpr int rows = ndof + ny, cols = nu + ndof, entries = rows * cols;
        std::array<Jet, nx> xj{};
        std::array<Jet, (ntheta > 0 ? ntheta : 1)> tj{};
        seed(x, theta, xj.data(), tj.data());
        Eom<Jet> eom;
        Measurement<Jet> y;
        model().template equations_of_motion<Jet>(xj.data(), xj.data() + ndof, tj.data(), t, eom);
        model().template measurement<Jet>(xj.data(), xj.data() + ndof, tj.data(), t, y);
        auto put = [&](double* value, double* jac, int k, int stride, const Jet& e, double sign) {
          value[k] = sign * e.v;
          for (int j = 0; j < nz; ++j) jac[k + j * stride] = sign * e.d[j];
        };
        for (int i = 0; i < ndof; ++i) put(c, c_jac, i, rows, eom.h(i), 1.0);
        for (int i = 0; i < ny; ++i) put(c, c_jac, ndof + i, rows, y.g(i), 1.0);
        for (int j = 0; j < nu; ++j) {  // the columns of u: -H over R
          for (int i = 0; i < ndof; ++i) put(Fc, Fc_jac, i + j * rows, entries, eom.H(i, j), -1.0);
          for (int i = 0; i < ny; ++i) put(Fc, Fc_jac, ndof + i + j * rows, entries, y.R(i, j), 1.0);
        }
        for (int j = 0; j < ndof; ++j) {  // the columns of a: M over G
          const int col = nu + j;
          for (int i = 0; i < ndof; ++i) put(Fc, Fc_jac, i + col * rows, entries, eom.M(i, j), 1.0);
          for (int i = 0; i < ny; ++i) put(Fc, Fc_jac, ndof + i + col * rows, entries, y.G(i, j), 1.0);
        }
      }
    });
  }

  // A batch of at least kLanes points is evaluated kLanes at a time with T =
  // Lanes<kLanes> (lanes.hpp), which vectorises across them; fewer points,
  // and a chunk whose points take different branches, one at a time with
  // T = double.
  // Mechanical models solve for the accelerations with pivoting chosen by
  // value, where the lanes would rarely agree: they go one point at a time,
  // as does a model that declares `static constexpr bool vectorize = false;`
  // (one whose code needs a plain double, for instance).
  static constexpr uint32_t kLanes = 2;  // what SSE2 holds; measured faster than 4 here
  static constexpr bool vectorized = [] {
    if constexpr (MechanicalModel<M>) return false;
    else if constexpr (requires { M::vectorize; }) return bool(M::vectorize);
    return true;
  }();

  template <bool which_f>
  static void eval_points(uint32_t first, uint32_t end, size_t ld, double t, const double* u, const double* x,
                          const double* theta, double* out) {
    constexpr int rows = which_f ? nx : ny;
    std::array<double, nx> xp;
    std::array<double, (ntheta > 0 ? ntheta : 1)> tp;
    std::array<double, rows> op;
    for (uint32_t p = first; p < end; ++p) {
      for (int i = 0; i < nx; ++i) xp[i] = x[i * ld + p];
      for (int j = 0; j < ntheta; ++j) tp[j] = theta[j * ld + p];
      call<which_f, double>(xp.data(), tp.data(), u, t, op.data());
      for (int i = 0; i < rows; ++i) out[i * ld + p] = op[i];
    }
  }

  template <bool which_f>
  static int eval(uint32_t n, size_t ld, double t, const double* u, const double* x, const double* theta,
                  double* out, char* err, size_t err_len) {
    return guarded(err, err_len, [&] {
      if constexpr (vectorized) {
        if (n >= kLanes) {
          // Chunks of kLanes points; the last chunk ends at n and may overlap
          // the one before (its points get the same values again).
          for (uint32_t p = 0; p < n; p += kLanes) eval_lanes<which_f>(std::min(p, n - kLanes), ld, t, u, x, theta, out);
          return;
        }
      }
      eval_points<which_f>(0, n, ld, t, u, x, theta, out);
    });
  }

  // Points first .. first + kLanes - 1 together.
  template <bool which_f>
  static void eval_lanes(uint32_t first, size_t ld, double t, const double* u, const double* x, const double* theta,
                         double* out) {
    using L = Lanes<kLanes>;
    constexpr int rows = which_f ? nx : ny;
    std::array<L, nx> xl;
    std::array<L, (ntheta > 0 ? ntheta : 1)> tl;
    std::array<L, rows> ol;
    for (int i = 0; i < nx; ++i) {
      for (uint32_t l = 0; l < kLanes; ++l) xl[i].v[l] = x[i * ld + first + l];
    }
    for (int j = 0; j < ntheta; ++j) {
      for (uint32_t l = 0; l < kLanes; ++l) tl[j].v[l] = theta[j * ld + first + l];
    }
    try {
      call<which_f, L>(xl.data(), tl.data(), u, t, ol.data());
    } catch (...) {
      // Diverging branches, or an error that the points will report one by one.
      eval_points<which_f>(first, first + kLanes, ld, t, u, x, theta, out);
      return;
    }
    for (int i = 0; i < rows; ++i) {
      for (uint32_t l = 0; l < kLanes; ++l) out[i * ld + first + l] = ol[i].v[l];
    }
  }

  // Seeds zeroed Jets with the values of [x; theta] and unit derivatives, in
  // place: building whole Jets as temporaries costs store-forwarding stalls.
  static void seed(const double* x, const double* theta, Jet* xj, Jet* tj) {
    for (int i = 0; i < nx; ++i) {
      xj[i].v = x[i];
      xj[i].d[i] = 1.0;
    }
    for (int j = 0; j < ntheta; ++j) {
      tj[j].v = theta[j];
      tj[j].d[nx + j] = 1.0;
    }
  }

  template <bool which_f>
  static int jac(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                 char* err, size_t err_len) {
    constexpr int rows = which_f ? nx : ny;
    return guarded(err, err_len, [&] {
      std::array<Jet, nx> xj{};
      std::array<Jet, (ntheta > 0 ? ntheta : 1)> tj{};
      std::array<Jet, rows> oj;
      seed(x, theta, xj.data(), tj.data());
      call<which_f, Jet>(xj.data(), tj.data(), u, t, oj.data());
      for (int i = 0; i < rows; ++i) {
        out[i] = oj[i].v;
        for (int j = 0; j < nz; ++j) jac[i + j * rows] = oj[i].d[j];
      }
    });
  }

  // Value, Jacobian and second derivatives (model_abi.h, riccati_hess_fn)
  // with second-order dual numbers.
  template <bool which_f>
  static int hess(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                  double* hessian, char* err, size_t err_len) {
    constexpr int rows = which_f ? nx : ny;
    using Jet2 = Dual2<nz>;
    return guarded(err, err_len, [&] {
      std::array<Jet2, nx> xj{};
      std::array<Jet2, (ntheta > 0 ? ntheta : 1)> tj{};
      std::array<Jet2, rows> oj;
      for (int i = 0; i < nx; ++i) xj[i] = Jet2::variable(x[i], i);
      for (int j = 0; j < ntheta; ++j) tj[j] = Jet2::variable(theta[j], nx + j);
      call<which_f, Jet2>(xj.data(), tj.data(), u, t, oj.data());
      for (int i = 0; i < rows; ++i) {
        out[i] = oj[i].v;
        for (int j = 0; j < nz; ++j) jac[i + j * rows] = oj[i].d[j];
        for (int b = 0, k = 0; b < nz; ++b) {  // the packed lower triangle, mirrored
          for (int a = b; a < nz; ++a, ++k) {
            hessian[i + rows * (a + nz * b)] = hessian[i + rows * (b + nz * a)] = oj[i].h[k];
          }
        }
      }
    });
  }

  static const riccati_model_v1* table() {
    static const riccati_model_v1 t = {
        RICCATI_MODEL_ABI_VERSION,
        static_cast<uint32_t>(sizeof(riccati_model_v1)),
        spec.name,
        spec.version,
        spec.description,
        static_cast<uint32_t>(nx),
        static_cast<uint32_t>(ntheta),
        static_cast<uint32_t>(nu),
        static_cast<uint32_t>(ny),
        spec.states.data(),
        spec.params.data(),
        nu > 0 ? spec.inputs.data() : nullptr,
        spec.outputs.data(),
        spec.theta_default.data(),
        spec.theta_lower.data(),
        spec.theta_upper.data(),
        &eval<true>,
        &eval<false>,
        &jac<true>,
        &jac<false>,
        static_cast<uint32_t>(ndof),
        ndof > 0 ? &mech : nullptr,
        nullptr,  // user_data and the *_ctx functions: a plugin of the SDK needs no context
        nullptr,
        nullptr,
        nullptr,
        nullptr,
        nullptr,
        spec.state_units.data(),
        ntheta > 0 ? spec.param_units.data() : nullptr,
        nu > 0 ? spec.input_units.data() : nullptr,
        spec.output_units.data(),
        &hess<true>,
        &hess<false>,
        nullptr,  // the *_ctx forms: a plugin of the SDK needs no context
        nullptr,
    };
    return &t;
  }

  static const riccati_model_v1* entry(uint32_t host_abi_version) {
    return host_abi_version == RICCATI_MODEL_ABI_VERSION ? table() : nullptr;
  }
};

}  // namespace detail
}  // namespace riccati

// Emits the plugin's C entry point for the model type `Model`. Use once per
// shared library, at namespace scope.
#define RICCATI_MODEL_PLUGIN(Model)                                                           \
  extern "C" RICCATI_PLUGIN_EXPORT const riccati_model_v1* riccati_model_entry(uint32_t host) { \
    return ::riccati::detail::Plugin<Model>::entry(host);                                     \
  }
