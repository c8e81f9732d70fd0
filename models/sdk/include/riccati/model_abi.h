/*
 * riccati model plugin ABI, version 1 (plain C; stable across compilers).
 *
 * A model plugin is a shared library exporting one function,
 *
 *     const riccati_model_v1* riccati_model_entry(uint32_t host_abi_version);
 *
 * which returns a table that lives as long as the library stays loaded. The
 * table describes the model
 *
 *     x' = f(x, theta, u, t)      states x [nx], parameters theta [ntheta],
 *     y  = g(x, theta, u, t)      inputs u [nu], outputs y [ny]
 *
 * and gives function pointers to evaluate f and g. Most authors never write
 * this table by hand: model.hpp builds it from a templated C++ model and adds
 * exact Jacobians by automatic differentiation.
 *
 * Rules of the boundary
 *  - No C++ type and no exception crosses it. Every function returns 0 on
 *    success or non-zero on failure, with a NUL-terminated message written into
 *    `err` (at most `err_len` bytes, truncated if longer).
 *  - Functions are reentrant: the host calls them from several threads at once.
 *  - Batched evaluation: f and g evaluate `n` points in one call so a plugin
 *    can vectorise across points (the UKF's sigma points). Point arrays are
 *    stored variable-major ("structure of arrays"): value i of point p is
 *    at `a[i * ld + p]`, with ld >= n. x, theta and the result share one ld.
 *    u and t are the same for all points of a call.
 *  - Jacobians are with respect to the augmented state [x; theta], stored
 *    column-major: d out_i / d z_j at `jac[i + j * rows]`, z = [x; theta].
 *    They are optional (NULL): the host falls back to central finite
 *    differences.
 *  - The host checks results for NaN and Inf; a plugin need not.
 *  - The table only grows: fields are appended, and a plugin's struct_size
 *    says which it has. The host reads an appended field only when the
 *    plugin's struct_size covers it, so older plugins keep loading.
 */
#ifndef RICCATI_MODEL_ABI_H_
#define RICCATI_MODEL_ABI_H_

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define RICCATI_MODEL_ABI_VERSION 1u
#define RICCATI_MODEL_ENTRY_SYMBOL "riccati_model_entry"

#if defined(_WIN32)
#define RICCATI_PLUGIN_EXPORT __declspec(dllexport)
#else
#define RICCATI_PLUGIN_EXPORT __attribute__((visibility("default")))
#endif

/* Batched evaluation of f (out: nx values per point) or g (out: ny per point). */
typedef int (*riccati_eval_fn)(uint32_t n, size_t ld, double t, const double* u, const double* x,
                               const double* theta, double* out, char* err, size_t err_len);

/* One point: the value (out, rows values) and the Jacobian with respect to
 * [x; theta] (jac, rows x (nx + ntheta), column-major). */
typedef int (*riccati_jac_fn)(double t, const double* u, const double* x, const double* theta,
                              double* out, double* jac, char* err, size_t err_len);

/* The mechanical (implicit) form of a model, for the optimal filter. With
 * n = ndof degrees of freedom the states are x = [s; v] (n positions, then n
 * velocities: nx = 2 n), a = v' are the accelerations, the inputs u [nu] are
 * the applied forces, and
 *     M(s, theta) a + h(s, v, theta) = H(s, v, theta) u     (n equations of motion)
 *     y = g(s, v, theta, t) + G(s, v, theta, t) a + R(s, v, theta, t) u
 * One point: the stacked rows, so that [0; y] = c + Fc [u; a],
 *     c  = [h; g]            (n + ny)
 *     Fc = [-H  M; R  G]     ((n + ny) x (nu + n), column-major),
 * and their Jacobians with respect to z = [x; theta], column-major:
 * c_jac is (n + ny) x nz, Fc_jac is ((n + ny)(nu + n)) x nz with row k the
 * derivative of Fc's column-major element k. */
/* One point: the value, the Jacobian as riccati_jac_fn gives it, and the
 * second derivatives with respect to [x; theta] (hess, rows x nz x nz):
 * d^2 out_i / d z_a d z_b at hess[i + rows * (a + nz * b)], symmetric in a
 * and b. */
typedef int (*riccati_hess_fn)(double t, const double* u, const double* x, const double* theta, double* out,
                               double* jac, double* hess, char* err, size_t err_len);

typedef int (*riccati_mech_fn)(double t, const double* x, const double* theta, double* c, double* Fc,
                               double* c_jac, double* Fc_jac, char* err, size_t err_len);

/* The same functions with a context: `user_data` of the table comes first.
 * For models whose code needs state of its own (the host's compiled text
 * models; a plugin serving several models from one library). */
typedef int (*riccati_eval_ctx_fn)(void* user_data, uint32_t n, size_t ld, double t, const double* u,
                                   const double* x, const double* theta, double* out, char* err, size_t err_len);
typedef int (*riccati_jac_ctx_fn)(void* user_data, double t, const double* u, const double* x,
                                  const double* theta, double* out, double* jac, char* err, size_t err_len);
typedef int (*riccati_hess_ctx_fn)(void* user_data, double t, const double* u, const double* x,
                                   const double* theta, double* out, double* jac, double* hess, char* err,
                                   size_t err_len);
typedef int (*riccati_mech_ctx_fn)(void* user_data, double t, const double* x, const double* theta, double* c,
                                   double* Fc, double* c_jac, double* Fc_jac, char* err, size_t err_len);

typedef struct riccati_model_v1 {
  uint32_t abi_version; /* RICCATI_MODEL_ABI_VERSION the plugin was built with */
  uint32_t struct_size; /* sizeof(riccati_model_v1) in the plugin: later versions only append */

  const char* name;        /* unique model name, [a-z0-9_]+ */
  const char* version;     /* the model's own version, free text */
  const char* description; /* one line */

  uint32_t nx, ntheta, nu, ny;

  const char* const* state_names;  /* [nx] */
  const char* const* param_names;  /* [ntheta] */
  const char* const* input_names;  /* [nu] (may be NULL when nu == 0) */
  const char* const* output_names; /* [ny] */

  const double* theta_default; /* [ntheta] default (typical) parameter values */
  const double* theta_lower;   /* [ntheta] or NULL: lower bounds, -HUGE_VAL for none */
  const double* theta_upper;   /* [ntheta] or NULL: upper bounds, +HUGE_VAL for none */

  riccati_eval_fn f; /* required */
  riccati_eval_fn g; /* required */
  riccati_jac_fn f_jac; /* optional: f value and d f / d [x; theta] (nx rows) */
  riccati_jac_fn g_jac; /* optional: g value and d g / d [x; theta] (ny rows) */

  /* Appended: the mechanical form (optional; ndof = 0 and mech = NULL for a
   * model without one). f and g above stay required: they are its explicit
   * form, a = M^-1 (H u - h). */
  uint32_t ndof;
  riccati_mech_fn mech;

  /* Appended: functions with a context (optional). When f_ctx and g_ctx are
   * set the host calls the *_ctx functions, with user_data first, and never
   * f, g, f_jac, g_jac or mech (which may then be NULL); f_jac_ctx,
   * g_jac_ctx and mech_ctx are optional as their plain forms are. user_data
   * must stay valid as long as the table. */
  void* user_data;
  riccati_eval_ctx_fn f_ctx;
  riccati_eval_ctx_fn g_ctx;
  riccati_jac_ctx_fn f_jac_ctx;
  riccati_jac_ctx_fn g_jac_ctx;
  riccati_mech_ctx_fn mech_ctx;

  /* Appended: units of the names above, free text such as "m^3/s"
   * (optional): each array NULL, or with an entry per name that is NULL or
   * "" where the name has no unit. Shown by `riccati models show` and the
   * workbench; the host computes nothing with them. */
  const char* const* state_units;  /* [nx] or NULL */
  const char* const* param_units;  /* [ntheta] or NULL */
  const char* const* input_units;  /* [nu] or NULL */
  const char* const* output_units; /* [ny] or NULL */

  /* Appended: exact second derivatives (optional, NULL for none). Maximum
   * likelihood's exact gradient needs them for f and for g; without them it
   * differences the likelihood. The *_ctx forms are used when f_ctx and g_ctx
   * are set, as above. The SDK fills f_hess and g_hess with second-order dual
   * numbers. */
  riccati_hess_fn f_hess;
  riccati_hess_fn g_hess;
  riccati_hess_ctx_fn f_hess_ctx;
  riccati_hess_ctx_fn g_hess_ctx;
} riccati_model_v1;

/* The size of the table before any field was appended: the least a plugin's
 * struct_size may be. */
#define RICCATI_MODEL_V1_BASE_SIZE offsetof(riccati_model_v1, ndof)

/* The one symbol a plugin exports. The host passes its own ABI version; a
 * plugin may return NULL if it cannot serve that version. */
typedef const riccati_model_v1* (*riccati_model_entry_fn)(uint32_t host_abi_version);

#ifdef __cplusplus
} /* extern "C" */
#endif

#endif /* RICCATI_MODEL_ABI_H_ */
