// The expressions of a text model (docs/text-models.md): a small
// recursive-descent parser into a syntax tree.
//
//   expression := additive [ ("<" | "<=" | ">" | ">=" | "==" | "!=") additive ]
//   additive   := term { ("+" | "-") term }
//   term       := unary { ("*" | "/") unary }
//   unary      := ("-" | "+") unary | power
//   power      := primary [ "^" unary ]            right-associative: 2^3^2 = 2^9
//   primary    := number | name | name "(" expression { "," expression } ")"
//               | "(" expression ")"
//
// -x^2 is -(x^2), as in mathematics. Nothing but these: no assignment, no
// loops, no strings; the callable names are the fixed table of functions().
// Parsing is bounded: nesting deeper than kMaxDepth and expressions of more
// than kMaxNodes nodes are refused, so a hostile file costs a bounded stack
// and memory.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace riccati::text {

// The operations of expressions, of the graph and of the tape (graph.hpp).
enum class Op : std::uint8_t {
  kConst,
  kInput,  // x, theta, u or t
  kAdd,
  kSub,
  kMul,
  kDiv,
  kNeg,
  kPow,
  kSqrt,
  kExp,
  kLog,
  kSin,
  kCos,
  kTan,
  kAsin,
  kAcos,
  kAtan,
  kAtan2,
  kSinh,
  kCosh,
  kTanh,
  kAbs,
  kSign,
  kMin,
  kMax,
  kHypot,
  kSat,
  kLt,
  kLe,
  kGt,
  kGe,
  kEq,
  kNe,
  kIf,     // if(c, a, b): a where c is not 0, else b
  kChain,  // chain(d, f'): f' * d, and 0 where d is 0 (derivatives only, never written)
  kNegMul,  // -(a * b): a product with a negated operand, fused on the tape (tapes only, never in a graph)
};

// A function callable in expressions.
struct Function {
  const char* name;
  Op op;
  int arity;
};
// sqrt exp log sin cos tan asin acos atan atan2 sinh cosh tanh abs min max
// sign pow hypot sat if.
const std::vector<Function>& functions();
const Function* find_function(std::string_view name);

struct AstNode {
  enum class Kind : std::uint8_t { kNumber, kName, kOp } kind = Kind::kNumber;
  Op op = Op::kConst;  // for kOp: the operation (operators and functions alike)
  double number = 0.0;
  std::string name;    // for kName
  std::vector<int> args;
  std::size_t offset = 0;  // where in the expression's text it starts (for messages)
};

struct Ast {
  std::vector<AstNode> nodes;
  int root = -1;
};

struct ExpressionError {
  std::size_t offset = 0;  // into the expression's text
  std::string message;
};

// Recursion levels of the parser: each pair of parentheses, function call or
// unary minus costs up to six, so about forty levels of nesting pass.
inline constexpr int kMaxDepth = 256;
inline constexpr std::size_t kMaxNodes = 20000;

// Parses `text` into `ast`; false with `error` set on a syntax error.
bool parse_expression(std::string_view text, Ast* ast, ExpressionError* error);

// The names an expression refers to (variables, not functions), each once,
// with the offset of its first use.
std::vector<std::pair<std::string, std::size_t>> referenced_names(const Ast& ast);

}  // namespace riccati::text
