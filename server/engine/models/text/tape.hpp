// The compiled form of a text model: an expression graph, its symbolic
// derivatives, and flat instruction tapes evaluated without branches of
// control, loops or allocation.
//
// Graph: every node is (op, operands, constant), hash-consed, so a
// subexpression written twice (or reached through two helpers) is one node,
// and folded: an operation on constants is a constant, computed by the same
// apply() the tape runs, and x + 0, x * 1, x * 0, if(1, a, b) ... are
// simplified as they are built. Nodes are created children first, so their
// indices are a topological order.
//
// Derivatives are symbolic, into the same graph (derivative()), and
// differentiate again for second derivatives: forward-mode
// dual numbers over the tape would carry nz derivatives through every
// instruction, most of them zero (df/dtheta_j is zero in all rows but a
// few), while symbolic derivatives are folded to the structural zeros and
// shared with the values (d exp(a) reuses exp(a)); the same graph also gives
// the Jacobians' sparsity for `riccati models show`. Rules follow
// riccati/dual.hpp (the SDK's dual numbers) so that a text model and its C++
// plugin agree to rounding: d(a/b) = (da - (a/b) db) / b, min/max take the
// derivative of the argument chosen, |a|' = sign(a) (0 at 0). One difference:
// the chain rule f'(a) da is 0 where da is 0 even if f'(a) is infinite
// (sqrt(max(h, 0)) at h < 0), where a dual number would give NaN.
//
// Tape: the nodes an output needs, in index order, one instruction each,
// writing register (inputs + i); inputs (x, theta, u, t) are the first
// registers. Evaluation is one pass over the instructions: it cannot loop,
// and its memory is one register file per thread, sized at compile time.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "engine/models/text/expression.hpp"

namespace riccati::text {

inline constexpr std::size_t kMaxGraphNodes = 200000;

struct Node {
  Op op = Op::kConst;
  int a = -1, b = -1, c = -1;  // operands (node indices), -1 unused
  double k = 0.0;              // kConst: the value; kInput: the input slot
};

// The value of an operation on values (the one definition, used for folding
// and by the tape).
double apply(Op op, double a, double b, double c);

class Graph {
 public:
  int constant(double v);
  int input(int slot);
  int make(Op op, int a, int b = -1, int c = -1);

  const Node& node(int i) const { return nodes_[static_cast<std::size_t>(i)]; }
  std::size_t size() const { return nodes_.size(); }
  // Set when a node was refused because the graph reached kMaxGraphNodes;
  // the model is then refused as too large.
  bool overflowed() const { return overflowed_; }
  bool is_constant(int i, double v) const { return node(i).op == Op::kConst && node(i).k == v; }

  // d roots / d input `slot`, for each root: new nodes of this graph.
  std::vector<int> derivative(const std::vector<int>& roots, int slot);

 private:
  int intern(const Node& n);
  int simplify(Op op, int a, int b, int c);

  struct Key {
    Op op;
    int a, b, c;
    std::uint64_t k;
    bool operator==(const Key&) const = default;
  };
  struct KeyHash {
    std::size_t operator()(const Key& k) const;
  };
  std::vector<Node> nodes_;
  std::unordered_map<Key, int, KeyHash> index_;
  bool overflowed_ = false;
};

struct Instruction {
  Op op;
  std::uint32_t a, b, c;  // registers (constants have registers of their own: no immediate)
};

class Tape {
 public:
  // The instructions that compute `outputs` (nodes of `graph`) from inputs
  // [0, num_inputs); input nodes read their slot's register directly.
  static Tape compile(const Graph& graph, const std::vector<int>& outputs, int num_inputs);

  // Instructions, constants included.
  std::size_t length() const { return code_.size() + constants_.size(); }
  std::size_t registers() const { return static_cast<std::size_t>(num_inputs_) + constants_.size() + code_.size(); }
  std::size_t outputs() const { return outputs_.size(); }
  // Writes the constants into their registers (once per call: they stay
  // while only the inputs change, point after point).
  void load_constants(double* r) const {
    for (std::size_t i = 0; i < constants_.size(); ++i) r[static_cast<std::size_t>(num_inputs_) + i] = constants_[i];
  }
  // Runs the tape on `r` (registers(): the inputs filled in the first ones,
  // the constants loaded) and copies output i to out[i * stride].
  void run(double* r, double* out, std::size_t stride) const;
  // The same, outputs [0, split) to first and the rest to second.
  void run_split(double* r, std::size_t split, double* first, double* second) const;

  // The same on up to kLanes points at once (a UKF's sigma points): register
  // i holds point j at r[i * kLanes + j], so that each instruction is
  // dispatched once for all points and its loop over them vectorises.
  static constexpr std::size_t kLanes = 16;
  void load_constants_lanes(double* r) const {
    for (std::size_t i = 0; i < constants_.size(); ++i) {
      for (std::size_t j = 0; j < kLanes; ++j) r[(static_cast<std::size_t>(num_inputs_) + i) * kLanes + j] = constants_[i];
    }
  }
  // Runs `points` (<= kLanes) points; output i of point j to out[i * ld + j].
  void run_lanes(double* r, std::size_t points, double* out, std::size_t ld) const;

 private:
  std::vector<Instruction> code_;
  std::vector<double> constants_;       // registers num_inputs_ ...
  std::vector<std::uint32_t> outputs_;  // registers
  int num_inputs_ = 0;
};

}  // namespace riccati::text
