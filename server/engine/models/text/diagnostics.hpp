// The diagnostics of a text model's source: every error names the file,
// line and column, and shows the line with a caret under the spot (Source);
// and the reading of the YAML around the expressions (mappings in document
// order, name lists with units, numbers, expressions parsed where they
// stand), each refusal through Source. Used by the compiler (compiler.hpp).
#pragma once

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cstddef>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "engine/models/text/expression.hpp"
#include "engine/status.hpp"

namespace riccati::text {

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

bool valid_identifier(const std::string& s);
bool valid_model_name(const std::string& s);  // a-z, 0-9 and _

// The entries of a YAML mapping in document order, keys as strings; a
// repeated key is an error (YAML forbids it, yaml-cpp keeps both).
struct Entry {
  std::string key;
  YAML::Node key_node;
  YAML::Node value;
};
Status entries(const Source& src, const YAML::Node& map, const std::string& what, std::vector<Entry>* out);

// A list of names: a sequence of names, or a mapping name -> attributes
// (unit, description: free text).
Status name_list(const Source& src, const YAML::Node& node, const std::string& what, std::vector<Entry>* out);

// The unit a name list's entry declares: `h1: m` or `h1: {unit: m}`; "" if none.
std::string unit_of(const Entry& e);

// A finite number, else an error at the node.
Result<double> number(const Source& src, const YAML::Node& node, const std::string& what);

// One expression of the file: where it is, its text and its tree.
struct Expression {
  std::string name;  // the state, output or helper it defines
  YAML::Node key;
  YAML::Node value;
  Ast ast;
};

// Parses the expression of entry `e` (`what` names its section in messages);
// a syntax error is placed at its character in the file.
Status parse(const Source& src, const Entry& e, const std::string& what, Expression* out);

}  // namespace riccati::text
