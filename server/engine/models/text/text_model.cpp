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

class CompiledModel {
 public:
  std::string name, version, description;
  std::vector<std::string> states, params, inputs, outputs;
  std::vector<const char*> state_ptrs, param_ptrs, input_ptrs, output_ptrs;
  std::vector<double> theta_default, theta_lower, theta_upper;
  Tape f, g, f_jac, g_jac;  // f_jac: f then df/dz column-major; g_jac likewise
  int nx = 0, ntheta = 0, nu = 0, ny = 0;
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
    table.theta_default = theta_default.data();
    table.theta_lower = theta_lower.data();
    table.theta_upper = theta_upper.data();
    table.user_data = this;
    table.f_ctx = &eval<true>;
    table.g_ctx = &eval<false>;
    table.f_jac_ctx = &jac<true>;
    table.g_jac_ctx = &jac<false>;
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

  template <bool is_f>
  static int jac(void* self, double t, const double* u, const double* x, const double* theta, double* out,
                 double* jacobian, char* err, size_t err_len) {
    try {
      const auto* m = static_cast<const CompiledModel*>(self);
      const Tape& tape = is_f ? m->f_jac : m->g_jac;
      double* r = scratch(m->registers);
      m->load(r, t, u, x, theta, 1, 0);
      tape.load_constants(r);
      const std::size_t rows = static_cast<std::size_t>(is_f ? m->nx : m->ny);
      double* values = r + tape.registers();  // the outputs, after the registers
      tape.run(r, values, 1);
      std::memcpy(out, values, rows * sizeof(double));
      std::memcpy(jacobian, values + rows, rows * static_cast<std::size_t>(m->nx + m->ntheta) * sizeof(double));
      return 0;
    } catch (const std::exception& e) {
      write_error(err, err_len, e.what());
      return 1;
    }
  }
};

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
    static const std::set<std::string> kKeys = {"model",  "version", "description", "states", "inputs",
                                                "parameters", "define", "der", "outputs"};
    std::map<std::string, YAML::Node> section;
    for (const Entry& e : top) {
      if (kKeys.count(e.key) == 0) {
        return src_.at(e.key_node.Mark(), "unknown key \"" + e.key +
                                              "\" (model, version, description, states, inputs, parameters, "
                                              "define, der, outputs)");
      }
      section[e.key] = e.value;
    }
    auto m = std::make_shared<CompiledModel>();

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

    // Every name known.
    std::unordered_map<std::string, int> define_index;
    for (std::size_t i = 0; i < defines.size(); ++i) define_index[defines[i].key] = static_cast<int>(i);
    for (const auto* list : {&define_exprs, &der_exprs, &output_exprs}) {
      for (const Expression& e : *list) {
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
    for (std::size_t i = 0; i < states.size(); ++i) {
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
    for (std::size_t i = 0; i < states.size(); ++i) {
      const Expression& e = der_exprs[static_cast<std::size_t>(der_of_state[i])];
      f_roots.push_back(lower(e.ast, e.ast.root, node_of));
    }
    for (const Expression& e : output_exprs) g_roots.push_back(lower(e.ast, e.ast.root, node_of));

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

    const riccati_model_v1* table = &m->table;
    RICCATI_ASSIGN_OR_RETURN(out.model, Model::create(table, std::shared_ptr<void>(m), "text model " + src_.origin()));
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
};

}  // namespace

Result<TextModel> compile_text_model(std::string_view text, const std::string& origin) {
  Compiler compiler(text, origin);
  return compiler.run();
}

}  // namespace riccati
