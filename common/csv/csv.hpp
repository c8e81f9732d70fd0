// The one CSV reader of riccati: a text with a header row naming the
// columns, values separated by commas, read into the columns asked for, by
// name, as doubles. The engine reads uploaded datasets with it (parse_csv in
// server/engine/data/dataset.cpp), and the command line reads the local
// files that `riccati stream` replays and `riccati simulate` takes.
//
// What it accepts: a UTF-8 byte order mark, "\r\n" line ends, header names
// in double quotes (not containing commas), blanks around cells and header
// names (" F2" is F2), blank lines at the end, unnamed columns (which cannot
// be asked for), a header ending in a comma (rows may then leave that empty
// column out) and any text in the columns not asked for. Every cell asked for must be a finite number
// (a leading '+' is allowed). Errors name the source and the line, the
// column and the cell as written: `rig.csv line 5, column "h1": "abc" is not
// a number`.
//
// Standard library only: the engine and the command line link it without
// each other's dependencies.
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace riccati::csv {

// The selected columns, row by row: value c of row r (columns in the order
// asked for) is values[r * columns + c]. Viewed column-major, that is a
// columns x rows matrix with one sample per column.
struct Table {
  std::size_t columns = 0;
  std::vector<double> values;

  std::size_t rows() const { return columns == 0 ? 0 : values.size() / columns; }
  std::span<const double> row(std::size_t r) const { return {values.data() + r * columns, columns}; }
};

// Reads `text` (the contents of `source`, a name for messages) into `out`.
// Returns what is wrong, if anything.
std::optional<std::string> parse(std::string_view text, std::span<const std::string> select,
                                 const std::string& source, Table* out);

// Reads the file at `path`; messages name the path.
std::optional<std::string> read_file(const std::string& path, std::span<const std::string> select, Table* out);

}  // namespace riccati::csv
