#include "engine/models/text/tape.hpp"

#include <bit>
#include <cmath>
#include <utility>

namespace riccati::text {

double apply(Op op, double a, double b, double c) {
  switch (op) {
    case Op::kConst:
    case Op::kInput:
      return a;
    case Op::kAdd: return a + b;
    case Op::kSub: return a - b;
    case Op::kMul: return a * b;
    case Op::kDiv: return a / b;
    case Op::kNeg: return -a;
    case Op::kPow: return std::pow(a, b);
    case Op::kSqrt: return std::sqrt(a);
    case Op::kExp: return std::exp(a);
    case Op::kLog: return std::log(a);
    case Op::kSin: return std::sin(a);
    case Op::kCos: return std::cos(a);
    case Op::kTan: return std::tan(a);
    case Op::kAsin: return std::asin(a);
    case Op::kAcos: return std::acos(a);
    case Op::kAtan: return std::atan(a);
    case Op::kAtan2: return std::atan2(a, b);
    case Op::kSinh: return std::sinh(a);
    case Op::kCosh: return std::cosh(a);
    case Op::kTanh: return std::tanh(a);
    case Op::kAbs: return std::abs(a);
    case Op::kSign: return a > 0 ? 1.0 : (a < 0 ? -1.0 : 0.0);
    case Op::kMin: return b < a ? b : a;  // as riccati::min: the first on a tie
    case Op::kMax: return a < b ? b : a;
    case Op::kHypot: return std::hypot(a, b);
    case Op::kSat: return a > 1.0 ? 1.0 : (a < -1.0 ? -1.0 : a);
    case Op::kLt: return a < b ? 1.0 : 0.0;
    case Op::kLe: return a <= b ? 1.0 : 0.0;
    case Op::kGt: return a > b ? 1.0 : 0.0;
    case Op::kGe: return a >= b ? 1.0 : 0.0;
    case Op::kEq: return a == b ? 1.0 : 0.0;
    case Op::kNe: return a != b ? 1.0 : 0.0;
    case Op::kIf: return a != 0.0 ? b : c;
    case Op::kChain: return a == 0.0 ? 0.0 : b * a;
    case Op::kNegMul: return -(a * b);
  }
  return a;
}

namespace {

int arity(Op op) {
  switch (op) {
    case Op::kConst:
    case Op::kInput:
      return 0;
    case Op::kAdd: case Op::kSub: case Op::kMul: case Op::kDiv: case Op::kPow: case Op::kAtan2:
    case Op::kMin: case Op::kMax: case Op::kHypot: case Op::kLt: case Op::kLe: case Op::kGt:
    case Op::kGe: case Op::kEq: case Op::kNe: case Op::kChain: case Op::kNegMul:
      return 2;
    case Op::kIf:
      return 3;
    default:
      return 1;
  }
}

bool commutative(Op op) {
  return op == Op::kAdd || op == Op::kMul || op == Op::kHypot || op == Op::kEq || op == Op::kNe;
}

}  // namespace

std::size_t Graph::KeyHash::operator()(const Key& k) const {
  std::uint64_t h = static_cast<std::uint64_t>(k.op);
  for (const std::uint64_t v : {static_cast<std::uint64_t>(static_cast<std::uint32_t>(k.a)),
                                static_cast<std::uint64_t>(static_cast<std::uint32_t>(k.b)),
                                static_cast<std::uint64_t>(static_cast<std::uint32_t>(k.c)), k.k}) {
    h ^= v + 0x9e3779b97f4a7c15ULL + (h << 6) + (h >> 2);
  }
  return static_cast<std::size_t>(h);
}

int Graph::intern(const Node& n) {
  const Key key{n.op, n.a, n.b, n.c, std::bit_cast<std::uint64_t>(n.k)};
  if (const auto it = index_.find(key); it != index_.end()) return it->second;
  if (nodes_.size() >= kMaxGraphNodes) {
    overflowed_ = true;
    return 0;  // a placeholder: the graph is refused as a whole
  }
  nodes_.push_back(n);
  const int i = static_cast<int>(nodes_.size() - 1);
  index_.emplace(key, i);
  return i;
}

int Graph::constant(double v) {
  if (v == 0.0) v = 0.0;  // -0 and 0 are one constant
  return intern(Node{Op::kConst, -1, -1, -1, v});
}

int Graph::input(int slot) { return intern(Node{Op::kInput, -1, -1, -1, static_cast<double>(slot)}); }

int Graph::make(Op op, int a, int b, int c) {
  if (overflowed_) return 0;
  if (commutative(op) && b < a) std::swap(a, b);
  return simplify(op, a, b, c);
}

int Graph::simplify(Op op, int a, int b, int c) {
  const int n = arity(op);
  const auto is_const = [&](int i) { return i >= 0 && node(i).op == Op::kConst; };
  // Folding: all operands constant.
  if ((n >= 1 && is_const(a)) && (n < 2 || is_const(b)) && (n < 3 || is_const(c))) {
    return constant(apply(op, node(a).k, n >= 2 ? node(b).k : 0.0, n >= 3 ? node(c).k : 0.0));
  }
  switch (op) {
    case Op::kAdd:
      if (is_constant(a, 0.0)) return b;
      if (is_constant(b, 0.0)) return a;
      break;
    case Op::kSub:
      if (is_constant(b, 0.0)) return a;
      if (is_constant(a, 0.0)) return make(Op::kNeg, b);
      break;
    case Op::kMul:
      if (is_constant(a, 0.0) || is_constant(b, 0.0)) return constant(0.0);
      if (is_constant(a, 1.0)) return b;
      if (is_constant(b, 1.0)) return a;
      if (is_constant(a, -1.0)) return make(Op::kNeg, b);
      if (is_constant(b, -1.0)) return make(Op::kNeg, a);
      break;
    case Op::kDiv:
      if (is_constant(a, 0.0)) return constant(0.0);
      if (is_constant(b, 1.0)) return a;
      break;
    case Op::kNeg:
      if (node(a).op == Op::kNeg) return node(a).a;
      break;
    case Op::kPow:
      if (is_constant(b, 1.0)) return a;
      break;
    case Op::kIf:
      if (is_const(a)) return node(a).k != 0.0 ? b : c;
      if (b == c) return b;
      break;
    case Op::kChain:
      if (is_constant(a, 0.0)) return constant(0.0);
      if (is_constant(a, 1.0)) return b;
      if (is_constant(b, 1.0)) return a;
      break;
    default:
      break;
  }
  return intern(Node{op, a, b, c, 0.0});
}

std::vector<int> Graph::derivative(const std::vector<int>& roots, int slot) {
  const std::size_t count = nodes_.size();
  std::vector<char> needed(count, 0);
  std::vector<int> stack;
  for (const int r : roots) {
    if (!needed[static_cast<std::size_t>(r)]) {
      needed[static_cast<std::size_t>(r)] = 1;
      stack.push_back(r);
    }
  }
  while (!stack.empty()) {
    const Node n = node(stack.back());
    stack.pop_back();
    for (const int child : {n.a, n.b, n.c}) {
      if (child >= 0 && !needed[static_cast<std::size_t>(child)]) {
        needed[static_cast<std::size_t>(child)] = 1;
        stack.push_back(child);
      }
    }
  }
  const int zero = constant(0.0);
  const int one = constant(1.0);
  std::vector<int> d(count, zero);
  auto add = [&](int x, int y) { return make(Op::kAdd, x, y); };
  auto sub = [&](int x, int y) { return make(Op::kSub, x, y); };
  auto mul = [&](int x, int y) { return make(Op::kMul, x, y); };
  auto div = [&](int x, int y) { return make(Op::kDiv, x, y); };
  auto chain = [&](int dx, int fprime) { return make(Op::kChain, dx, fprime); };
  for (std::size_t i = 0; i < count && !overflowed_; ++i) {
    if (!needed[i]) continue;
    const Node n = nodes_[i];
    const int self = static_cast<int>(i);
    const int da = n.a >= 0 ? d[static_cast<std::size_t>(n.a)] : zero;
    const int db = n.b >= 0 ? d[static_cast<std::size_t>(n.b)] : zero;
    const int dc = n.c >= 0 ? d[static_cast<std::size_t>(n.c)] : zero;
    if (n.op != Op::kInput && n.op != Op::kConst && da == zero && db == zero && dc == zero) continue;
    int r = zero;
    switch (n.op) {
      case Op::kConst: break;
      case Op::kInput: r = static_cast<int>(n.k) == slot ? one : zero; break;
      case Op::kAdd: r = add(da, db); break;
      case Op::kSub: r = sub(da, db); break;
      case Op::kMul: r = add(mul(da, n.b), mul(n.a, db)); break;
      case Op::kDiv: r = mul(sub(da, mul(self, db)), div(one, n.b)); break;  // (da - q db) / b, as Dual does
      case Op::kNeg: r = make(Op::kNeg, da); break;
      case Op::kPow:
        if (node(n.b).op == Op::kConst) {
          r = chain(da, mul(n.b, make(Op::kPow, n.a, constant(node(n.b).k - 1.0))));
        } else {
          const int base = chain(da, mul(n.b, make(Op::kPow, n.a, sub(n.b, one))));
          const int log_term = make(Op::kIf, make(Op::kGt, n.a, zero), mul(self, make(Op::kLog, n.a)), zero);
          r = add(base, chain(db, log_term));
        }
        break;
      case Op::kSqrt: r = chain(da, div(constant(0.5), self)); break;
      case Op::kExp: r = chain(da, self); break;
      case Op::kLog: r = chain(da, div(one, n.a)); break;
      case Op::kSin: r = chain(da, make(Op::kCos, n.a)); break;
      case Op::kCos: r = chain(da, make(Op::kNeg, make(Op::kSin, n.a))); break;
      case Op::kTan: r = chain(da, add(one, mul(self, self))); break;
      case Op::kAsin: r = chain(da, div(one, make(Op::kSqrt, sub(one, mul(n.a, n.a))))); break;
      case Op::kAcos: r = chain(da, make(Op::kNeg, div(one, make(Op::kSqrt, sub(one, mul(n.a, n.a)))))); break;
      case Op::kAtan: r = chain(da, div(one, add(one, mul(n.a, n.a)))); break;
      case Op::kAtan2:  // atan2(y, x)' = (x dy - y dx) / (x^2 + y^2)
        r = div(sub(mul(n.b, da), mul(n.a, db)), add(mul(n.b, n.b), mul(n.a, n.a)));
        break;
      case Op::kSinh: r = chain(da, make(Op::kCosh, n.a)); break;
      case Op::kCosh: r = chain(da, make(Op::kSinh, n.a)); break;
      case Op::kTanh: r = chain(da, sub(one, mul(self, self))); break;
      case Op::kAbs: r = chain(da, make(Op::kSign, n.a)); break;
      case Op::kHypot: r = div(add(mul(n.a, da), mul(n.b, db)), self); break;
      case Op::kMin: r = make(Op::kIf, make(Op::kLt, n.b, n.a), db, da); break;
      case Op::kMax: r = make(Op::kIf, make(Op::kLt, n.a, n.b), db, da); break;
      case Op::kSat:
        r = make(Op::kIf, make(Op::kGt, n.a, one), zero, make(Op::kIf, make(Op::kLt, n.a, constant(-1.0)), zero, da));
        break;
      case Op::kIf: r = make(Op::kIf, n.a, db, dc); break;
      // A derivative differentiated again (second derivatives): f' d' + d f'',
      // each term zero where its factor of d is.
      case Op::kChain: r = add(chain(da, n.b), chain(n.a, db)); break;
      case Op::kSign: case Op::kLt: case Op::kLe: case Op::kGt: case Op::kGe: case Op::kEq: case Op::kNe:
      case Op::kNegMul:   // made by Tape::compile, never in a graph
        break;
    }
    d[i] = r;
  }
  std::vector<int> out;
  out.reserve(roots.size());
  for (const int r : roots) out.push_back(d[static_cast<std::size_t>(r)]);
  return out;
}

namespace {

// A negation read by a sum, a difference or a product is folded into it
// (x + -y is x - y, x - -y is x + y, -x * y is -(x y)): derivatives are full
// of them (d(a/b)/db = -(a/b) / b), and each is an instruction of a tape that
// runs at a few ns an instruction. The results are the same to the bit:
// IEEE 754 defines x - y as x + (-y), and negation is exact.
struct Folded {
  Op op;
  int a, b;
};

Folded fold_negations(const Graph& graph, const Node& n) {
  const auto negated = [&](int i) { return i >= 0 && graph.node(i).op == Op::kNeg; };
  const auto inner = [&](int i) { return graph.node(i).a; };
  const bool na = negated(n.a), nb = negated(n.b);
  switch (n.op) {
    case Op::kMul:
      if (na && nb) return {Op::kMul, inner(n.a), inner(n.b)};
      if (na) return {Op::kNegMul, inner(n.a), n.b};
      if (nb) return {Op::kNegMul, n.a, inner(n.b)};
      break;
    case Op::kAdd:
      if (nb && !na) return {Op::kSub, n.a, inner(n.b)};
      if (na && !nb) return {Op::kSub, n.b, inner(n.a)};
      break;
    case Op::kSub:
      if (nb) return {Op::kAdd, n.a, inner(n.b)};
      break;
    default:
      break;
  }
  return {n.op, n.a, n.b};
}

}  // namespace

Tape Tape::compile(const Graph& graph, const std::vector<int>& outputs, int num_inputs) {
  Tape tape;
  tape.num_inputs_ = num_inputs;
  std::vector<char> needed(graph.size(), 0);
  std::vector<int> stack(outputs.begin(), outputs.end());
  for (const int o : outputs) needed[static_cast<std::size_t>(o)] = 1;
  while (!stack.empty()) {
    const Node& n = graph.node(stack.back());
    stack.pop_back();
    const Folded f = fold_negations(graph, n);  // a folded negation is needed only if read elsewhere
    for (const int child : {f.a, f.b, n.c}) {
      if (child >= 0 && !needed[static_cast<std::size_t>(child)]) {
        needed[static_cast<std::size_t>(child)] = 1;
        stack.push_back(child);
      }
    }
  }
  // A quotient a / b whose reciprocal 1 / b the tape computes anyway (a
  // derivative of a / b needs it) is a * (1 / b): one division instead of
  // two, and the value the SDK's dual numbers compute for a / b, so that a
  // text model's Jacobian call gives its plugin's values to the bit there.
  std::unordered_map<int, int> reciprocal;  // b -> the node 1 / b
  for (std::size_t i = 0; i < graph.size(); ++i) {
    const Node& n = graph.node(static_cast<int>(i));
    if (needed[i] && n.op == Op::kDiv && graph.is_constant(n.a, 1.0)) reciprocal.emplace(n.b, static_cast<int>(i));
  }
  std::vector<std::uint32_t> reg(graph.size(), 0);
  for (std::size_t i = 0; i < graph.size(); ++i) {  // constants first: registers of their own
    const Node& n = graph.node(static_cast<int>(i));
    if (!needed[i] || n.op != Op::kConst) continue;
    reg[i] = static_cast<std::uint32_t>(num_inputs) + static_cast<std::uint32_t>(tape.constants_.size());
    tape.constants_.push_back(n.k);
  }
  const auto first = static_cast<std::uint32_t>(num_inputs) + static_cast<std::uint32_t>(tape.constants_.size());
  std::vector<char> emitted(graph.size(), 0);
  // Nodes in index order (children first), except that a reciprocal is
  // emitted ahead of the quotient that reads it (its own operands, 1 and b,
  // come before that quotient too).
  const auto emit = [&](std::size_t i, Folded f, const Node& n) {
    Instruction in{f.op, 0, 0, 0};
    if (f.a >= 0) in.a = reg[static_cast<std::size_t>(f.a)];
    if (f.b >= 0) in.b = reg[static_cast<std::size_t>(f.b)];
    if (n.c >= 0) in.c = reg[static_cast<std::size_t>(n.c)];
    reg[i] = first + static_cast<std::uint32_t>(tape.code_.size());
    tape.code_.push_back(in);
    emitted[i] = 1;
  };
  for (std::size_t i = 0; i < graph.size(); ++i) {
    if (!needed[i] || emitted[i]) continue;
    const Node& n = graph.node(static_cast<int>(i));
    if (n.op == Op::kConst) continue;
    if (n.op == Op::kInput) {
      reg[i] = static_cast<std::uint32_t>(n.k);
      continue;
    }
    Folded f = fold_negations(graph, n);
    if (f.op == Op::kDiv && !graph.is_constant(f.a, 1.0)) {
      if (const auto inv = reciprocal.find(f.b); inv != reciprocal.end()) {
        const auto k = static_cast<std::size_t>(inv->second);
        if (!emitted[k]) emit(k, fold_negations(graph, graph.node(inv->second)), graph.node(inv->second));
        f = {Op::kMul, f.a, inv->second};
      }
    }
    emit(i, f, n);
  }
  for (const int o : outputs) tape.outputs_.push_back(reg[static_cast<std::size_t>(o)]);
  return tape;
}

// One switch over the common operations, inlined; the rest through
// apply(). Each instruction reads what an earlier one stored, so a tape runs
// at about the latency of store-to-load forwarding per instruction
// (docs/benchmarks-log.md: about 2 ns); a computed goto was tried and gained
// nothing measurable.
void Tape::run_split(double* r, std::size_t split, double* first, double* second) const {
  run(r, nullptr, 0);
  for (std::size_t i = 0; i < split; ++i) first[i] = r[outputs_[i]];
  for (std::size_t i = split; i < outputs_.size(); ++i) second[i - split] = r[outputs_[i]];
}

void Tape::run(double* r, double* out, std::size_t stride) const {
  double* w = r + num_inputs_ + constants_.size();
  for (const Instruction& in : code_) {
    const double a = r[in.a];
    double v;
    switch (in.op) {
      case Op::kAdd: v = a + r[in.b]; break;
      case Op::kSub: v = a - r[in.b]; break;
      case Op::kMul: v = a * r[in.b]; break;
      case Op::kDiv: v = a / r[in.b]; break;
      case Op::kNeg: v = -a; break;
      case Op::kSqrt: v = std::sqrt(a); break;
      case Op::kIf: v = a != 0.0 ? r[in.b] : r[in.c]; break;
      case Op::kChain: v = a == 0.0 ? 0.0 : r[in.b] * a; break;
      case Op::kNegMul: v = -(a * r[in.b]); break;
      case Op::kGt: v = a > r[in.b] ? 1.0 : 0.0; break;
      case Op::kLt: v = a < r[in.b] ? 1.0 : 0.0; break;
      case Op::kSin: v = std::sin(a); break;
      case Op::kCos: v = std::cos(a); break;
      case Op::kExp: v = std::exp(a); break;
      case Op::kTanh: v = std::tanh(a); break;
      default: v = apply(in.op, a, r[in.b], r[in.c]); break;
    }
    *w++ = v;
  }
  if (out == nullptr) return;
  for (std::size_t i = 0; i < outputs_.size(); ++i) out[i * stride] = r[outputs_[i]];
}

namespace {

// One operation over the lanes of a register. The register written comes
// after every register read (no overlap, as __restrict says), which lets the
// loop vectorise.
template <typename F>
[[gnu::always_inline]] inline void each_lane(double* __restrict v, const double* __restrict a,
                                             const double* __restrict b, const double* __restrict c, F f) {
  for (std::size_t j = 0; j < Tape::kLanes; ++j) v[j] = f(a[j], b[j], c[j]);
}

}  // namespace

void Tape::run_lanes(double* r, std::size_t points, double* out, std::size_t ld) const {
  constexpr std::size_t L = kLanes;
  std::size_t w = (static_cast<std::size_t>(num_inputs_) + constants_.size()) * L;
  for (const Instruction& in : code_) {
    const double* a = r + std::size_t{in.a} * L;
    const double* b = r + std::size_t{in.b} * L;
    const double* c = r + std::size_t{in.c} * L;
    double* v = r + w;
    switch (in.op) {
      case Op::kAdd: each_lane(v, a, b, c, [](double x, double y, double) { return x + y; }); break;
      case Op::kSub: each_lane(v, a, b, c, [](double x, double y, double) { return x - y; }); break;
      case Op::kMul: each_lane(v, a, b, c, [](double x, double y, double) { return x * y; }); break;
      case Op::kDiv: each_lane(v, a, b, c, [](double x, double y, double) { return x / y; }); break;
      case Op::kNeg: each_lane(v, a, b, c, [](double x, double, double) { return -x; }); break;
      case Op::kNegMul: each_lane(v, a, b, c, [](double x, double y, double) { return -(x * y); }); break;
      case Op::kSqrt: each_lane(v, a, b, c, [](double x, double, double) { return std::sqrt(x); }); break;
      case Op::kChain: each_lane(v, a, b, c, [](double x, double y, double) { return x == 0.0 ? 0.0 : y * x; }); break;
      case Op::kIf: each_lane(v, a, b, c, [](double x, double y, double z) { return x != 0.0 ? y : z; }); break;
      case Op::kGt: each_lane(v, a, b, c, [](double x, double y, double) { return x > y ? 1.0 : 0.0; }); break;
      case Op::kLt: each_lane(v, a, b, c, [](double x, double y, double) { return x < y ? 1.0 : 0.0; }); break;
      default: for (std::size_t j = 0; j < points; ++j) v[j] = apply(in.op, a[j], b[j], c[j]); break;
    }
    w += L;
  }
  for (std::size_t i = 0; i < outputs_.size(); ++i) {
    const double* o = r + std::size_t{outputs_[i]} * L;
    for (std::size_t j = 0; j < points; ++j) out[i * ld + j] = o[j];
  }
}

}  // namespace riccati::text
