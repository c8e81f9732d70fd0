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
// evaluation, never a crash of the host).
//
// Common mistakes
//  - Calling std::sqrt (or std::sin ...) on a T: it does not accept a Dual.
//    Call the unqualified name after `using namespace riccati::math;`.
//  - Keeping state in the model object: f and g must be const and
//    thread-safe; the host calls them from many threads at once.
//  - Branching on a T: comparisons work (they compare values), but the
//    derivative is that of the branch taken; prefer riccati::sat, min, max.
//  - Inputs u are plain doubles: the Jacobians are with respect to x and
//    theta only.
#pragma once

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstring>
#include <exception>
#include <limits>
#include <type_traits>

#include "riccati/dual.hpp"
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
};

namespace detail {

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

  // Calls model().f or .g (selected by `which_f`) on scalars of type T.
  template <bool which_f, typename T>
  static void call(const T* x, const T* theta, const double* u, double t, T* out) {
    if constexpr (which_f) {
      model().template f<T>(x, theta, u, t, out);
    } else {
      model().template g<T>(x, theta, u, t, out);
    }
  }

  template <bool which_f>
  static int eval(uint32_t n, size_t ld, double t, const double* u, const double* x, const double* theta,
                  double* out, char* err, size_t err_len) {
    constexpr int rows = which_f ? nx : ny;
    return guarded(err, err_len, [&] {
      // One point at a time through local arrays; the loop over points is
      // what a vectorising SDK would widen.
      std::array<double, nx> xp;
      std::array<double, (ntheta > 0 ? ntheta : 1)> tp;
      std::array<double, rows> op;
      for (uint32_t p = 0; p < n; ++p) {
        for (int i = 0; i < nx; ++i) xp[i] = x[i * ld + p];
        for (int j = 0; j < ntheta; ++j) tp[j] = theta[j * ld + p];
        call<which_f, double>(xp.data(), tp.data(), u, t, op.data());
        for (int i = 0; i < rows; ++i) out[i * ld + p] = op[i];
      }
    });
  }

  template <bool which_f>
  static int jac(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                 char* err, size_t err_len) {
    constexpr int rows = which_f ? nx : ny;
    return guarded(err, err_len, [&] {
      // Seeded in place (zero derivatives, then one unit each): building
      // whole Jets as temporaries costs store-forwarding stalls here.
      std::array<Jet, nx> xj{};
      std::array<Jet, (ntheta > 0 ? ntheta : 1)> tj{};
      std::array<Jet, rows> oj;
      for (int i = 0; i < nx; ++i) {
        xj[i].v = x[i];
        xj[i].d[i] = 1.0;
      }
      for (int j = 0; j < ntheta; ++j) {
        tj[j].v = theta[j];
        tj[j].d[nx + j] = 1.0;
      }
      call<which_f, Jet>(xj.data(), tj.data(), u, t, oj.data());
      for (int i = 0; i < rows; ++i) {
        out[i] = oj[i].v;
        for (int j = 0; j < nz; ++j) jac[i + j * rows] = oj[i].d[j];
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
