// The compiler of text models: the YAML read (diagnostics.hpp), every name
// resolved (helpers sorted, cycles refused), one hash-consed graph of f and
// g and their derivatives with respect to [x; theta] (tape.hpp), and the
// tapes that the runtime (runtime.hpp) runs behind the model's table.
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "engine/models/text/diagnostics.hpp"
#include "engine/models/text/expression.hpp"
#include "engine/models/text/runtime.hpp"
#include "engine/models/text/tape.hpp"
#include "engine/models/text/text_model.hpp"

namespace riccati {

namespace {

using text::Ast;
using text::AstNode;
using text::CompiledModel;
using text::Entry;
using text::Expression;
using text::Graph;
using text::Op;
using text::Source;
using text::Tape;
using text::entries;
using text::name_list;
using text::number;
using text::parse;
using text::unit_of;
using text::valid_identifier;
using text::valid_model_name;

constexpr std::size_t kMaxDefines = 10000;

std::string sparsity_row(const Graph& graph, const std::vector<int>& jac, std::size_t row, std::size_t rows,
                         std::size_t nz) {
  std::string s;
  for (std::size_t j = 0; j < nz; ++j) s += graph.is_constant(jac[row + j * rows], 0.0) ? '.' : 'x';
  return s;
}

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
    std::shared_ptr<CompiledModel> m = text::new_compiled_model();
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

    // Second derivatives, d(df/dz_a)/dz_b at i + rows (a + nz b) (model_abi.h):
    // the Jacobians differentiated again. A model too large for them (more
    // than kMaxSecondDerivatives entries, or a graph past its bound) keeps its
    // Jacobians and goes without: maximum likelihood then differences, and
    // compiling an upload costs what it did.
    constexpr std::size_t kMaxSecondDerivatives = std::size_t{1} << 16;
    const bool second_derivatives_fit =
        static_cast<std::size_t>(m->nx + m->ny) * static_cast<std::size_t>(nz) * static_cast<std::size_t>(nz) <=
        kMaxSecondDerivatives;
    std::vector<int> f_hess, g_hess;
    for (int b = 0; b < nz && second_derivatives_fit && !graph_.overflowed(); ++b) {
      const std::vector<int> df = graph_.derivative(f_jac, b);
      const std::vector<int> dg = graph_.derivative(g_jac, b);
      f_hess.insert(f_hess.end(), df.begin(), df.end());
      g_hess.insert(g_hess.end(), dg.begin(), dg.end());
    }
    m->has_second_derivatives = second_derivatives_fit && !graph_.overflowed();

    // Tapes.
    const int num_inputs = nz + m->nu + 1;
    std::vector<int> f_all = f_roots, g_all = g_roots;
    f_all.insert(f_all.end(), f_jac.begin(), f_jac.end());
    g_all.insert(g_all.end(), g_jac.begin(), g_jac.end());
    m->f = Tape::compile(graph_, f_roots, num_inputs);
    m->g = Tape::compile(graph_, g_roots, num_inputs);
    m->f_jac = Tape::compile(graph_, f_all, num_inputs);
    m->g_jac = Tape::compile(graph_, g_all, num_inputs);
    if (m->has_second_derivatives) {
      f_all.insert(f_all.end(), f_hess.begin(), f_hess.end());
      g_all.insert(g_all.end(), g_hess.begin(), g_hess.end());
      m->f_hess = Tape::compile(graph_, f_all, num_inputs);
      m->g_hess = Tape::compile(graph_, g_all, num_inputs);
    }
    for (const Tape* tape : {&m->f, &m->g, &m->f_jac, &m->g_jac, &m->f_hess, &m->g_hess}) {
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
    summary.check_operations = text::check_operations(*m);

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
    summary.check_operations = text::check_operations(m);
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
