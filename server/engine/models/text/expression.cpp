#include "engine/models/text/expression.hpp"

#include <cctype>
#include <charconv>
#include <cmath>
#include <set>
#include <utility>

namespace riccati::text {

const std::vector<Function>& functions() {
  static const std::vector<Function> table = {
      {"sqrt", Op::kSqrt, 1},   {"exp", Op::kExp, 1},     {"log", Op::kLog, 1},     {"sin", Op::kSin, 1},
      {"cos", Op::kCos, 1},     {"tan", Op::kTan, 1},     {"asin", Op::kAsin, 1},   {"acos", Op::kAcos, 1},
      {"atan", Op::kAtan, 1},   {"atan2", Op::kAtan2, 2}, {"sinh", Op::kSinh, 1},   {"cosh", Op::kCosh, 1},
      {"tanh", Op::kTanh, 1},   {"abs", Op::kAbs, 1},     {"min", Op::kMin, 2},     {"max", Op::kMax, 2},
      {"sign", Op::kSign, 1},   {"pow", Op::kPow, 2},     {"hypot", Op::kHypot, 2}, {"sat", Op::kSat, 1},
      {"if", Op::kIf, 3},
  };
  return table;
}

const Function* find_function(std::string_view name) {
  for (const Function& f : functions()) {
    if (name == f.name) return &f;
  }
  return nullptr;
}

namespace {

bool is_name_start(char c) { return std::isalpha(static_cast<unsigned char>(c)) != 0 || c == '_'; }
bool is_name_char(char c) { return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_'; }

class Parser {
 public:
  Parser(std::string_view text, Ast* ast) : text_(text), ast_(ast) {}

  bool run(ExpressionError* error) {
    skip_space();
    if (pos_ == text_.size()) return fail(pos_, "empty expression", error);
    const int root = expression(0);
    if (root < 0) return report(error);
    skip_space();
    if (pos_ != text_.size()) {
      const char c = text_[pos_];
      if (c == ')') return fail(pos_, "unbalanced ')'", error);
      if (c == '=' ) return fail(pos_, "'=' is not an operator here (comparison is '==')", error);
      return fail(pos_, std::string("unexpected '") + c + "' after the end of the expression", error);
    }
    ast_->root = root;
    return true;
  }

 private:
  bool fail(std::size_t at, std::string message, ExpressionError* error) {
    error->offset = at;
    error->message = std::move(message);
    return false;
  }
  bool report(ExpressionError* error) {
    *error = error_;
    return false;
  }
  int set_error(std::size_t at, std::string message) {
    if (error_.message.empty()) error_ = {at, std::move(message)};
    return -1;
  }

  void skip_space() {
    while (pos_ < text_.size() && std::isspace(static_cast<unsigned char>(text_[pos_])) != 0) ++pos_;
  }
  bool accept(std::string_view token) {
    skip_space();
    if (text_.substr(pos_, token.size()) == token) {
      pos_ += token.size();
      return true;
    }
    return false;
  }

  int add(AstNode node) {
    if (ast_->nodes.size() >= kMaxNodes) {
      return set_error(node.offset, "the expression is too long (more than " + std::to_string(kMaxNodes) + " terms)");
    }
    ast_->nodes.push_back(std::move(node));
    return static_cast<int>(ast_->nodes.size() - 1);
  }
  int op(Op o, std::size_t at, std::vector<int> args) {
    AstNode n;
    n.kind = AstNode::Kind::kOp;
    n.op = o;
    n.offset = at;
    n.args = std::move(args);
    return add(std::move(n));
  }

  bool too_deep(int depth) {
    if (depth > kMaxDepth) {
      set_error(pos_, "the expression is nested too deeply (about " + std::to_string(kMaxDepth / 6) +
                          " levels of parentheses, calls or signs at most)");
      return true;
    }
    return false;
  }

  int expression(int depth) {
    if (too_deep(depth)) return -1;
    const int left = additive(depth + 1);
    if (left < 0) return -1;
    skip_space();
    const std::size_t at = pos_;
    Op o;
    if (accept("<=")) {
      o = Op::kLe;
    } else if (accept(">=")) {
      o = Op::kGe;
    } else if (accept("==")) {
      o = Op::kEq;
    } else if (accept("!=")) {
      o = Op::kNe;
    } else if (accept("<")) {
      o = Op::kLt;
    } else if (accept(">")) {
      o = Op::kGt;
    } else {
      return left;
    }
    const int right = additive(depth + 1);
    if (right < 0) return -1;
    skip_space();
    if (pos_ < text_.size() && (text_[pos_] == '<' || text_[pos_] == '>' || text_.substr(pos_, 2) == "==" ||
                                text_.substr(pos_, 2) == "!=")) {
      return set_error(pos_, "comparisons do not chain: write if(a < b, if(b < c, ...), ...)");
    }
    return op(o, at, {left, right});
  }

  int additive(int depth) {
    if (too_deep(depth)) return -1;
    int left = term(depth + 1);
    while (left >= 0) {
      skip_space();
      const std::size_t at = pos_;
      if (accept("+")) {
        const int right = term(depth + 1);
        if (right < 0) return -1;
        left = op(Op::kAdd, at, {left, right});
      } else if (accept("-")) {
        const int right = term(depth + 1);
        if (right < 0) return -1;
        left = op(Op::kSub, at, {left, right});
      } else {
        break;
      }
    }
    return left;
  }

  int term(int depth) {
    if (too_deep(depth)) return -1;
    int left = unary(depth + 1);
    while (left >= 0) {
      skip_space();
      const std::size_t at = pos_;
      if (accept("*")) {
        if (pos_ < text_.size() && text_[pos_] == '*') return set_error(at, "'**' is not an operator: write a^b");
        const int right = unary(depth + 1);
        if (right < 0) return -1;
        left = op(Op::kMul, at, {left, right});
      } else if (accept("/")) {
        const int right = unary(depth + 1);
        if (right < 0) return -1;
        left = op(Op::kDiv, at, {left, right});
      } else {
        break;
      }
    }
    return left;
  }

  int unary(int depth) {
    if (too_deep(depth)) return -1;
    skip_space();
    const std::size_t at = pos_;
    if (accept("-")) {
      const int a = unary(depth + 1);
      if (a < 0) return -1;
      return op(Op::kNeg, at, {a});
    }
    if (accept("+")) return unary(depth + 1);
    return power(depth + 1);
  }

  int power(int depth) {
    if (too_deep(depth)) return -1;
    const int base = primary(depth + 1);
    if (base < 0) return -1;
    skip_space();
    const std::size_t at = pos_;
    if (!accept("^")) return base;
    const int exponent = unary(depth + 1);
    if (exponent < 0) return -1;
    return op(Op::kPow, at, {base, exponent});
  }

  int primary(int depth) {
    if (too_deep(depth)) return -1;
    skip_space();
    const std::size_t at = pos_;
    if (pos_ == text_.size()) return set_error(pos_, "the expression ends where a number, a name or '(' is expected");
    const char c = text_[pos_];
    if (c == '(') {
      ++pos_;
      const int inner = expression(depth + 1);
      if (inner < 0) return -1;
      if (!accept(")")) return set_error(at, "this '(' is not closed");
      return inner;
    }
    if (std::isdigit(static_cast<unsigned char>(c)) != 0 || c == '.') return number();
    if (is_name_start(c)) {
      std::size_t end = pos_;
      while (end < text_.size() && is_name_char(text_[end])) ++end;
      const std::string name(text_.substr(pos_, end - pos_));
      pos_ = end;
      skip_space();
      if (pos_ < text_.size() && text_[pos_] == '(') {
        const Function* f = find_function(name);
        if (f == nullptr) {
          return set_error(at, "unknown function '" + name + "' (functions: " + function_list() + ")");
        }
        ++pos_;
        std::vector<int> args;
        skip_space();
        if (!(pos_ < text_.size() && text_[pos_] == ')')) {
          while (true) {
            const int a = expression(depth + 1);
            if (a < 0) return -1;
            args.push_back(a);
            if (accept(",")) continue;
            if (accept(")")) break;
            skip_space();
            return set_error(pos_, "expected ',' or ')' in the arguments of " + name);
          }
        } else {
          ++pos_;
        }
        if (static_cast<int>(args.size()) != f->arity) {
          return set_error(at, name + " takes " + std::to_string(f->arity) + " argument" +
                                   (f->arity == 1 ? "" : "s") + ", not " + std::to_string(args.size()));
        }
        return op(f->op, at, std::move(args));
      }
      if (find_function(name) != nullptr) return set_error(at, "'" + name + "' is a function: write " + name + "(...)");
      AstNode n;
      n.kind = AstNode::Kind::kName;
      n.name = name;
      n.offset = at;
      return add(std::move(n));
    }
    if (c == ')') return set_error(at, "unexpected ')': a number, a name or '(' is expected");
    return set_error(at, std::string("unexpected '") + c + "': a number, a name or '(' is expected");
  }

  int number() {
    const std::size_t at = pos_;
    std::size_t end = pos_;
    while (end < text_.size() && (std::isdigit(static_cast<unsigned char>(text_[end])) != 0 || text_[end] == '.')) ++end;
    if (end < text_.size() && (text_[end] == 'e' || text_[end] == 'E')) {
      std::size_t e = end + 1;
      if (e < text_.size() && (text_[e] == '+' || text_[e] == '-')) ++e;
      if (e < text_.size() && std::isdigit(static_cast<unsigned char>(text_[e])) != 0) {
        while (e < text_.size() && std::isdigit(static_cast<unsigned char>(text_[e])) != 0) ++e;
        end = e;
      }
    }
    double value = 0.0;
    const auto [ptr, ec] = std::from_chars(text_.data() + at, text_.data() + end, value);
    if (ec != std::errc() || ptr != text_.data() + end) {
      std::string message(text_.substr(at, end - at));
      message.append(" is not a number");
      return set_error(at, std::move(message));
    }
    if (!std::isfinite(value)) return set_error(at, "the number is too large for a double");
    pos_ = end;
    if (pos_ < text_.size() && is_name_start(text_[pos_])) {
      return set_error(pos_, "a name cannot follow a number: write 2*x, not 2x");
    }
    AstNode n;
    n.kind = AstNode::Kind::kNumber;
    n.number = value;
    n.offset = at;
    return add(std::move(n));
  }

  static std::string function_list() {
    std::string s;
    for (const Function& f : functions()) {
      if (!s.empty()) s.push_back(' ');
      s.append(f.name);
    }
    return s;
  }

  std::string_view text_;
  Ast* ast_;
  std::size_t pos_ = 0;
  ExpressionError error_;
};

}  // namespace

bool parse_expression(std::string_view text, Ast* ast, ExpressionError* error) {
  ast->nodes.clear();
  ast->root = -1;
  Parser parser(text, ast);
  return parser.run(error);
}

std::vector<std::pair<std::string, std::size_t>> referenced_names(const Ast& ast) {
  std::vector<std::pair<std::string, std::size_t>> names;
  std::set<std::string> seen;
  // Nodes are stored children first; their offsets order them in the text.
  for (const AstNode& n : ast.nodes) {
    if (n.kind == AstNode::Kind::kName && seen.insert(n.name).second) names.emplace_back(n.name, n.offset);
  }
  return names;
}

}  // namespace riccati::text
