#include "engine/models/text/runtime.hpp"

#include <algorithm>
#include <cmath>
#include <exception>

#include "engine/models/text/text_model.hpp"
#include "riccati/dual.hpp"
#include "riccati/model.hpp"

namespace riccati::text {

namespace {

thread_local std::vector<double> tape_registers;

using riccati::detail::write_error;  // the SDK's: what a plugin's functions report with

// Dual numbers of run-time width w = 1 + nz (value, then derivatives): the
// SDK's, the operations of its Dual<N> one for one.
using Duals = DualArithmetic;

// The functions of the table, over the CompiledModel they are given as
// user_data (always a Runtime: new_compiled_model()).
struct Runtime : CompiledModel {
  // The registers of this thread, grown (once per size) to `n`.
  static double* scratch(std::size_t n) {
    if (tape_registers.size() < n) tape_registers.resize(n);
    return tape_registers.data();
  }
  void load(double* r, double t, const double* u, const double* x, const double* theta, std::size_t ld,
            std::size_t p) const {
    for (int i = 0; i < nx; ++i) r[i] = x[static_cast<std::size_t>(i) * ld + p];
    for (int j = 0; j < ntheta; ++j) r[nx + j] = theta[static_cast<std::size_t>(j) * ld + p];
    for (int k = 0; k < nu; ++k) r[nx + ntheta + k] = u[k];
    r[nx + ntheta + nu] = t;
  }

  template <bool is_f>
  static int eval(void* self, uint32_t n, size_t ld, double t, const double* u, const double* x,
                  const double* theta, double* out, char* err, size_t err_len) {
    try {
      const auto* m = static_cast<const Runtime*>(self);
      const Tape& tape = is_f ? m->f : m->g;
      if (n == 1) {
        double* r = scratch(m->registers);
        tape.load_constants(r);
        m->load(r, t, u, x, theta, ld, 0);
        tape.run(r, out, ld);
        return 0;
      }
      // Points kLanes at a time, lane by lane (Tape::run_lanes).
      constexpr std::size_t L = Tape::kLanes;
      double* r = scratch(m->registers * L);
      tape.load_constants_lanes(r);
      const int nz = m->nx + m->ntheta;
      for (int k = 0; k < m->nu; ++k) {
        for (std::size_t j = 0; j < L; ++j) r[static_cast<std::size_t>(nz + k) * L + j] = u[k];
      }
      for (std::size_t j = 0; j < L; ++j) r[static_cast<std::size_t>(nz + m->nu) * L + j] = t;
      for (std::size_t p0 = 0; p0 < n; p0 += L) {
        const std::size_t points = std::min<std::size_t>(L, n - p0);
        for (int i = 0; i < m->nx; ++i) {
          for (std::size_t j = 0; j < points; ++j) r[static_cast<std::size_t>(i) * L + j] = x[static_cast<std::size_t>(i) * ld + p0 + j];
        }
        for (int i = 0; i < m->ntheta; ++i) {
          for (std::size_t j = 0; j < points; ++j) {
            r[static_cast<std::size_t>(m->nx + i) * L + j] = theta[static_cast<std::size_t>(i) * ld + p0 + j];
          }
        }
        tape.run_lanes(r, points, out + p0, ld);
      }
      return 0;
    } catch (const std::exception& e) {
      write_error(err, err_len, e.what());
      return 1;
    }
  }

  // Where the entries of the mechanical form are, in the tapes' outputs.
  std::size_t at_M(int i, int j) const { return static_cast<std::size_t>(i + j * ndof); }
  std::size_t at_h(int i) const { return static_cast<std::size_t>(ndof * ndof + i); }
  std::size_t at_H(int i, int j) const { return static_cast<std::size_t>(ndof * ndof + ndof + i + j * ndof); }
  std::size_t at_g(int i) const { return static_cast<std::size_t>(ndof * ndof + ndof + ndof * nu + i); }
  std::size_t at_G(int i, int j) const { return at_g(ny) + static_cast<std::size_t>(i + j * ny); }
  std::size_t at_R(int i, int j) const { return at_G(0, ndof) + static_cast<std::size_t>(i + j * ny); }

  // f or g of the mechanical form at one point, on duals of width w: `e`
  // holds every entry (w doubles each), `work` the solve's room. Writes
  // out[row * w ...]. False if M is singular.
  template <bool is_f>
  bool mech_point(const Duals& d, const double* e, const double* u, const double* x, double* work,
                  double* out) const {
    const std::size_t w = d.w;
    const int n = ndof;
    double* M = work;                                      // n x n, a copy (eliminated in place)
    double* b = M + static_cast<std::size_t>(n * n) * w;   // n
    double* a = b + static_cast<std::size_t>(n) * w;       // n
    double* tmp = a + static_cast<std::size_t>(n) * w;     // 2
    double* tmp2 = tmp + w;
    for (int k = 0; k < n * n; ++k) d.copy(M + static_cast<std::size_t>(k) * w, e + static_cast<std::size_t>(k) * w);
    for (int i = 0; i < n; ++i) {  // b = -h + H u
      double* bi = b + static_cast<std::size_t>(i) * w;
      const double* hi = e + at_h(i) * w;
      for (std::size_t c = 0; c < w; ++c) bi[c] = -1.0 * hi[c];
      bi[0] = -hi[0];
      for (int j = 0; j < nu; ++j) d.add_scaled(bi, e + at_H(i, j) * w, u[j]);
    }
    // Elimination and substitution as the SDK's mechanical models do them
    // (riccati/model.hpp, detail::gaussian_elimination), on these duals.
    struct System {
      const Duals& d;
      double *M, *b, *a, *tmp, *tmp2;
      int n;
      double* m_at(int i, int j) const { return M + static_cast<std::size_t>(i + j * n) * d.w; }
      double* b_at(int i) const { return b + static_cast<std::size_t>(i) * d.w; }
      double* a_at(int i) const { return a + static_cast<std::size_t>(i) * d.w; }
      double value(int i, int k) const { return m_at(i, k)[0]; }
      void swap(int k, int p) const {
        for (int j = k; j < n; ++j) std::swap_ranges(m_at(k, j), m_at(k, j) + d.w, m_at(p, j));
        std::swap_ranges(b_at(k), b_at(k) + d.w, b_at(p));
      }
      void eliminate(int i, int k) const {
        d.div(m_at(i, k), m_at(k, k), tmp);  // the factor
        for (int j = k + 1; j < n; ++j) {
          d.mul(tmp, m_at(k, j), tmp2);
          d.sub_from(m_at(i, j), tmp2);
        }
        d.mul(tmp, b_at(k), tmp2);
        d.sub_from(b_at(i), tmp2);
      }
      void substitute(int k) const {
        d.copy(tmp, b_at(k));  // the sum
        for (int j = k + 1; j < n; ++j) {
          d.mul(m_at(k, j), a_at(j), tmp2);
          d.sub_from(tmp, tmp2);
        }
        d.div(tmp, m_at(k, k), a_at(k));
      }
    } system{d, M, b, a, tmp, tmp2, n};
    if (!riccati::detail::gaussian_elimination(system, n)) return false;
    if constexpr (is_f) {
      for (int i = 0; i < n; ++i) {
        double* v = out + static_cast<std::size_t>(i) * w;  // x' = v: the seeded velocity
        std::fill(v, v + w, 0.0);
        v[0] = x[n + i];
        if (w > 1) v[1 + static_cast<std::size_t>(n + i)] = 1.0;
        d.copy(out + static_cast<std::size_t>(n + i) * w, a + static_cast<std::size_t>(i) * w);
      }
    } else {
      for (int i = 0; i < ny; ++i) {
        double* sum = out + static_cast<std::size_t>(i) * w;
        d.copy(sum, e + at_g(i) * w);
        for (int j = 0; j < n; ++j) {
          d.mul(e + at_G(i, j) * w, a + static_cast<std::size_t>(j) * w, tmp2);
          d.add_to(sum, tmp2);
        }
        for (int j = 0; j < nu; ++j) d.add_scaled(sum, e + at_R(i, j) * w, u[j]);
      }
    }
    return true;
  }

  template <bool is_f>
  static int mech_eval(void* self, uint32_t n, size_t ld, double t, const double* u, const double* x,
                       const double* theta, double* out, char* err, size_t err_len) {
    try {
      const auto* m = static_cast<const Runtime*>(self);
      double* r = scratch(m->registers);
      double* e = r + m->mech.registers();
      double* work = e + m->mech_count;
      m->mech.load_constants(r);
      const Duals d{1};
      const int rows = is_f ? m->nx : m->ny;
      double point_out[2 * 256];  // nx, ny <= kMaxTextModelSize
      double xp[256];
      for (uint32_t p = 0; p < n; ++p) {
        m->load(r, t, u, x, theta, ld, p);
        for (int i = 0; i < m->nx; ++i) xp[i] = x[static_cast<std::size_t>(i) * ld + p];
        m->mech.run(r, e, 1);
        if (!m->mech_point<is_f>(d, e, u, xp, work, point_out)) {
          write_error(err, err_len, "the mass matrix M is singular");
          return 1;
        }
        for (int i = 0; i < rows; ++i) out[static_cast<std::size_t>(i) * ld + p] = point_out[i];
      }
      return 0;
    } catch (const std::exception& ex) {
      write_error(err, err_len, ex.what());
      return 1;
    }
  }

  // The tape's values and derivatives of every entry, as duals.
  double* mech_duals(double* r, double t, const double* u, const double* x, const double* theta) const {
    load(r, t, u, x, theta, 1, 0);
    mech_jac.load_constants(r);
    double* values = r + mech_jac.registers();
    mech_jac.run(r, values, 1);
    const std::size_t w = static_cast<std::size_t>(nx + ntheta) + 1, count = mech_count;
    double* e = values + count * w;
    for (std::size_t k = 0; k < count; ++k) {
      e[k * w] = values[k];
      for (std::size_t j = 0; j + 1 < w; ++j) e[k * w + 1 + j] = values[count + k + j * count];
    }
    return e;
  }

  template <bool is_f>
  static int mech_jacobian(void* self, double t, const double* u, const double* x, const double* theta, double* out,
                           double* jacobian, char* err, size_t err_len) {
    try {
      const auto* m = static_cast<const Runtime*>(self);
      double* r = scratch(m->registers);
      const std::size_t w = static_cast<std::size_t>(m->nx + m->ntheta) + 1;
      double* e = m->mech_duals(r, t, u, x, theta);
      double* work = e + m->mech_count * w;
      double* result = work + static_cast<std::size_t>(m->ndof * m->ndof + 2 * m->ndof + 2) * w;
      if (!m->mech_point<is_f>(Duals{w}, e, u, x, work, result)) {
        write_error(err, err_len, "the mass matrix M is singular");
        return 1;
      }
      const std::size_t rows = static_cast<std::size_t>(is_f ? m->nx : m->ny);
      for (std::size_t i = 0; i < rows; ++i) {
        out[i] = result[i * w];
        for (std::size_t j = 0; j + 1 < w; ++j) jacobian[i + j * rows] = result[i * w + 1 + j];
      }
      return 0;
    } catch (const std::exception& ex) {
      write_error(err, err_len, ex.what());
      return 1;
    }
  }

  static int mech_form(void* self, double t, const double* x, const double* theta, double* c, double* Fc,
                       double* c_jac, double* Fc_jac, char* err, size_t err_len) {
    try {
      const auto* m = static_cast<const Runtime*>(self);
      double* r = scratch(m->registers);
      const std::size_t w = static_cast<std::size_t>(m->nx + m->ntheta) + 1, nz = w - 1;
      static const double kNoInputs[kMaxTextModelSize] = {};  // M, h, H, g, G, R do not depend on u (checked)
      const double* e = m->mech_duals(r, t, kNoInputs, x, theta);
      const int n = m->ndof;
      const std::size_t rows = static_cast<std::size_t>(n + m->ny), cols = static_cast<std::size_t>(m->nu + n);
      const std::size_t entries = rows * cols;
      auto put = [&](double* value, double* jac, std::size_t k, std::size_t stride, std::size_t entry, double sign) {
        value[k] = sign * e[entry * w];
        for (std::size_t j = 0; j < nz; ++j) jac[k + j * stride] = sign * e[entry * w + 1 + j];
      };
      for (int i = 0; i < n; ++i) put(c, c_jac, static_cast<std::size_t>(i), rows, m->at_h(i), 1.0);
      for (int i = 0; i < m->ny; ++i) put(c, c_jac, static_cast<std::size_t>(n + i), rows, m->at_g(i), 1.0);
      for (int j = 0; j < m->nu; ++j) {
        for (int i = 0; i < n; ++i) put(Fc, Fc_jac, static_cast<std::size_t>(i) + j * rows, entries, m->at_H(i, j), -1.0);
        for (int i = 0; i < m->ny; ++i) {
          put(Fc, Fc_jac, static_cast<std::size_t>(n + i) + j * rows, entries, m->at_R(i, j), 1.0);
        }
      }
      for (int j = 0; j < n; ++j) {
        const std::size_t col = static_cast<std::size_t>(m->nu + j);
        for (int i = 0; i < n; ++i) put(Fc, Fc_jac, static_cast<std::size_t>(i) + col * rows, entries, m->at_M(i, j), 1.0);
        for (int i = 0; i < m->ny; ++i) {
          put(Fc, Fc_jac, static_cast<std::size_t>(n + i) + col * rows, entries, m->at_G(i, j), 1.0);
        }
      }
      return 0;
    } catch (const std::exception& ex) {
      write_error(err, err_len, ex.what());
      return 1;
    }
  }

  template <bool is_f>
  static int jac(void* self, double t, const double* u, const double* x, const double* theta, double* out,
                 double* jacobian, char* err, size_t err_len) {
    try {
      const auto* m = static_cast<const Runtime*>(self);
      const Tape& tape = is_f ? m->f_jac : m->g_jac;
      double* r = scratch(m->registers);
      m->load(r, t, u, x, theta, 1, 0);
      tape.load_constants(r);
      tape.run_split(r, static_cast<std::size_t>(is_f ? m->nx : m->ny), out, jacobian);
      return 0;
    } catch (const std::exception& e) {
      write_error(err, err_len, e.what());
      return 1;
    }
  }

  template <bool is_f>
  static int hess(void* self, double t, const double* u, const double* x, const double* theta, double* out,
                  double* jacobian, double* hessian, char* err, size_t err_len) {
    try {
      const auto* m = static_cast<const Runtime*>(self);
      const Tape& tape = is_f ? m->f_hess : m->g_hess;
      double* r = scratch(m->registers);
      m->load(r, t, u, x, theta, 1, 0);
      tape.load_constants(r);
      double* all = r + tape.registers();  // the room for outputs after the registers
      tape.run(r, all, 1);
      const std::size_t rows = static_cast<std::size_t>(is_f ? m->nx : m->ny);
      const std::size_t nz = static_cast<std::size_t>(m->nx + m->ntheta);
      std::copy(all, all + rows, out);
      std::copy(all + rows, all + rows + rows * nz, jacobian);
      std::copy(all + rows + rows * nz, all + rows + rows * nz + rows * nz * nz, hessian);
      return 0;
    } catch (const std::exception& e) {
      write_error(err, err_len, e.what());
      return 1;
    }
  }
};

}  // namespace

std::shared_ptr<CompiledModel> new_compiled_model() { return std::make_shared<Runtime>(); }


void CompiledModel::fill_table() {
  auto ptrs = [](const std::vector<std::string>& names, std::vector<const char*>* out) {
    for (const auto& n : names) out->push_back(n.c_str());
  };
  ptrs(states, &state_ptrs);
  ptrs(params, &param_ptrs);
  ptrs(inputs, &input_ptrs);
  ptrs(outputs, &output_ptrs);
  ptrs(state_units, &state_unit_ptrs);
  ptrs(param_units, &param_unit_ptrs);
  ptrs(input_units, &input_unit_ptrs);
  ptrs(output_units, &output_unit_ptrs);
  table.abi_version = RICCATI_MODEL_ABI_VERSION;
  table.struct_size = sizeof(riccati_model_v1);
  table.name = name.c_str();
  table.version = version.c_str();
  table.description = description.c_str();
  table.nx = static_cast<uint32_t>(nx);
  table.ntheta = static_cast<uint32_t>(ntheta);
  table.nu = static_cast<uint32_t>(nu);
  table.ny = static_cast<uint32_t>(ny);
  table.state_names = state_ptrs.data();
  table.param_names = param_ptrs.data();
  table.input_names = nu > 0 ? input_ptrs.data() : nullptr;
  table.output_names = output_ptrs.data();
  table.state_units = state_unit_ptrs.data();
  table.param_units = param_unit_ptrs.data();
  table.input_units = nu > 0 ? input_unit_ptrs.data() : nullptr;
  table.output_units = output_unit_ptrs.data();
  table.theta_default = theta_default.data();
  table.theta_lower = theta_lower.data();
  table.theta_upper = theta_upper.data();
  table.user_data = static_cast<Runtime*>(this);  // what its functions cast back
  table.f_ctx = &Runtime::eval<true>;
  table.g_ctx = &Runtime::eval<false>;
  table.f_jac_ctx = &Runtime::jac<true>;
  table.g_jac_ctx = &Runtime::jac<false>;
  if (has_second_derivatives) {
    table.f_hess_ctx = &Runtime::hess<true>;
    table.g_hess_ctx = &Runtime::hess<false>;
  }
  if (ndof > 0) {
    table.ndof = static_cast<uint32_t>(ndof);
    table.f_ctx = &Runtime::mech_eval<true>;
    table.g_ctx = &Runtime::mech_eval<false>;
    table.f_jac_ctx = &Runtime::mech_jacobian<true>;
    table.g_jac_ctx = &Runtime::mech_jacobian<false>;
    table.mech_ctx = &Runtime::mech_form;
  }
}

double check_operations(const CompiledModel& m) {
  const double nz = m.nx + m.ntheta, w = nz + 1.0, fd = 4.0 * nz;
  double per_point = 0.0;
  if (m.ndof == 0) {
    per_point = double(m.f_jac.length()) + fd * double(m.f.length()) + double(m.g_jac.length()) +
                fd * double(m.g.length()) + 2.0 * (m.nx + m.ny) * nz;
  } else {
    const double n = m.ndof, count = double(m.mech_count);
    const double solve = n * n * n, duals = double(m.mech_jac.length()) + count * w;
    const double nc = n + m.ny, nfc = nc * (m.nu + n);
    const double f_or_g = duals + solve * w + fd * (double(m.mech.length()) + count + solve);
    // c and Fc with their Jacobians, allocated per call and scattered a
    // column of nz apart (a cache miss each: 3 operations, as measured).
    const double form = duals + 3.0 * (nc + nfc) * w;
    per_point = 2.0 * f_or_g + 2.0 * (1.0 + fd) * form;
  }
  return 3.0 * per_point;
}

}  // namespace riccati::text
