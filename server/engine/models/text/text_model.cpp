#include "engine/models/text/text_model.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <set>
#include <unordered_map>
#include <utility>

#include "engine/models/text/expression.hpp"
#include "engine/models/text/tape.hpp"

namespace riccati {

namespace {

using text::Ast;
using text::AstNode;
using text::Graph;
using text::Op;
using text::Tape;

constexpr std::size_t kMaxDefines = 10000;

// ---------------------------------------------------------------------------
// Messages with a place: "file:line:col: what", the line, a caret.

class Source {
 public:
  Source(std::string_view text, std::string origin) : text_(text), origin_(std::move(origin)) {}

  Status at_offset(std::size_t pos, const std::string& message) const {
    pos = std::min(pos, text_.size());
    std::size_t line_start = 0;
    int line = 1;
    for (std::size_t i = 0; i < pos; ++i) {
      if (text_[i] == '\n') {
        ++line;
        line_start = i + 1;
      }
    }
    std::size_t line_end = text_.find('\n', line_start);
    if (line_end == std::string_view::npos) line_end = text_.size();
    std::string line_text(text_.substr(line_start, line_end - line_start));
    std::replace(line_text.begin(), line_text.end(), '\t', ' ');  // tabs shown as one space, as counted
    std::string caret;
    int column = 1;  // in characters: UTF-8 continuation bytes do not count
    for (std::size_t i = line_start; i < pos; ++i) {
      if ((static_cast<unsigned char>(text_[i]) & 0xc0) == 0x80) continue;
      caret += ' ';
      ++column;
    }
    caret += '^';
    return invalid_argument(origin_ + ":" + std::to_string(line) + ":" + std::to_string(column) + ": " + message +
                            "\n  " + line_text + "\n  " + caret);
  }

  Status at(const YAML::Mark& mark, const std::string& message) const {
    if (mark.is_null()) return invalid_argument(origin_ + ": " + message);
    return at_offset(static_cast<std::size_t>(mark.pos), message);
  }

  // At `offset` into the scalar `node` (an expression): exact for plain and
  // quoted scalars on one line, the start of the scalar otherwise.
  Status in_scalar(const YAML::Node& node, std::size_t offset, const std::string& message) const {
    const YAML::Mark mark = node.Mark();
    if (mark.is_null()) return invalid_argument(origin_ + ": " + message);
    const std::string& s = node.Scalar();
    const auto pos = static_cast<std::size_t>(mark.pos);
    if (text_.substr(pos, s.size()) == s) return at_offset(pos + offset, message);
    if (pos < text_.size() && (text_[pos] == '"' || text_[pos] == '\'') && text_.substr(pos + 1, s.size()) == s) {
      return at_offset(pos + 1 + offset, message);
    }
    return at_offset(pos, message + " (at character " + std::to_string(offset + 1) + " of the expression)");
  }

  const std::string& origin() const { return origin_; }

 private:
  std::string_view text_;
  std::string origin_;
};

bool valid_identifier(const std::string& s) {
  if (s.empty() || !(std::isalpha(static_cast<unsigned char>(s[0])) != 0 || s[0] == '_')) return false;
  return std::all_of(s.begin(), s.end(), [](char c) { return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_'; });
}

bool valid_model_name(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
  });
}

// The entries of a YAML mapping in document order, keys as strings; a
// repeated key is an error (YAML forbids it, yaml-cpp keeps both).
struct Entry {
  std::string key;
  YAML::Node key_node;
  YAML::Node value;
};

Status entries(const Source& src, const YAML::Node& map, const std::string& what, std::vector<Entry>* out) {
  out->clear();
  if (!map.IsDefined() || map.IsNull()) return Status::ok();
  if (!map.IsMap()) return src.at(map.Mark(), what + " must be a mapping (name: value)");
  std::set<std::string> seen;
  for (auto it = map.begin(); it != map.end(); ++it) {
    if (!it->first.IsScalar()) return src.at(it->first.Mark(), "a key of " + what + " must be a name");
    const std::string key = it->first.Scalar();
    if (!seen.insert(key).second) return src.at(it->first.Mark(), "\"" + key + "\" appears twice in " + what);
    out->push_back({key, it->first, it->second});
  }
  return Status::ok();
}

// A list of names: a sequence of names, or a mapping name -> attributes
// (unit, description: free text).
Status name_list(const Source& src, const YAML::Node& node, const std::string& what, std::vector<Entry>* out) {
  out->clear();
  if (!node.IsDefined() || node.IsNull()) return Status::ok();
  if (node.IsSequence()) {
    std::set<std::string> seen;
    for (const YAML::Node& item : node) {
      if (!item.IsScalar()) return src.at(item.Mark(), "each of " + what + " must be a name");
      if (!seen.insert(item.Scalar()).second) return src.at(item.Mark(), "\"" + item.Scalar() + "\" appears twice in " + what);
      out->push_back({item.Scalar(), item, YAML::Node()});
    }
    return Status::ok();
  }
  RICCATI_RETURN_IF_ERROR(entries(src, node, what, out));
  for (const Entry& e : *out) {
    if (e.value.IsNull() || e.value.IsScalar()) continue;  // no attributes, or a unit alone
    std::vector<Entry> attributes;
    RICCATI_RETURN_IF_ERROR(entries(src, e.value, what + "." + e.key, &attributes));
    for (const Entry& a : attributes) {
      if (a.key != "unit" && a.key != "description") {
        return src.at(a.key_node.Mark(), "unknown attribute \"" + a.key + "\" of " + e.key + " (unit, description)");
      }
    }
  }
  return Status::ok();
}

// The unit a name list's entry declares: `h1: m` or `h1: {unit: m}`; "" if none.
std::string unit_of(const Entry& e) {
  if (e.value.IsScalar()) return e.value.Scalar();
  if (!e.value.IsMap()) return "";
  for (const auto& attribute : e.value) {
    if (attribute.first.IsScalar() && attribute.first.Scalar() == "unit" && attribute.second.IsScalar()) {
      return attribute.second.Scalar();
    }
  }
  return "";
}

Result<double> number(const Source& src, const YAML::Node& node, const std::string& what) {
  if (!node.IsScalar()) return src.at(node.Mark(), what + " must be a number");
  const std::string& s = node.Scalar();
  double v = 0.0;
  const char* begin = s.data();
  if (!s.empty() && s[0] == '+') ++begin;
  const auto [ptr, ec] = std::from_chars(begin, s.data() + s.size(), v);
  if (ec != std::errc() || ptr != s.data() + s.size() || !std::isfinite(v)) {
    return src.at(node.Mark(), what + " must be a finite number, not \"" + s + "\"");
  }
  return v;
}

// One expression of the file: where it is, its text and its tree.
struct Expression {
  std::string name;  // the state, output or helper it defines
  YAML::Node key;
  YAML::Node value;
  Ast ast;
};

Status parse(const Source& src, const Entry& e, const std::string& what, Expression* out) {
  out->name = e.key;
  out->key = e.key_node;
  out->value = e.value;
  if (!e.value.IsScalar()) return src.at(e.value.Mark(), what + " " + e.key + " must be an expression");
  text::ExpressionError error;
  if (!text::parse_expression(e.value.Scalar(), &out->ast, &error)) return src.in_scalar(e.value, error.offset, error.message);
  return Status::ok();
}

// ---------------------------------------------------------------------------
// The compiled model behind the table.

thread_local std::vector<double> tape_registers;

void write_error(char* err, std::size_t err_len, const char* what) {
  if (err != nullptr && err_len > 0) std::snprintf(err, err_len, "%s", what);
}

// Dual numbers of run-time width W = 1 + nz (value, then derivatives), the
// operations of riccati::Dual (riccati/dual.hpp) one for one; W = 1 is plain
// doubles (a division then divides, as double arithmetic does).
struct Duals {
  std::size_t w;
  void mul(const double* a, const double* b, double* out) const {  // out may not alias a or b
    out[0] = a[0] * b[0];
    for (std::size_t i = 1; i < w; ++i) out[i] = a[i] * b[0] + a[0] * b[i];
  }
  void div(const double* a, const double* b, double* out) const {
    if (w == 1) {
      out[0] = a[0] / b[0];
      return;
    }
    const double inv = 1.0 / b[0];
    const double q = a[0] * inv;
    out[0] = q;
    for (std::size_t i = 1; i < w; ++i) out[i] = (a[i] - q * b[i]) * inv;
  }
  void sub_from(double* a, const double* b) const {
    for (std::size_t i = 0; i < w; ++i) a[i] -= b[i];
  }
  void add_to(double* a, const double* b) const {
    for (std::size_t i = 0; i < w; ++i) a[i] += b[i];
  }
  void add_scaled(double* a, const double* b, double s) const {  // a += b * s (a Dual times a double)
    for (std::size_t i = 0; i < w; ++i) a[i] += b[i] * s;
  }
  void copy(double* a, const double* b) const { std::memcpy(a, b, w * sizeof(double)); }
};

class CompiledModel {
 public:
  std::string name, version, description;
  std::vector<std::string> states, params, inputs, outputs;
  std::vector<const char*> state_ptrs, param_ptrs, input_ptrs, output_ptrs;
  std::vector<std::string> state_units, param_units, input_units, output_units;  // "" where none
  std::vector<const char*> state_unit_ptrs, param_unit_ptrs, input_unit_ptrs, output_unit_ptrs;
  std::vector<double> theta_default, theta_lower, theta_upper;
  Tape f, g, f_jac, g_jac;  // f_jac: f then df/dz column-major; g_jac likewise
  int nx = 0, ntheta = 0, nu = 0, ny = 0;
  // The mechanical form (ndof > 0): f and g come from M, h, H, g, G, R,
  // whose values (mech) and derivatives (mech_jac: the values, then entry e
  // of z_j at count + e + j count) the tapes give; the accelerations are
  // solved for as the SDK does (riccati/model.hpp, detail::solve), with the
  // same dual arithmetic for the Jacobians, so that a text model and a
  // plugin agree to rounding.
  int ndof = 0;
  Tape mech, mech_jac;
  std::size_t mech_count = 0;  // entries of M, h, H, g, G, R
  std::size_t mech_scratch = 0;
  std::size_t registers = 0;  // the most any tape needs, plus room for outputs
  riccati_model_v1 table{};

  void fill_table() {
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
    table.user_data = this;
    table.f_ctx = &eval<true>;
    table.g_ctx = &eval<false>;
    table.f_jac_ctx = &jac<true>;
    table.g_jac_ctx = &jac<false>;
    if (ndof > 0) {
      table.ndof = static_cast<uint32_t>(ndof);
      table.f_ctx = &mech_eval<true>;
      table.g_ctx = &mech_eval<false>;
      table.f_jac_ctx = &mech_jacobian<true>;
      table.g_jac_ctx = &mech_jacobian<false>;
      table.mech_ctx = &mech_form;
    }
  }

 private:
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
      const auto* m = static_cast<const CompiledModel*>(self);
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
    auto m_at = [&](int i, int j) { return M + static_cast<std::size_t>(i + j * n) * w; };
    for (int k = 0; k < n; ++k) {  // Gaussian elimination with partial pivoting, as detail::solve
      int pivot = k;
      for (int i = k + 1; i < n; ++i) {
        if (std::abs(m_at(i, k)[0]) > std::abs(m_at(pivot, k)[0])) pivot = i;
      }
      if (m_at(pivot, k)[0] == 0.0) return false;
      if (pivot != k) {
        for (int j = k; j < n; ++j) {
          for (std::size_t c = 0; c < w; ++c) std::swap(m_at(k, j)[c], m_at(pivot, j)[c]);
        }
        for (std::size_t c = 0; c < w; ++c) std::swap(b[static_cast<std::size_t>(k) * w + c], b[static_cast<std::size_t>(pivot) * w + c]);
      }
      for (int i = k + 1; i < n; ++i) {
        if (m_at(i, k)[0] == 0.0) continue;
        d.div(m_at(i, k), m_at(k, k), tmp);  // factor
        for (int j = k + 1; j < n; ++j) {
          d.mul(tmp, m_at(k, j), tmp2);
          d.sub_from(m_at(i, j), tmp2);
        }
        d.mul(tmp, b + static_cast<std::size_t>(k) * w, tmp2);
        d.sub_from(b + static_cast<std::size_t>(i) * w, tmp2);
      }
    }
    for (int k = n - 1; k >= 0; --k) {
      double* sum = tmp;
      d.copy(sum, b + static_cast<std::size_t>(k) * w);
      for (int j = k + 1; j < n; ++j) {
        d.mul(m_at(k, j), a + static_cast<std::size_t>(j) * w, tmp2);
        d.sub_from(sum, tmp2);
      }
      d.div(sum, m_at(k, k), a + static_cast<std::size_t>(k) * w);
    }
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
      const auto* m = static_cast<const CompiledModel*>(self);
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
      const auto* m = static_cast<const CompiledModel*>(self);
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
      const auto* m = static_cast<const CompiledModel*>(self);
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
      const auto* m = static_cast<const CompiledModel*>(self);
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
};

// What check_jacobians() (jacobian_check.cpp) costs on this model, in tape
// instructions and arithmetic operations, from the sizes of its tapes: at
// each of generic_points()' 3 points, an exact Jacobian and 4 evaluations
// per column z_j for its fourth-order differences, of f and g, and of the
// mechanical form's c and Fc, each of which runs the derivatives' tape and
// copies every entry with its derivatives (about nz^2 n^2 a call: what makes
// a dense mass matrix cost n^5). About the time in nanoseconds on a current
// core (n = 32, 40, 48: 0.6, 1.6, 3.3 s for 0.6e9, 1.6e9, 3.2e9).
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

std::string sparsity_row(const Graph& graph, const std::vector<int>& jac, std::size_t row, std::size_t rows,
                         std::size_t nz) {
  std::string s;
  for (std::size_t j = 0; j < nz; ++j) s += graph.is_constant(jac[row + j * rows], 0.0) ? '.' : 'x';
  return s;
}

// ---------------------------------------------------------------------------
// The compiler.

class Compiler {
 public:
  Compiler(std::string_view text, const std::string& origin) : text_(text), src_(text, origin) {}

  Result<TextModel> run() {
    if (text_.size() > kMaxTextModelBytes) {
      return invalid_argument(src_.origin() + ": the model is " + std::to_string(text_.size()) +
                              " bytes, more than the limit of " + std::to_string(kMaxTextModelBytes));
    }
    YAML::Node root;
    try {
      root = YAML::Load(std::string(text_));
    } catch (const YAML::Exception& e) {
      return src_.at(e.mark, "not valid YAML: " + e.msg);
    }
    try {
      return compile(root);
    } catch (const YAML::Exception& e) {  // a conversion the checks above did not foresee
      return src_.at(e.mark, e.msg);
    }
  }

 private:
  Result<TextModel> compile(const YAML::Node& root) {
    if (!root.IsMap()) return src_.at(root.Mark(), "a text model is a YAML mapping (model:, states:, der:, ...)");
    std::vector<Entry> top;
    RICCATI_RETURN_IF_ERROR(entries(src_, root, "the model", &top));
    static const std::set<std::string> kKeys = {"model",  "version", "description", "states",     "inputs",
                                                "parameters", "define", "der",     "mechanical", "outputs"};
    std::map<std::string, YAML::Node> section;
    for (const Entry& e : top) {
      if (kKeys.count(e.key) == 0) {
        return src_.at(e.key_node.Mark(), "unknown key \"" + e.key +
                                              "\" (model, version, description, states, inputs, parameters, "
                                              "define, der, mechanical, outputs)");
      }
      section[e.key] = e.value;
    }
    auto m = std::make_shared<CompiledModel>();
    owner_ = m;

    // Name, version, description.
    if (section.count("model") == 0) return src_.at(root.Mark(), "the model has no name (model: my_model)");
    const YAML::Node& name = section["model"];
    if (!name.IsScalar() || !valid_model_name(name.Scalar())) {
      return src_.at(name.Mark(), "the model's name must be non-empty and use only a-z, 0-9 and _");
    }
    m->name = name.Scalar();
    for (const char* key : {"version", "description"}) {
      if (section.count(key) == 0) continue;
      if (!section[key].IsScalar()) return src_.at(section[key].Mark(), std::string(key) + " must be text");
      (std::string(key) == "version" ? m->version : m->description) = section[key].Scalar();
    }
    if (m->version.empty()) m->version = "1";

    // Names: states, inputs, parameters, helpers; one namespace.
    std::vector<Entry> states, inputs, params, defines, ders, outputs;
    RICCATI_RETURN_IF_ERROR(name_list(src_, section["states"], "states", &states));
    RICCATI_RETURN_IF_ERROR(name_list(src_, section["inputs"], "inputs", &inputs));
    RICCATI_RETURN_IF_ERROR(entries(src_, section["parameters"], "parameters", &params));
    RICCATI_RETURN_IF_ERROR(entries(src_, section["define"], "define", &defines));
    RICCATI_RETURN_IF_ERROR(entries(src_, section["der"], "der", &ders));
    RICCATI_RETURN_IF_ERROR(entries(src_, section["outputs"], "outputs", &outputs));
    if (states.empty()) return src_.at(root.Mark(), "the model has no states (states: {x: {unit: m}})");
    if (outputs.empty()) return src_.at(root.Mark(), "the model has no outputs (outputs: {y: x})");
    for (const auto& [list, what] : {std::pair{&states, "states"}, std::pair{&inputs, "inputs"},
                                     std::pair{&params, "parameters"}, std::pair{&outputs, "outputs"}}) {
      if (list->size() > kMaxTextModelSize) {
        return src_.at(section[what].Mark(), std::string("more than ") + std::to_string(kMaxTextModelSize) + " " + what);
      }
    }
    if (defines.size() > kMaxDefines) {
      return src_.at(section["define"].Mark(), "more than " + std::to_string(kMaxDefines) + " helpers in define");
    }
    std::map<std::string, std::string> kind;  // name -> what it is, for duplicates
    auto declare = [&](const Entry& e, const std::string& what) -> Status {
      if (!valid_identifier(e.key)) {
        return src_.at(e.key_node.Mark(), "\"" + e.key + "\" is not a valid name (letters, digits, _; not first a digit)");
      }
      if (e.key == "t" || e.key == "pi") return src_.at(e.key_node.Mark(), "\"" + e.key + "\" is reserved (time, or the constant pi)");
      if (text::find_function(e.key) != nullptr) {
        return src_.at(e.key_node.Mark(), "\"" + e.key + "\" is the name of a function");
      }
      if (const auto it = kind.find(e.key); it != kind.end()) {
        return src_.at(e.key_node.Mark(), "duplicate name \"" + e.key + "\": it is already " + it->second);
      }
      kind[e.key] = what;
      return Status::ok();
    };
    // In the order of the file, so that the second of two is the one named.
    std::vector<std::pair<const Entry*, const char*>> names;
    for (const Entry& e : states) names.emplace_back(&e, "a state");
    for (const Entry& e : inputs) names.emplace_back(&e, "an input");
    for (const Entry& e : params) names.emplace_back(&e, "a parameter");
    for (const Entry& e : defines) names.emplace_back(&e, "a helper (define)");
    std::stable_sort(names.begin(), names.end(), [](const auto& a, const auto& b) {
      return a.first->key_node.Mark().pos < b.first->key_node.Mark().pos;
    });
    for (const auto& [e, what] : names) RICCATI_RETURN_IF_ERROR(declare(*e, what));
    for (const Entry& e : outputs) {
      if (!valid_identifier(e.key)) return src_.at(e.key_node.Mark(), "\"" + e.key + "\" is not a valid output name");
    }
    for (const Entry& e : states) m->states.push_back(e.key);
    for (const Entry& e : inputs) m->inputs.push_back(e.key);
    for (const Entry& e : outputs) m->outputs.push_back(e.key);
    // Units: as declared; an output that is a state or an input as written
    // has its unit.
    std::map<std::string, std::string> unit_of_name;
    for (const auto* list : {&states, &inputs}) {
      for (const Entry& e : *list) unit_of_name[e.key] = unit_of(e);
    }
    for (const Entry& e : states) m->state_units.push_back(unit_of(e));
    for (const Entry& e : inputs) m->input_units.push_back(unit_of(e));
    for (const Entry& e : params) m->param_units.push_back(e.value.IsMap() ? unit_of(e) : "");
    for (const Entry& e : outputs) {
      const auto it = e.value.IsScalar() ? unit_of_name.find(e.value.Scalar()) : unit_of_name.end();
      m->output_units.push_back(it != unit_of_name.end() ? it->second : "");
    }
    m->nx = static_cast<int>(states.size());
    m->nu = static_cast<int>(inputs.size());
    m->ny = static_cast<int>(outputs.size());
    m->ntheta = static_cast<int>(params.size());

    // Parameters: a number (the default) or {value, min, max, unit}.
    for (const Entry& e : params) {
      m->params.push_back(e.key);
      double value = 0.0, lower = -std::numeric_limits<double>::infinity(), upper = std::numeric_limits<double>::infinity();
      if (e.value.IsMap()) {
        std::vector<Entry> attributes;
        RICCATI_RETURN_IF_ERROR(entries(src_, e.value, "parameter " + e.key, &attributes));
        bool has_value = false;
        for (const Entry& a : attributes) {
          const std::string what = "the " + a.key + " of parameter " + e.key;
          if (a.key == "value") {
            RICCATI_ASSIGN_OR_RETURN(value, number(src_, a.value, what));
            has_value = true;
          } else if (a.key == "min") {
            RICCATI_ASSIGN_OR_RETURN(lower, number(src_, a.value, what));
          } else if (a.key == "max") {
            RICCATI_ASSIGN_OR_RETURN(upper, number(src_, a.value, what));
          } else if (a.key != "unit" && a.key != "description") {
            return src_.at(a.key_node.Mark(), "unknown attribute \"" + a.key + "\" of parameter " + e.key +
                                                   " (value, min, max, unit, description)");
          }
        }
        if (!has_value) return src_.at(e.key_node.Mark(), "parameter " + e.key + " has no value (value: 1.5)");
      } else {
        RICCATI_ASSIGN_OR_RETURN(value, number(src_, e.value, "the value of parameter " + e.key));
      }
      if (lower > upper) return src_.at(e.key_node.Mark(), "parameter " + e.key + " has min > max");
      if (value < lower || value > upper) {
        return src_.at(e.key_node.Mark(), "the value of parameter " + e.key + " is outside [min, max]");
      }
      m->theta_default.push_back(value);
      m->theta_lower.push_back(lower);
      m->theta_upper.push_back(upper);
    }

    // Expressions.
    std::vector<Expression> define_exprs(defines.size()), der_exprs(ders.size()), output_exprs(outputs.size());
    for (std::size_t i = 0; i < defines.size(); ++i) RICCATI_RETURN_IF_ERROR(parse(src_, defines[i], "helper", &define_exprs[i]));
    for (std::size_t i = 0; i < ders.size(); ++i) RICCATI_RETURN_IF_ERROR(parse(src_, ders[i], "der", &der_exprs[i]));
    for (std::size_t i = 0; i < outputs.size(); ++i) RICCATI_RETURN_IF_ERROR(parse(src_, outputs[i], "output", &output_exprs[i]));

    // The mechanical form instead of der: M a + h = H u, y = g + G a + R u.
    std::vector<Expression> mech_exprs;  // M, h, H, G, R in their layout (g is the outputs); empty text = 0
    const bool mechanical = section.count("mechanical") > 0;
    if (mechanical) {
      const YAML::Node& mech = section["mechanical"];
      if (!ders.empty()) return src_.at(ders.front().key_node.Mark(), "give der or mechanical, not both");
      if (m->nx % 2 != 0) {
        return src_.at(mech.Mark(), "a mechanical model's states are its positions, then as many velocities: " +
                                        std::to_string(m->nx) + " states");
      }
      m->ndof = m->nx / 2;
      std::vector<Entry> parts;
      RICCATI_RETURN_IF_ERROR(entries(src_, mech, "mechanical", &parts));
      std::map<std::string, YAML::Node> part;
      for (const Entry& e : parts) {
        if (e.key != "M" && e.key != "h" && e.key != "H" && e.key != "G" && e.key != "R") {
          return src_.at(e.key_node.Mark(), "unknown key \"" + e.key + "\" of mechanical (M, h, H, G, R)");
        }
        part[e.key] = e.value;
      }
      const int n = m->ndof;
      RICCATI_RETURN_IF_ERROR(matrix(part, mech, "M", n, n, true, &mech_exprs));
      RICCATI_RETURN_IF_ERROR(matrix(part, mech, "h", n, 1, true, &mech_exprs));
      RICCATI_RETURN_IF_ERROR(matrix(part, mech, "H", n, m->nu, m->nu > 0, &mech_exprs));
      RICCATI_RETURN_IF_ERROR(matrix(part, mech, "G", m->ny, n, false, &mech_exprs));
      RICCATI_RETURN_IF_ERROR(matrix(part, mech, "R", m->ny, m->nu, false, &mech_exprs));
    }

    // Every name known.
    std::unordered_map<std::string, int> define_index;
    for (std::size_t i = 0; i < defines.size(); ++i) define_index[defines[i].key] = static_cast<int>(i);
    for (const auto* list : {&define_exprs, &der_exprs, &output_exprs, &mech_exprs}) {
      for (const Expression& e : *list) {
        if (e.ast.root < 0) continue;  // an entry left out: zero
        for (const auto& [n, offset] : text::referenced_names(e.ast)) {
          if (kind.count(n) == 0 && n != "t" && n != "pi") {
            return src_.in_scalar(e.value, offset,
                                  "unknown name \"" + n + "\": not a state, input, parameter or helper (define), nor t");
          }
        }
      }
    }

    // One derivative per state, in the states' order.
    std::vector<int> der_of_state(states.size(), -1);
    for (std::size_t i = 0; i < der_exprs.size(); ++i) {
      const auto it = std::find(m->states.begin(), m->states.end(), der_exprs[i].name);
      if (it == m->states.end()) {
        return src_.at(der_exprs[i].key.Mark(), "der " + der_exprs[i].name + ": \"" + der_exprs[i].name + "\" is not a state");
      }
      der_of_state[static_cast<std::size_t>(it - m->states.begin())] = static_cast<int>(i);
    }
    for (std::size_t i = 0; i < states.size() && !mechanical; ++i) {
      if (der_of_state[i] < 0) {
        return src_.at(states[i].key_node.Mark(), "state " + m->states[i] + " has no derivative (der: {" + m->states[i] + ": ...})");
      }
    }

    // Helpers in dependency order; a cycle is refused.
    std::vector<int> order;
    RICCATI_RETURN_IF_ERROR(sort_defines(define_exprs, define_index, &order));

    // The graph.
    const int nz = m->nx + m->ntheta;
    std::unordered_map<std::string, int> node_of;
    for (int i = 0; i < m->nx; ++i) node_of[m->states[static_cast<std::size_t>(i)]] = graph_.input(i);
    for (int j = 0; j < m->ntheta; ++j) node_of[m->params[static_cast<std::size_t>(j)]] = graph_.input(m->nx + j);
    for (int k = 0; k < m->nu; ++k) node_of[m->inputs[static_cast<std::size_t>(k)]] = graph_.input(nz + k);
    node_of["t"] = graph_.input(nz + m->nu);
    node_of["pi"] = graph_.constant(3.14159265358979323846);
    for (const int i : order) {
      const Expression& e = define_exprs[static_cast<std::size_t>(i)];
      node_of[e.name] = lower(e.ast, e.ast.root, node_of);
    }
    std::vector<int> f_roots, g_roots;
    for (std::size_t i = 0; i < states.size() && !mechanical; ++i) {
      const Expression& e = der_exprs[static_cast<std::size_t>(der_of_state[i])];
      f_roots.push_back(lower(e.ast, e.ast.root, node_of));
    }
    for (const Expression& e : output_exprs) g_roots.push_back(lower(e.ast, e.ast.root, node_of));
    if (mechanical) return compile_mechanical(root, *m, mech_exprs, output_exprs, define_exprs, g_roots, node_of);

    // Jacobians, column-major over z = [x; theta].
    std::vector<int> f_jac(static_cast<std::size_t>(m->nx * nz)), g_jac(static_cast<std::size_t>(m->ny * nz));
    for (int j = 0; j < nz && !graph_.overflowed(); ++j) {
      const std::vector<int> df = graph_.derivative(f_roots, j);
      const std::vector<int> dg = graph_.derivative(g_roots, j);
      for (int i = 0; i < m->nx; ++i) f_jac[static_cast<std::size_t>(i + j * m->nx)] = df[static_cast<std::size_t>(i)];
      for (int i = 0; i < m->ny; ++i) g_jac[static_cast<std::size_t>(i + j * m->ny)] = dg[static_cast<std::size_t>(i)];
    }
    if (graph_.overflowed()) {
      return src_.at(root.Mark(), "the model is too large: its equations and their derivatives need more than " +
                                      std::to_string(text::kMaxGraphNodes) + " operations");
    }

    // Tapes.
    const int num_inputs = nz + m->nu + 1;
    std::vector<int> f_all = f_roots, g_all = g_roots;
    f_all.insert(f_all.end(), f_jac.begin(), f_jac.end());
    g_all.insert(g_all.end(), g_jac.begin(), g_jac.end());
    m->f = Tape::compile(graph_, f_roots, num_inputs);
    m->g = Tape::compile(graph_, g_roots, num_inputs);
    m->f_jac = Tape::compile(graph_, f_all, num_inputs);
    m->g_jac = Tape::compile(graph_, g_all, num_inputs);
    for (const Tape* tape : {&m->f, &m->g, &m->f_jac, &m->g_jac}) {
      m->registers = std::max(m->registers, tape->registers() + tape->outputs());
    }
    m->fill_table();

    TextModel out;
    TextModelSummary& summary = out.summary;
    for (std::size_t i = 0; i < states.size(); ++i) {
      summary.equations.push_back(m->states[i] + "' = " + der_exprs[static_cast<std::size_t>(der_of_state[i])].value.Scalar());
    }
    for (const Expression& e : output_exprs) summary.equations.push_back("y." + e.name + " = " + e.value.Scalar());
    for (const Expression& e : define_exprs) summary.equations.push_back(e.name + " := " + e.value.Scalar());
    for (int i = 0; i < m->nx; ++i) {
      summary.f_sparsity.push_back(sparsity_row(graph_, f_jac, static_cast<std::size_t>(i), static_cast<std::size_t>(m->nx),
                                                static_cast<std::size_t>(nz)));
    }
    for (int i = 0; i < m->ny; ++i) {
      summary.g_sparsity.push_back(sparsity_row(graph_, g_jac, static_cast<std::size_t>(i), static_cast<std::size_t>(m->ny),
                                                static_cast<std::size_t>(nz)));
    }
    summary.graph_nodes = graph_.size();
    summary.tape_length = m->f_jac.length();
    summary.check_operations = check_operations(*m);

    const riccati_model_v1* table = &m->table;
    RICCATI_ASSIGN_OR_RETURN(out.model, Model::create(table, std::shared_ptr<void>(m), "text model " + src_.origin()));
    return out;
  }

  // Appends the entries of matrix `key` of the mechanical form (rows x cols,
  // a list of rows; h a list) column-major to `out`; one left out is zero
  // unless `required`.
  Status matrix(std::map<std::string, YAML::Node>& part, const YAML::Node& mech, const std::string& key, int rows,
                int cols, bool required, std::vector<Expression>* out) const {
    const std::size_t first = out->size();
    out->resize(first + static_cast<std::size_t>(rows * cols));
    if (part.count(key) == 0) {
      if (required) return src_.at(mech.Mark(), "the mechanical form has no " + key);
      return Status::ok();
    }
    const YAML::Node& node = part[key];
    const bool vector = key == "h";
    const std::string shape = vector ? "a list of " + std::to_string(rows) + " expressions"
                                     : "a list of " + std::to_string(rows) + " rows of " + std::to_string(cols) + " expressions";
    if (!node.IsSequence() || node.size() != static_cast<std::size_t>(rows)) {
      return src_.at(node.Mark(), "mechanical " + key + " must be " + shape +
                                      (key == "G" || key == "R" ? " (one row per output)" : ""));
    }
    for (int i = 0; i < rows; ++i) {
      const YAML::Node row = node[static_cast<std::size_t>(i)];
      if (!vector && (!row.IsSequence() || row.size() != static_cast<std::size_t>(cols))) {
        return src_.at(row.Mark(), "row " + std::to_string(i + 1) + " of mechanical " + key + " must have " +
                                       std::to_string(cols) + " entries");
      }
      for (int j = 0; j < cols; ++j) {
        const YAML::Node cell = vector ? row : row[static_cast<std::size_t>(j)];
        const std::string name = key + "(" + std::to_string(i + 1) + (vector ? "" : "," + std::to_string(j + 1)) + ")";
        RICCATI_RETURN_IF_ERROR(
            parse(src_, Entry{name, cell, cell}, "mechanical", &(*out)[first + static_cast<std::size_t>(i + j * rows)]));
      }
    }
    return Status::ok();
  }

  // The mechanical form's tapes (CompiledModel::mech, mech_jac) and the model.
  Result<TextModel> compile_mechanical(const YAML::Node& root, CompiledModel& m, const std::vector<Expression>& mech,
                                       const std::vector<Expression>& outputs, const std::vector<Expression>& defines,
                                       const std::vector<int>& g_roots,
                                       const std::unordered_map<std::string, int>& node_of) {
    const int n = m.ndof, nz = m.nx + m.ntheta;
    // Layout: M, h, H, then g (the outputs), G, R.
    std::vector<int> roots;
    const std::size_t before_g = static_cast<std::size_t>(n * n + n + n * m.nu);
    for (std::size_t k = 0; k < before_g; ++k) {
      roots.push_back(mech[k].ast.root < 0 ? graph_.constant(0.0) : lower(mech[k].ast, mech[k].ast.root, node_of));
    }
    roots.insert(roots.end(), g_roots.begin(), g_roots.end());
    for (std::size_t k = before_g; k < mech.size(); ++k) {
      roots.push_back(mech[k].ast.root < 0 ? graph_.constant(0.0) : lower(mech[k].ast, mech[k].ast.root, node_of));
    }
    // The inputs enter only through H u and R u.
    {
      std::vector<char> seen(graph_.size(), 0);
      std::vector<int> stack(roots.begin(), roots.end());
      while (!stack.empty()) {
        const int i = stack.back();
        stack.pop_back();
        if (seen[static_cast<std::size_t>(i)]) continue;
        seen[static_cast<std::size_t>(i)] = 1;
        const text::Node& node = graph_.node(i);
        if (node.op == Op::kInput && static_cast<int>(node.k) >= nz && static_cast<int>(node.k) < nz + m.nu) {
          return src_.at(root.Mark(), "input " + m.inputs[static_cast<std::size_t>(static_cast<int>(node.k) - nz)] +
                                          " appears in M, h, G, the outputs or an entry of H or R: in the mechanical "
                                          "form the inputs enter only as H u and R u");
        }
        for (const int c : {node.a, node.b, node.c}) {
          if (c >= 0) stack.push_back(c);
        }
      }
    }
    const std::size_t count = roots.size();
    std::vector<int> all = roots;
    all.resize(count * static_cast<std::size_t>(1 + nz));
    for (int j = 0; j < nz && !graph_.overflowed(); ++j) {
      const std::vector<int> d = graph_.derivative(roots, j);
      for (std::size_t e = 0; e < count; ++e) all[count + e + static_cast<std::size_t>(j) * count] = d[e];
    }
    if (graph_.overflowed()) {
      return src_.at(root.Mark(), "the model is too large: its equations and their derivatives need more than " +
                                      std::to_string(text::kMaxGraphNodes) + " operations");
    }
    const int num_inputs = nz + m.nu + 1;
    m.mech_count = count;
    m.mech = Tape::compile(graph_, roots, num_inputs);
    m.mech_jac = Tape::compile(graph_, all, num_inputs);
    const std::size_t w = static_cast<std::size_t>(nz + 1);
    const std::size_t solve = static_cast<std::size_t>(n * n + 2 * n + 2) * w;
    m.registers = std::max(m.mech.registers() + count + solve,
                           m.mech_jac.registers() + 2 * count * w + solve + static_cast<std::size_t>(m.nx) * w);
    m.fill_table();

    TextModel out;
    TextModelSummary& summary = out.summary;
    auto depends = [&](std::size_t e, int j) { return !graph_.is_constant(all[count + e + static_cast<std::size_t>(j) * count], 0.0); };
    // Sparsity: x' = v has its unit entries; a depends on whatever M, h, H do.
    std::string accel(static_cast<std::size_t>(nz), '.');
    for (std::size_t e = 0; e < before_g; ++e) {
      for (int j = 0; j < nz; ++j) {
        if (depends(e, j)) accel[static_cast<std::size_t>(j)] = 'x';
      }
    }
    for (int i = 0; i < n; ++i) {
      std::string row(static_cast<std::size_t>(nz), '.');
      row[static_cast<std::size_t>(n + i)] = 'x';
      summary.f_sparsity.push_back(row);
    }
    for (int i = 0; i < n; ++i) summary.f_sparsity.push_back(accel);
    for (int i = 0; i < m.ny; ++i) {
      std::string row(static_cast<std::size_t>(nz), '.');
      bool uses_a = false;
      for (int j = 0; j < nz; ++j) {
        if (depends(before_g + static_cast<std::size_t>(i), j)) row[static_cast<std::size_t>(j)] = 'x';
      }
      for (int k = 0; k < n; ++k) {
        const std::size_t at = before_g + static_cast<std::size_t>(m.ny + i + k * m.ny);  // G(i, k)
        uses_a = uses_a || !graph_.is_constant(roots[at], 0.0);
        for (int j = 0; j < nz; ++j) {
          if (depends(at, j)) row[static_cast<std::size_t>(j)] = 'x';
        }
      }
      for (int k = 0; k < m.nu; ++k) {
        const std::size_t at = before_g + static_cast<std::size_t>(m.ny + m.ny * n + i + k * m.ny);  // R(i, k)
        for (int j = 0; j < nz; ++j) {
          if (depends(at, j)) row[static_cast<std::size_t>(j)] = 'x';
        }
      }
      if (uses_a) {
        for (int j = 0; j < nz; ++j) {
          if (accel[static_cast<std::size_t>(j)] == 'x') row[static_cast<std::size_t>(j)] = 'x';
        }
      }
      summary.g_sparsity.push_back(row);
    }
    summary.equations.push_back("M(s) a + h(s, v) = H u, a = [" + [&] {
      std::string a;
      for (int i = 0; i < n; ++i) a += (i > 0 ? ", " : "") + m.states[static_cast<std::size_t>(n + i)] + "'";
      return a;
    }() + "]");
    for (const Expression& e : mech) {
      if (e.ast.root >= 0) summary.equations.push_back(e.name + " = " + e.value.Scalar());
    }
    for (const Expression& e : outputs) summary.equations.push_back("y." + e.name + " = " + e.value.Scalar());
    for (const Expression& e : defines) summary.equations.push_back(e.name + " := " + e.value.Scalar());
    summary.graph_nodes = graph_.size();
    summary.tape_length = m.mech_jac.length();
    summary.check_operations = check_operations(m);
    const riccati_model_v1* table = &m.table;
    // The model keeps the CompiledModel alive: find the shared_ptr that owns m.
    RICCATI_ASSIGN_OR_RETURN(out.model, Model::create(table, owner_, "text model " + src_.origin()));
    return out;
  }

  // Depth-first over the helpers' references, without recursion (a chain of
  // thousands of helpers must not exhaust the stack).
  Status sort_defines(const std::vector<Expression>& defines, const std::unordered_map<std::string, int>& index,
                      std::vector<int>* order) const {
    std::vector<std::vector<int>> deps(defines.size());
    for (std::size_t i = 0; i < defines.size(); ++i) {
      for (const auto& [n, offset] : text::referenced_names(defines[i].ast)) {
        if (const auto it = index.find(n); it != index.end()) deps[i].push_back(it->second);
      }
    }
    std::vector<int> state(defines.size(), 0);  // 0 new, 1 on the path, 2 done
    for (std::size_t start = 0; start < defines.size(); ++start) {
      if (state[start] != 0) continue;
      std::vector<std::pair<int, std::size_t>> path{{static_cast<int>(start), 0}};
      state[start] = 1;
      while (!path.empty()) {
        auto& [node, next] = path.back();
        const auto& ds = deps[static_cast<std::size_t>(node)];
        if (next == ds.size()) {
          state[static_cast<std::size_t>(node)] = 2;
          order->push_back(node);
          path.pop_back();
          continue;
        }
        const int d = ds[next++];
        if (state[static_cast<std::size_t>(d)] == 1) {
          std::string cycle;
          bool on = false;
          for (const auto& [p, unused] : path) {
            on = on || p == d;
            if (on) cycle += defines[static_cast<std::size_t>(p)].name + " -> ";
          }
          cycle += defines[static_cast<std::size_t>(d)].name;
          return src_.at(defines[static_cast<std::size_t>(d)].key.Mark(), "the helpers in define form a cycle: " + cycle);
        }
        if (state[static_cast<std::size_t>(d)] == 0) {
          state[static_cast<std::size_t>(d)] = 1;
          path.emplace_back(d, 0);
        }
      }
    }
    return Status::ok();
  }

  // The graph node of an expression's subtree (names already resolved: the
  // tree's depth is bounded by the parser's nesting limit).
  int lower(const Ast& ast, int i, const std::unordered_map<std::string, int>& node_of) {
    const AstNode& n = ast.nodes[static_cast<std::size_t>(i)];
    switch (n.kind) {
      case AstNode::Kind::kNumber:
        return graph_.constant(n.number);
      case AstNode::Kind::kName:
        return node_of.at(n.name);
      case AstNode::Kind::kOp:
        break;
    }
    int a[3] = {-1, -1, -1};
    for (std::size_t k = 0; k < n.args.size() && k < 3; ++k) a[k] = lower(ast, n.args[k], node_of);
    return graph_.make(n.op, a[0], a[1], a[2]);
  }

  std::string_view text_;
  Source src_;
  Graph graph_;
  std::shared_ptr<CompiledModel> owner_;  // the model being compiled
};

}  // namespace

Result<TextModel> compile_text_model(std::string_view text, const std::string& origin) {
  Compiler compiler(text, origin);
  return compiler.run();
}

}  // namespace riccati
