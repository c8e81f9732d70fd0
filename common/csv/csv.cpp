#include "csv/csv.hpp"

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <fstream>
#include <iterator>
#include <numeric>
#include <system_error>

namespace riccati::csv {
namespace {

constexpr std::string_view kUtf8Bom = "\xEF\xBB\xBF";

std::string in_quotes(std::string_view text) { return '"' + std::string(text) + '"'; }

// A cell as the user wrote it, cut short so a runaway cell cannot flood the message.
std::string cell_in_quotes(std::string_view cell) {
  constexpr std::size_t kMaxShown = 40;
  if (cell.size() > kMaxShown) return '"' + std::string(cell.substr(0, kMaxShown)) + "...\"";
  return in_quotes(cell);
}

std::string plural(std::size_t count, const char* noun) {
  return std::to_string(count) + " " + noun + (count == 1 ? "" : "s");
}

bool is_blank_char(char c) { return c == ' ' || c == '\t'; }

std::string_view trim(std::string_view text) {
  while (!text.empty() && is_blank_char(text.front())) text.remove_prefix(1);
  while (!text.empty() && is_blank_char(text.back())) text.remove_suffix(1);
  return text;
}

bool is_blank(std::string_view line) { return trim(line).empty(); }

// Yields the lines of a text without their "\n" or "\r\n", counting them from 1.
class LineReader {
 public:
  explicit LineReader(std::string_view text) : rest_(text) {}

  bool next(std::string_view& line) {
    if (rest_.empty()) return false;
    const std::size_t end = rest_.find('\n');
    line = rest_.substr(0, end);
    rest_ = end == std::string_view::npos ? std::string_view{} : rest_.substr(end + 1);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    ++number_;
    return true;
  }

  // 1-based number of the line last returned by next().
  std::size_t number() const { return number_; }

 private:
  std::string_view rest_;
  std::size_t number_ = 0;
};

// The comma-separated cells of one line, trimmed of blanks.
void split_cells(std::string_view line, std::vector<std::string_view>& cells) {
  cells.clear();
  for (;;) {
    const std::size_t end = line.find(',');
    cells.push_back(trim(line.substr(0, end)));
    if (end == std::string_view::npos) return;
    line.remove_prefix(end + 1);
  }
}

// A header name, without the double quotes spreadsheets like to add.
std::string_view unquote(std::string_view name) {
  if (name.size() >= 2 && name.front() == '"' && name.back() == '"') return trim(name.substr(1, name.size() - 2));
  return name;
}

enum class CellProblem { kNone, kEmpty, kNotANumber, kNotFinite, kOutOfRange };

CellProblem parse_cell(std::string_view cell, double& value) {
  if (cell.empty()) return CellProblem::kEmpty;
  // from_chars has no leading '+', but some writers emit one.
  if (cell.size() > 1 && cell.front() == '+' && cell[1] != '-' && cell[1] != '+') cell.remove_prefix(1);
  const char* end = cell.data() + cell.size();
  const auto [ptr, ec] = std::from_chars(cell.data(), end, value, std::chars_format::general);
  if (ec == std::errc::result_out_of_range) return CellProblem::kOutOfRange;
  if (ec != std::errc{} || ptr != end) return CellProblem::kNotANumber;
  if (!std::isfinite(value)) return CellProblem::kNotFinite;  // from_chars accepts "nan", "inf"
  return CellProblem::kNone;
}

std::string describe(CellProblem problem, std::string_view cell) {
  switch (problem) {
    case CellProblem::kEmpty: return "empty value";
    case CellProblem::kNotANumber: return cell_in_quotes(cell) + " is not a number";
    case CellProblem::kNotFinite: return cell_in_quotes(cell) + " is not a finite number";
    case CellProblem::kOutOfRange: return cell_in_quotes(cell) + " is out of the range of a double";
    case CellProblem::kNone: break;
  }
  return "no problem";
}

// The named columns (unnamed ones cannot be asked for, so are not offered).
std::string list_names(const std::vector<std::string_view>& names) {
  std::string list;
  for (const std::string_view name : names) {
    if (name.empty()) continue;
    if (!list.empty()) list += ", ";
    list += name;
  }
  return list;
}

}  // namespace

std::optional<std::string> parse(std::string_view text, std::span<const std::string> select,
                                 const std::string& source, Table* out) {
  if (text.starts_with(kUtf8Bom)) text.remove_prefix(kUtf8Bom.size());
  LineReader lines(text);
  std::string_view line;
  if (!lines.next(line) || is_blank(line)) return source + ": no header row (the first line must name the columns)";
  std::vector<std::string_view> header;
  split_cells(line, header);
  for (std::string_view& name : header) name = unquote(name);
  // A header ending in commas ("t,u,y,", as some spreadsheets write it):
  // rows may leave those unnamed columns out.
  std::size_t named_width = header.size();
  while (named_width > 0 && header[named_width - 1].empty()) --named_width;
  for (std::size_t a = 0; a < header.size(); ++a) {
    // Unnamed columns (a spreadsheet's index column) are allowed; they cannot be selected.
    if (header[a].empty()) continue;
    const auto again = std::find(header.begin() + static_cast<std::ptrdiff_t>(a) + 1, header.end(), header[a]);
    if (again != header.end()) {
      return source + " line 1: column name " + in_quotes(header[a]) + " appears twice (columns " +
             std::to_string(a + 1) + " and " + std::to_string(again - header.begin() + 1) + ")";
    }
  }

  // The header column of each selected one, and the order to read them in:
  // left to right, so the first bad cell of a line is the one reported.
  std::vector<std::size_t> column(select.size());
  for (std::size_t s = 0; s < select.size(); ++s) {
    const auto found = std::find(header.begin(), header.end(), select[s]);
    if (select[s].empty() || found == header.end()) {
      return source + ": missing column " + in_quotes(select[s]) + " (columns are: " + list_names(header) + ")";
    }
    column[s] = static_cast<std::size_t>(found - header.begin());
  }
  std::vector<std::size_t> order(select.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return column[a] < column[b]; });

  // Size the table once: every line up to the last non-blank one is a row.
  std::size_t num_rows = 0;
  for (LineReader scan = lines; scan.next(line);) {
    if (!is_blank(line)) num_rows = scan.number() - lines.number();
  }
  out->columns = select.size();
  out->values.assign(num_rows * select.size(), 0.0);

  std::vector<std::string_view> cells;
  for (std::size_t r = 0; r < num_rows; ++r) {
    lines.next(line);
    const auto at_line = [&] { return source + " line " + std::to_string(lines.number()); };
    if (is_blank(line)) return at_line() + ": blank line inside the data (only trailing blank lines are allowed)";
    split_cells(line, cells);
    if (cells.size() < named_width || cells.size() > header.size()) {
      const std::string expected = named_width == header.size()
                                       ? plural(header.size(), "value")
                                       : std::to_string(named_width) + " to " + plural(header.size(), "value");
      return at_line() + ": expected " + expected + ", found " + std::to_string(cells.size());
    }
    for (const std::size_t s : order) {
      const std::string_view cell = cells[column[s]];
      double& value = out->values[r * select.size() + s];
      if (const CellProblem problem = parse_cell(cell, value); problem != CellProblem::kNone) {
        return at_line() + ", column " + in_quotes(header[column[s]]) + ": " + describe(problem, cell);
      }
    }
  }
  return std::nullopt;
}

std::optional<std::string> read_file(const std::string& path, std::span<const std::string> select, Table* out) {
  errno = 0;
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return "cannot open " + in_quotes(path) + ": " + std::generic_category().message(errno != 0 ? errno : ENOENT);
  }
  const std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  if (in.bad()) return "cannot read " + in_quotes(path);
  return parse(text, select, path, out);
}

}  // namespace riccati::csv
