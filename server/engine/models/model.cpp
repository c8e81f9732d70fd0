#include "engine/models/model.hpp"

#include <array>
#include <bit>
#include <cstdint>
#include <cstddef>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "engine/scalar_loops.hpp"

namespace riccati {

namespace {

constexpr std::size_t kErrorBufferSize = 512;

// Copies `count` names from a plugin's table, refusing NULL entries.
Status read_names(const char* const* names, uint32_t count, const char* what, std::vector<std::string>* out) {
  out->clear();
  if (count == 0) return Status::ok();
  if (names == nullptr) return invalid_argument(std::string(what) + " names are missing (NULL)");
  for (uint32_t i = 0; i < count; ++i) {
    if (names[i] == nullptr || names[i][0] == '\0') {
      return invalid_argument(std::string(what) + " name " + std::to_string(i) + " is empty");
    }
    out->emplace_back(names[i]);
  }
  for (std::size_t i = 0; i < out->size(); ++i) {
    for (std::size_t j = i + 1; j < out->size(); ++j) {
      if ((*out)[i] == (*out)[j]) return invalid_argument(std::string(what) + " name \"" + (*out)[i] + "\" is repeated");
    }
  }
  return Status::ok();
}

bool valid_model_name(const char* name) {
  if (name == nullptr || name[0] == '\0') return false;
  for (const char* c = name; *c != '\0'; ++c) {
    const bool ok = (*c >= 'a' && *c <= 'z') || (*c >= '0' && *c <= '9') || *c == '_';
    if (!ok) return false;
  }
  return true;
}

// Copies `count` units from a plugin's table: NULL (the table has none, or
// is older than its units) and NULL entries are "".
std::vector<std::string> read_units(const char* const* units, uint32_t count) {
  std::vector<std::string> out(count);
  if (units == nullptr) return out;
  for (uint32_t i = 0; i < count; ++i) {
    if (units[i] != nullptr) out[i] = units[i];
  }
  return out;
}

int index_of(const std::vector<std::string>& names, std::string_view n) {
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (names[i] == n) return static_cast<int>(i);
  }
  return -1;
}

// True if no value is NaN or infinite, without a branch per value: a
// double is NaN or infinite when its exponent bits are all ones, and adding
// 1 to the exponent field then carries into bit 63. This runs on every
// model evaluation.
inline std::uint64_t carry_of_non_finite(double v) {
  constexpr std::uint64_t kExponent = 0x7ff0000000000000ULL, kOne = 0x0010000000000000ULL;
  return (std::bit_cast<std::uint64_t>(v) & kExponent) + kOne;
}

// For values stored packed (f and g at a batch of points, a structure of
// arrays): integer adds and ors, which SSE2 vectorises.
bool all_finite(const double* v, std::size_t n) {
  std::uint64_t carried = 0;
  for (std::size_t i = 0; i < n; ++i) carried |= carry_of_non_finite(v[i]);
  return (carried >> 63) == 0;
}

// For values the plugin has just stored one by one (a Jacobian): one
// scalar load each, on purpose. Loaded in pairs, as the vectorised loop
// does, each pair waits for its two stores to complete (a store-forwarding
// stall), which costs more than the tests: 27 -> 23-25 ns per two-tank
// Jacobian call.
__attribute__((noinline)) RICCATI_SCALAR_LOOPS bool all_finite_stored_singly(const double* v, std::size_t n) {
  std::uint64_t carried = 0;
  for (std::size_t i = 0; i < n; ++i) carried |= carry_of_non_finite(v[i]);
  return (carried >> 63) == 0;
}

// Scratch space for finite differences, per thread so that concurrent
// sessions never share it and no evaluation allocates after the first.
struct FdScratch {
  std::vector<double> x, theta, plus, minus;
};
thread_local FdScratch fd_scratch;

}  // namespace

Result<ModelPtr> Model::create(const riccati_model_v1* t, std::shared_ptr<void> library, std::string origin) {
  auto fail = [&](const std::string& why) -> Status {
    return invalid_argument("plugin " + origin + " refused: " + why);
  };
  if (t == nullptr) return fail("its entry point returned no model table (NULL)");
  if (t->abi_version != RICCATI_MODEL_ABI_VERSION) {
    return fail("ABI version " + std::to_string(t->abi_version) + ", this host speaks version " +
                std::to_string(RICCATI_MODEL_ABI_VERSION) + "; rebuild it against this riccati's model_abi.h");
  }
  if (t->struct_size < RICCATI_MODEL_V1_BASE_SIZE) {
    return fail("model table is " + std::to_string(t->struct_size) + " bytes, expected at least " +
                std::to_string(RICCATI_MODEL_V1_BASE_SIZE));
  }
  if (!valid_model_name(t->name)) return fail("model name must be non-empty and use only [a-z0-9_]");
  constexpr uint32_t kMaxSize = 4096;  // far above any real model; stops absurd tables early
  if (t->nx == 0 || t->nx > kMaxSize) return fail("model " + std::string(t->name) + " has nx = " + std::to_string(t->nx));
  if (t->ny == 0 || t->ny > kMaxSize) return fail("model " + std::string(t->name) + " has ny = " + std::to_string(t->ny));
  if (t->ntheta > kMaxSize || t->nu > kMaxSize) return fail("model " + std::string(t->name) + " sizes are too large");
  // Appended fields exist only as far as the plugin's table reaches.
  const bool has_mech_fields = t->struct_size >= offsetof(riccati_model_v1, mech) + sizeof(t->mech);
  const bool has_ctx_fields = t->struct_size >= offsetof(riccati_model_v1, mech_ctx) + sizeof(t->mech_ctx);
  const bool with_context = has_ctx_fields && (t->f_ctx != nullptr || t->g_ctx != nullptr);
  if (with_context ? (t->f_ctx == nullptr || t->g_ctx == nullptr) : (t->f == nullptr || t->g == nullptr)) {
    return fail("model " + std::string(t->name) + " does not provide f and g");
  }
  const uint32_t ndof = has_mech_fields ? t->ndof : 0;
  const bool has_mech = with_context ? t->mech_ctx != nullptr : t->mech != nullptr;
  if (ndof > 0 && (!has_mech || 2 * ndof != t->nx)) {
    return fail("model " + std::string(t->name) + " declares " + std::to_string(ndof) +
                " degrees of freedom: it needs nx = 2 ndof states [s; v] (it has " + std::to_string(t->nx) +
                ") and a mech function");
  }

  std::shared_ptr<Model> m(new Model());
  m->table_ = t;
  m->library_ = std::move(library);
  m->origin_ = origin;
  m->name_ = t->name;
  m->version_ = t->version != nullptr ? t->version : "";
  m->description_ = t->description != nullptr ? t->description : "";
  m->nx_ = static_cast<int>(t->nx);
  m->ntheta_ = static_cast<int>(t->ntheta);
  m->nu_ = static_cast<int>(t->nu);
  m->ny_ = static_cast<int>(t->ny);
  m->ndof_ = static_cast<int>(ndof);
  m->with_context_ = with_context;
  m->mech_ = ndof > 0 && !with_context ? t->mech : nullptr;
  m->mech_ctx_ = ndof > 0 && with_context ? t->mech_ctx : nullptr;
  if (t->struct_size >= offsetof(riccati_model_v1, g_hess_ctx) + sizeof(t->g_hess_ctx)) {
    m->f_hess_ = t->f_hess;
    m->g_hess_ = t->g_hess;
    m->f_hess_ctx_ = t->f_hess_ctx;
    m->g_hess_ctx_ = t->g_hess_ctx;
  }

  const std::string who = "model " + m->name_ + ": ";
  Status s = read_names(t->state_names, t->nx, "state", &m->state_names_);
  if (s.is_ok()) s = read_names(t->param_names, t->ntheta, "parameter", &m->param_names_);
  if (s.is_ok()) s = read_names(t->input_names, t->nu, "input", &m->input_names_);
  if (s.is_ok()) s = read_names(t->output_names, t->ny, "output", &m->output_names_);
  if (!s.is_ok()) return fail(who + s.message());
  const bool has_unit_fields = t->struct_size >= offsetof(riccati_model_v1, output_units) + sizeof(t->output_units);
  m->state_units_ = read_units(has_unit_fields ? t->state_units : nullptr, t->nx);
  m->param_units_ = read_units(has_unit_fields ? t->param_units : nullptr, t->ntheta);
  m->input_units_ = read_units(has_unit_fields ? t->input_units : nullptr, t->nu);
  m->output_units_ = read_units(has_unit_fields ? t->output_units : nullptr, t->ny);

  const Eigen::Index nth = m->ntheta_;
  m->theta_default_ = Eigen::VectorXd::Zero(nth);
  m->theta_lower_ = Eigen::VectorXd::Constant(nth, -std::numeric_limits<double>::infinity());
  m->theta_upper_ = Eigen::VectorXd::Constant(nth, std::numeric_limits<double>::infinity());
  if (nth > 0) {
    if (t->theta_default == nullptr) return fail(who + "parameter defaults are missing (NULL)");
    for (Eigen::Index j = 0; j < nth; ++j) {
      m->theta_default_[j] = t->theta_default[j];
      if (t->theta_lower != nullptr) m->theta_lower_[j] = t->theta_lower[j];
      if (t->theta_upper != nullptr) m->theta_upper_[j] = t->theta_upper[j];
      const std::string& pn = m->param_names_[j];
      if (!std::isfinite(m->theta_default_[j])) return fail(who + "default of parameter " + pn + " is not finite");
      if (std::isnan(m->theta_lower_[j]) || std::isnan(m->theta_upper_[j]) || m->theta_lower_[j] > m->theta_upper_[j]) {
        return fail(who + "bounds of parameter " + pn + " are inconsistent");
      }
    }
  }
  return ModelPtr(std::move(m));
}

Status Model::non_finite_error(bool is_f, double t, int row) const {
  const std::string what = is_f ? "f returned a non-finite derivative of state " + state_names_[row]
                                : "g returned a non-finite output " + output_names_[row];
  return failed_precondition("model " + name_ + ": " + what + " at t = " + std::to_string(t));
}

Status Model::eval(bool is_f, double t, const double* u, int n, std::size_t ld, const double* x,
                   const double* theta, double* out) const {
  std::array<char, kErrorBufferSize> err;  // not zeroed: written only on failure
  err[0] = '\0';
  const int failed = with_context_
                         ? (is_f ? table_->f_ctx : table_->g_ctx)(table_->user_data, static_cast<uint32_t>(n), ld, t, u,
                                                                  x, theta, out, err.data(), err.size())
                         : (is_f ? table_->f : table_->g)(static_cast<uint32_t>(n), ld, t, u, x, theta, out, err.data(),
                                                          err.size());
  if (failed != 0) {
    return internal_error("model " + name_ + ": " + (is_f ? "f" : "g") + " failed at t = " + std::to_string(t) +
                          ": " + err.data());
  }
  const int rows = is_f ? nx_ : ny_;
  for (int i = 0; i < rows; ++i) {
    if (!all_finite(out + i * ld, n)) return non_finite_error(is_f, t, i);
  }
  return Status::ok();
}

Status Model::f(double t, const double* u, int n, std::size_t ld, const double* x, const double* theta,
                double* out) const {
  return eval(true, t, u, n, ld, x, theta, out);
}

Status Model::g(double t, const double* u, int n, std::size_t ld, const double* x, const double* theta,
                double* out) const {
  return eval(false, t, u, n, ld, x, theta, out);
}

Status Model::jacobian(bool is_f, double t, const double* u, const double* x, const double* theta, double* out,
                       double* jac) const {
  if (!(is_f ? has_f_jacobian() : has_g_jacobian())) return finite_difference_jacobian(is_f, t, u, x, theta, out, jac);
  std::array<char, kErrorBufferSize> err;  // not zeroed: written only on failure
  err[0] = '\0';
  const int failed =
      with_context_
          ? (is_f ? table_->f_jac_ctx : table_->g_jac_ctx)(table_->user_data, t, u, x, theta, out, jac, err.data(),
                                                           err.size())
          : (is_f ? table_->f_jac : table_->g_jac)(t, u, x, theta, out, jac, err.data(), err.size());
  if (failed != 0) {
    return internal_error("model " + name_ + ": Jacobian of " + (is_f ? "f" : "g") + " failed at t = " +
                          std::to_string(t) + ": " + err.data());
  }
  const int rows = is_f ? nx_ : ny_;
  if (all_finite_stored_singly(out, rows) && all_finite_stored_singly(jac, std::size_t(rows) * nz())) {
    return Status::ok();
  }
  for (int i = 0; i < rows; ++i) {
    if (!std::isfinite(out[i])) return non_finite_error(is_f, t, i);
  }
  return failed_precondition("model " + name_ + ": Jacobian of " + (is_f ? "f" : "g") + " is not finite at t = " +
                             std::to_string(t));
}

// Central differences, step h_j = cbrt(eps) * max(1, |z_j|): the step that
// balances truncation error O(h^2) against rounding error O(eps / h).
Status Model::finite_difference_jacobian(bool is_f, double t, const double* u, const double* x,
                                         const double* theta, double* out, double* jac) const {
  const int rows = is_f ? nx_ : ny_;
  FdScratch& s = fd_scratch;
  s.x.assign(x, x + nx_);
  s.theta.assign(theta, theta + ntheta_);
  s.plus.resize(rows);
  s.minus.resize(rows);
  RICCATI_RETURN_IF_ERROR(eval(is_f, t, u, 1, 1, s.x.data(), s.theta.data(), out));
  const double step_scale = std::cbrt(std::numeric_limits<double>::epsilon());
  for (int j = 0; j < nz(); ++j) {
    double& zj = j < nx_ ? s.x[j] : s.theta[j - nx_];
    const double z0 = zj;
    const double h = step_scale * std::max(1.0, std::abs(z0));
    zj = z0 + h;
    RICCATI_RETURN_IF_ERROR(eval(is_f, t, u, 1, 1, s.x.data(), s.theta.data(), s.plus.data()));
    zj = z0 - h;
    RICCATI_RETURN_IF_ERROR(eval(is_f, t, u, 1, 1, s.x.data(), s.theta.data(), s.minus.data()));
    zj = z0;
    for (int i = 0; i < rows; ++i) jac[i + j * rows] = (s.plus[i] - s.minus[i]) / (2.0 * h);
  }
  return Status::ok();
}

Status Model::f_jacobian(double t, const double* u, const double* x, const double* theta, double* out,
                         double* jac) const {
  return jacobian(true, t, u, x, theta, out, jac);
}

Status Model::g_jacobian(double t, const double* u, const double* x, const double* theta, double* out,
                         double* jac) const {
  return jacobian(false, t, u, x, theta, out, jac);
}

Status Model::hessian(bool is_f, double t, const double* u, const double* x, const double* theta, double* out,
                      double* jac, double* hess) const {
  if (!has_second_derivatives()) {
    return failed_precondition("model " + name_ + " gives no second derivatives");
  }
  std::array<char, kErrorBufferSize> err;  // not zeroed: written only on failure
  err[0] = '\0';
  const int failed = with_context_ ? (is_f ? f_hess_ctx_ : g_hess_ctx_)(table_->user_data, t, u, x, theta, out, jac,
                                                                        hess, err.data(), err.size())
                                   : (is_f ? f_hess_ : g_hess_)(t, u, x, theta, out, jac, hess, err.data(), err.size());
  if (failed != 0) {
    return internal_error("model " + name_ + ": second derivatives of " + (is_f ? "f" : "g") + " failed at t = " +
                          std::to_string(t) + ": " + err.data());
  }
  const std::size_t rows = static_cast<std::size_t>(is_f ? nx_ : ny_), nz2 = std::size_t(nz()) * std::size_t(nz());
  if (!all_finite(out, rows) || !all_finite(jac, rows * nz()) || !all_finite(hess, rows * nz2)) {
    return failed_precondition("model " + name_ + ": the second derivatives of " + (is_f ? "f" : "g") +
                               " are not finite at t = " + std::to_string(t));
  }
  return Status::ok();
}

Status Model::f_hessian(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                        double* hess) const {
  return hessian(true, t, u, x, theta, out, jac, hess);
}

Status Model::g_hessian(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                        double* hess) const {
  return hessian(false, t, u, x, theta, out, jac, hess);
}

Status Model::mechanical(double t, const double* x, const double* theta, double* c, double* Fc, double* c_jac,
                         double* Fc_jac) const {
  if (!has_mechanical_form()) return failed_precondition("model " + name_ + " has no mechanical form (M a + h = H u)");
  std::array<char, kErrorBufferSize> err;  // not zeroed: written only on failure
  err[0] = '\0';
  const int failed = mech_ctx_ != nullptr
                         ? mech_ctx_(table_->user_data, t, x, theta, c, Fc, c_jac, Fc_jac, err.data(), err.size())
                         : mech_(t, x, theta, c, Fc, c_jac, Fc_jac, err.data(), err.size());
  if (failed != 0) {
    return internal_error("model " + name_ + ": mechanical form failed at t = " + std::to_string(t) + ": " +
                          err.data());
  }
  const std::size_t rows = static_cast<std::size_t>(ndof_ + ny_), cols = static_cast<std::size_t>(nu_ + ndof_);
  if (!all_finite(c, rows) || !all_finite(Fc, rows * cols) || !all_finite(c_jac, rows * nz()) ||
      !all_finite(Fc_jac, rows * cols * nz())) {
    return failed_precondition("model " + name_ + ": the mechanical form is not finite at t = " + std::to_string(t));
  }
  return Status::ok();
}

int Model::state_index(std::string_view n) const { return index_of(state_names_, n); }
int Model::param_index(std::string_view n) const { return index_of(param_names_, n); }
int Model::input_index(std::string_view n) const { return index_of(input_names_, n); }
int Model::output_index(std::string_view n) const { return index_of(output_names_, n); }

}  // namespace riccati
