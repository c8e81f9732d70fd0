// Models written as text (YAML, docs/text-models.md), compiled into a
// riccati_model_v1 table (model_abi.h) whose functions run instruction tapes
// (tape.hpp), so that Model::create takes a text model exactly as it takes a
// plugin, and every filter, identification, validation and smoothing runs
// on it unchanged. In three parts: the source's diagnostics (diagnostics.hpp),
// the compiler (compiler.cpp, which defines compile_text_model) and the
// runtime behind the table (runtime.hpp).
//
//   model: two_tank_text
//   states:     {h1: {unit: m}, h2: {unit: m}}
//   inputs:     {F1: {unit: m^3/s}, F2: {unit: m^3/s}}
//   parameters: {A1: {value: 10, min: 0}, k1: 0.0791, ...}
//   define:     {q1: k1 * sqrt(max(h1, 0)), ...}     helpers, in any order
//   der:        {h1: (F1 - q1) / A1, ...}              one per state
//   outputs:    {h1: h1, ...}
//
// Compiling is bounded (kMaxTextModelBytes, expression size and nesting in
// expression.hpp, kMaxGraphNodes in tape.hpp, at most kMaxTextModelSize
// states, parameters, inputs or outputs), so a file built to be slow is
// refused rather than run. Every error is INVALID_ARGUMENT naming the file,
// line and column, with the line and a caret under the spot.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "engine/models/model.hpp"
#include "engine/status.hpp"

namespace riccati {

inline constexpr std::size_t kMaxTextModelBytes = 256 * 1024;
inline constexpr std::size_t kMaxTextModelSize = 256;  // states, parameters, inputs, outputs each

// What `riccati models show` tells of a text model beyond its Model.
struct TextModelSummary {
  // "h1' = (F1 - q1) / A1", "q1 = k1 * sqrt(max(h1, 0))", "y h1 = h1": the
  // equations as written, der first, then outputs, then helpers.
  std::vector<std::string> equations;
  // The Jacobians' structure over z = [x; theta]: one string per row of
  // df/dz (then dg/dz), 'x' where the entry can be non-zero, '.' where it is
  // zero everywhere.
  std::vector<std::string> f_sparsity, g_sparsity;
  std::size_t graph_nodes = 0;  // after differentiation, shared
  std::size_t tape_length = 0;  // instructions of the f-and-Jacobian tape
  // What check_jacobians() at generic_points() costs, estimated from the
  // tapes' sizes (operations, about nanoseconds): what a service compares
  // with its bound before checking.
  double check_operations = 0.0;
};

struct TextModel {
  ModelPtr model;
  TextModelSummary summary;
};

// Compiles the YAML text of a model. `origin` names it in messages (a file
// name, or "upload"); the Model keeps the compiled tapes alive.
Result<TextModel> compile_text_model(std::string_view text, const std::string& origin);

}  // namespace riccati
