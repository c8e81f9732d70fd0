#include "engine/data/dataset.hpp"

#include <matio.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "engine/data/mat_screen.hpp"

namespace riccati {
namespace {

using Eigen::Index;

// ---------------------------------------------------------------- messages

// Shortest text that reads back as the same double: "11", "0.1", "1e-07".
std::string format_number(double value) {
  if (std::isnan(value)) return "NaN";
  std::array<char, 32> buffer{};  // 24 characters hold any double
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  return {buffer.data(), result.ptr};
}

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

// ---------------------------------------------------------------- CSV text

constexpr std::string_view kUtf8Bom = "\xEF\xBB\xBF";

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

// Yields the comma-separated cells of one line, trimmed of blanks.
class CellReader {
 public:
  explicit CellReader(std::string_view line) : rest_(line) {}

  std::string_view next() {
    const std::size_t end = rest_.find(',');
    const std::string_view cell = rest_.substr(0, end);
    rest_ = end == std::string_view::npos ? std::string_view{} : rest_.substr(end + 1);
    return trim(cell);
  }

 private:
  std::string_view rest_;
};

std::size_t count_cells(std::string_view line) {
  return static_cast<std::size_t>(std::count(line.begin(), line.end(), ',')) + 1;
}

// A header name, without the double quotes spreadsheets like to add.
// (Quoted names containing commas are not supported.)
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

// The mapping lists time, then inputs, then outputs; `slot` indexes that list.
struct MappingSlots {
  const ColumnMapping& mapping;

  std::size_t size() const { return 1 + mapping.inputs.size() + mapping.outputs.size(); }

  const std::string& name(std::size_t slot) const {
    if (slot == 0) return mapping.time;
    if (slot <= mapping.inputs.size()) return mapping.inputs[slot - 1];
    return mapping.outputs[slot - 1 - mapping.inputs.size()];
  }

  std::string role(std::size_t slot) const {
    if (slot == 0) return "time";
    if (slot <= mapping.inputs.size()) return "input " + std::to_string(slot);
    return "output " + std::to_string(slot - mapping.inputs.size());
  }
};

Status check_mapping(const ColumnMapping& mapping, const std::string& source) {
  if (mapping.outputs.empty()) {
    return invalid_argument(source + ": the column mapping names no outputs (at least one measured output is needed)");
  }
  const MappingSlots slots{mapping};
  for (std::size_t a = 0; a < slots.size(); ++a) {
    if (slots.name(a).empty()) {
      return invalid_argument(source + ": the column mapping gives no column name for " + slots.role(a));
    }
    for (std::size_t b = a + 1; b < slots.size(); ++b) {
      if (slots.name(a) == slots.name(b)) {
        return invalid_argument(source + ": column " + in_quotes(slots.name(a)) + " is requested twice in the column mapping (as " +
                                slots.role(a) + " and " + slots.role(b) + ")");
      }
    }
  }
  return Status::ok();
}

// Where a selected column of the file goes in the Dataset.
struct Destination {
  enum class Kind { kIgnored, kTime, kInput, kOutput };
  Kind kind = Kind::kIgnored;
  Index row = 0;
};

std::string list_names(const std::vector<std::string_view>& names) {
  std::string list;
  for (const std::string_view name : names) {
    if (!list.empty()) list += ", ";
    list += name;
  }
  return list;
}

// ---------------------------------------------------------------- files

std::string base_name(const std::string& path) { return std::filesystem::path(path).filename().string(); }

Status open_error(const std::string& path, int error_number) {
  std::string message = "cannot open " + in_quotes(path) + ": " + std::generic_category().message(error_number);
  return error_number == ENOENT ? not_found(std::move(message)) : invalid_argument(std::move(message));
}

Result<std::string> read_whole_file(const std::string& path) {
  errno = 0;
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) return open_error(path, errno != 0 ? errno : ENOENT);
  const std::streamoff size = in.tellg();
  if (size < 0) return invalid_argument("cannot read " + in_quotes(path));
  std::string text(static_cast<std::size_t>(size), '\0');
  in.seekg(0);
  if (!in.read(text.data(), size)) return invalid_argument("cannot read " + in_quotes(path) + " (is it a directory?)");
  return text;
}

// ---------------------------------------------------------------- MAT files

struct MatFileCloser {
  void operator()(mat_t* mat) const { Mat_Close(mat); }
};
struct MatVarFreer {
  void operator()(matvar_t* var) const { Mat_VarFree(var); }
};
using MatFile = std::unique_ptr<mat_t, MatFileCloser>;
using MatVar = std::unique_ptr<matvar_t, MatVarFreer>;

std::string dims_text(const matvar_t& var) {
  std::string text;
  for (int k = 0; k < var.rank; ++k) {
    if (k > 0) text += " x ";
    text += std::to_string(var.dims[k]);
  }
  return text;
}

// Number of values, or SIZE_MAX if the dimensions of a corrupt file overflow.
std::size_t element_count(const matvar_t& var) {
  constexpr std::size_t kMax = std::numeric_limits<std::size_t>::max();
  std::size_t count = 1;
  for (int k = 0; k < var.rank; ++k) {
    if (var.dims[k] != 0 && count > kMax / var.dims[k]) return kMax;
    count *= var.dims[k];
  }
  return count;
}

// Reads a variable that the screen kept and checked (a real double matrix
// whose values fit in the file); only what matio makes of the data is left
// to check.
Result<MatVar> read_double_matrix(mat_t* mat, const char* name, const std::string& source) {
  MatVar var(Mat_VarRead(mat, name));
  const std::size_t count = var == nullptr ? 0 : element_count(*var);
  if (var == nullptr || var->class_type != MAT_C_DOUBLE || var->isComplex || var->rank != 2 ||
      (count > 0 && (var->data == nullptr || var->nbytes < count * sizeof(double)))) {
    return invalid_argument(source + ": variable " + in_quotes(name) + " cannot be read (is the file truncated or corrupt?)");
  }
  return var;
}

// matio opens files by name only: the screened copy of an upload goes to an
// anonymous in-memory file, named through /proc/self/fd.
class MemoryFile {
 public:
  static Result<MemoryFile> holding(std::string_view bytes) {
    MemoryFile file(memfd_create("riccati-mat", MFD_CLOEXEC));
    if (file.fd_ < 0) return internal_error(std::string("cannot create an in-memory file: ") + std::strerror(errno));
    for (std::size_t done = 0; done < bytes.size();) {
      const ssize_t n = write(file.fd_, bytes.data() + done, bytes.size() - done);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) return internal_error(std::string("cannot write an in-memory file: ") + std::strerror(errno));
      done += static_cast<std::size_t>(n);
    }
    return file;
  }
  MemoryFile(MemoryFile&& other) noexcept : fd_(std::exchange(other.fd_, -1)) {}
  MemoryFile& operator=(MemoryFile&&) = delete;
  MemoryFile(const MemoryFile&) = delete;
  MemoryFile& operator=(const MemoryFile&) = delete;
  ~MemoryFile() {
    if (fd_ >= 0) close(fd_);
  }
  std::string path() const { return "/proc/self/fd/" + std::to_string(fd_); }

 private:
  explicit MemoryFile(int fd) : fd_(fd) {}
  int fd_;
};

// Checks that U or Y is [rows x num_samples], one column per sample.
Status check_columns(const matvar_t& var, const char* name, std::size_t num_samples, const std::string& source) {
  if (var.dims[1] == num_samples) return Status::ok();
  const bool transposed = var.dims[0] == num_samples;
  return invalid_argument(source + ": variable " + in_quotes(name) + " is " + dims_text(var) + " but T has " +
                          plural(num_samples, "sample") + "; expected one column per sample" +
                          (transposed ? " (is it transposed?)" : ""));
}

Result<std::vector<std::string>> signal_names(const std::vector<std::string>& mapped, Index count, const char* prefix,
                                              const char* kind, const char* variable, const std::string& source) {
  if (mapped.empty()) {
    std::vector<std::string> names;
    names.reserve(static_cast<std::size_t>(count));
    for (Index k = 1; k <= count; ++k) names.push_back(prefix + std::to_string(k));
    return names;
  }
  if (static_cast<Index>(mapped.size()) != count) {
    return invalid_argument(source + ": the column mapping names " + plural(mapped.size(), kind) + " but " + variable +
                            " has " + plural(static_cast<std::size_t>(count), "row"));
  }
  return mapped;
}

Eigen::Map<const Eigen::MatrixXd> as_matrix(const matvar_t& var) {
  return {static_cast<const double*>(var.data), static_cast<Index>(var.dims[0]), static_cast<Index>(var.dims[1])};
}

}  // namespace

Status validate_dataset(const Dataset& data) {
  const auto fail = [&data](const std::string& message) {
    return invalid_argument(data.name.empty() ? message : data.name + ": " + message);
  };
  const Index num_samples = data.t.size();
  if (data.u.cols() != num_samples || data.y.cols() != num_samples) {
    return fail("inconsistent sizes: " + std::to_string(num_samples) + " times, " + std::to_string(data.u.cols()) +
                " input samples, " + std::to_string(data.y.cols()) + " output samples");
  }
  if (static_cast<Index>(data.input_names.size()) != data.u.rows()) {
    return fail(plural(data.input_names.size(), "input name") + " for " +
                plural(static_cast<std::size_t>(data.u.rows()), "input"));
  }
  if (static_cast<Index>(data.output_names.size()) != data.y.rows()) {
    return fail(plural(data.output_names.size(), "output name") + " for " +
                plural(static_cast<std::size_t>(data.y.rows()), "output"));
  }
  if (num_samples < 2) return fail("at least 2 samples are needed, found " + std::to_string(num_samples));

  const auto where = [&data](Index j) {
    return "sample " + std::to_string(j + 1) + " (t = " + format_number(data.t(j)) + ")";
  };
  for (Index j = 0; j < num_samples; ++j) {
    const double t = data.t(j);
    if (!std::isfinite(t)) return fail("time is " + format_number(t) + " at sample " + std::to_string(j + 1));
    if (j > 0 && !(t > data.t(j - 1))) {
      return fail("time goes backwards (or repeats) at sample " + std::to_string(j + 1) + ": t = " + format_number(t) +
                  " after t = " + format_number(data.t(j - 1)));
    }
    for (Index i = 0; i < data.u.rows(); ++i) {
      if (!std::isfinite(data.u(i, j))) {
        return fail("input " + in_quotes(data.input_names[i]) + " is " + format_number(data.u(i, j)) + " at " + where(j));
      }
    }
    for (Index i = 0; i < data.y.rows(); ++i) {
      if (!std::isfinite(data.y(i, j))) {
        return fail("output " + in_quotes(data.output_names[i]) + " is " + format_number(data.y(i, j)) + " at " + where(j));
      }
    }
  }
  return Status::ok();
}

Result<Dataset> parse_csv(std::string_view text, const ColumnMapping& mapping, std::string source_name) {
  Dataset data;
  data.name = std::move(source_name);
  const std::string& source = data.name;
  RICCATI_RETURN_IF_ERROR(check_mapping(mapping, source));
  if (text.starts_with(kUtf8Bom)) text.remove_prefix(kUtf8Bom.size());

  LineReader lines(text);
  std::string_view line;
  if (!lines.next(line) || is_blank(line)) {
    return invalid_argument(source + ": no header row (the first line must name the columns)");
  }
  std::vector<std::string_view> header(count_cells(line));
  CellReader header_cells(line);
  for (std::string_view& name : header) name = unquote(header_cells.next());
  for (std::size_t a = 0; a < header.size(); ++a) {
    // Unnamed columns (a spreadsheet's index column) are allowed; they cannot be selected.
    if (header[a].empty()) continue;
    const auto again = std::find(header.begin() + static_cast<std::ptrdiff_t>(a) + 1, header.end(), header[a]);
    if (again != header.end()) {
      return invalid_argument(source + " line 1: column name " + in_quotes(header[a]) + " appears twice (columns " +
                              std::to_string(a + 1) + " and " + std::to_string(again - header.begin() + 1) + ")");
    }
  }

  std::vector<Destination> destinations(header.size());
  const MappingSlots slots{mapping};
  for (std::size_t slot = 0; slot < slots.size(); ++slot) {
    const auto column = std::find(header.begin(), header.end(), slots.name(slot));
    if (column == header.end()) {
      return invalid_argument(source + ": missing column " + in_quotes(slots.name(slot)) + " (columns are: " +
                              list_names(header) + ")");
    }
    Destination& destination = destinations[static_cast<std::size_t>(column - header.begin())];
    if (slot == 0) {
      destination = {Destination::Kind::kTime, 0};
    } else if (slot <= mapping.inputs.size()) {
      destination = {Destination::Kind::kInput, static_cast<Index>(slot - 1)};
    } else {
      destination = {Destination::Kind::kOutput, static_cast<Index>(slot - 1 - mapping.inputs.size())};
    }
  }

  // Size the matrices once: every line up to the last non-blank one is a sample.
  Index num_samples = 0;
  for (LineReader scan = lines; scan.next(line);) {
    if (!is_blank(line)) num_samples = static_cast<Index>(scan.number() - lines.number());
  }
  data.t.resize(num_samples);
  data.u.resize(static_cast<Index>(mapping.inputs.size()), num_samples);
  data.y.resize(static_cast<Index>(mapping.outputs.size()), num_samples);

  for (Index j = 0; j < num_samples; ++j) {
    lines.next(line);
    const auto at_line = [&] { return source + " line " + std::to_string(lines.number()); };
    if (is_blank(line)) return invalid_argument(at_line() + ": blank line inside the data (only trailing blank lines are allowed)");
    const std::size_t found = count_cells(line);
    if (found != header.size()) {
      return invalid_argument(at_line() + ": expected " + plural(header.size(), "value") + ", found " + std::to_string(found));
    }
    CellReader cells(line);
    for (std::size_t c = 0; c < header.size(); ++c) {
      const std::string_view cell = cells.next();
      const Destination& destination = destinations[c];
      if (destination.kind == Destination::Kind::kIgnored) continue;  // may hold anything, even text
      double value = 0.0;
      const CellProblem problem = parse_cell(cell, value);
      if (problem != CellProblem::kNone) {
        return invalid_argument(at_line() + ", column " + in_quotes(header[c]) + ": " + describe(problem, cell));
      }
      switch (destination.kind) {
        case Destination::Kind::kTime: data.t(j) = value; break;
        case Destination::Kind::kInput: data.u(destination.row, j) = value; break;
        case Destination::Kind::kOutput: data.y(destination.row, j) = value; break;
        case Destination::Kind::kIgnored: break;
      }
    }
  }

  data.input_names = mapping.inputs;
  data.output_names = mapping.outputs;
  RICCATI_RETURN_IF_ERROR(validate_dataset(data));
  return data;
}

Result<Dataset> read_csv_file(const std::string& path, const ColumnMapping& mapping) {
  RICCATI_ASSIGN_OR_RETURN(const std::string text, read_whole_file(path));
  return parse_csv(text, mapping, base_name(path));
}

Result<Dataset> parse_mat(std::string_view bytes, const ColumnMapping& mapping, std::string source_name,
                          std::uint64_t max_value_bytes) {
  Dataset data;
  data.name = std::move(source_name);
  const std::string& source = data.name;
  RICCATI_ASSIGN_OR_RETURN(const ScreenedMatFile screened,
                           screen_mat_file(bytes, {"T", "U", "Y"}, source, max_value_bytes));
  const auto has = [&screened](const char* name) {
    return std::find(screened.found.begin(), screened.found.end(), name) != screened.found.end();
  };
  for (const char* name : {"T", "Y"}) {
    if (!has(name)) {
      return invalid_argument(source + ": missing variable " + in_quotes(name) +
                              " (expected T [1 x N], Y [ny x N] and optionally U [nu x N])");
    }
  }
  RICCATI_ASSIGN_OR_RETURN(const MemoryFile file, MemoryFile::holding(screened.bytes));
  const MatFile mat(Mat_Open(file.path().c_str(), MAT_ACC_RDONLY));
  if (mat == nullptr) return invalid_argument(source + ": matio cannot open it (is the file corrupt?)");

  RICCATI_ASSIGN_OR_RETURN(const MatVar time, read_double_matrix(mat.get(), "T", source));
  if (time->dims[0] != 1 && time->dims[1] != 1) {
    return invalid_argument(source + ": variable \"T\" must be a vector [1 x N], found " + dims_text(*time));
  }
  const std::size_t num_samples = element_count(*time);

  RICCATI_ASSIGN_OR_RETURN(const MatVar outputs, read_double_matrix(mat.get(), "Y", source));
  if (element_count(*outputs) == 0) return invalid_argument(source + ": variable \"Y\" is empty; at least one output is needed");
  RICCATI_RETURN_IF_ERROR(check_columns(*outputs, "Y", num_samples, source));

  // U absent or empty: a system without inputs.
  MatVar inputs;
  if (has("U")) {
    RICCATI_ASSIGN_OR_RETURN(inputs, read_double_matrix(mat.get(), "U", source));
  }
  const bool has_inputs = inputs != nullptr && element_count(*inputs) > 0;
  if (has_inputs) RICCATI_RETURN_IF_ERROR(check_columns(*inputs, "U", num_samples, source));

  data.t = Eigen::Map<const Eigen::VectorXd>(static_cast<const double*>(time->data), static_cast<Index>(num_samples));
  data.y = as_matrix(*outputs);
  if (has_inputs) {
    data.u = as_matrix(*inputs);
  } else {
    data.u.resize(0, static_cast<Index>(num_samples));
  }
  RICCATI_ASSIGN_OR_RETURN(data.input_names, signal_names(mapping.inputs, data.u.rows(), "u", "input", "U", source));
  RICCATI_ASSIGN_OR_RETURN(data.output_names, signal_names(mapping.outputs, data.y.rows(), "y", "output", "Y", source));
  RICCATI_RETURN_IF_ERROR(validate_dataset(data));
  return data;
}

Result<Dataset> read_mat_file(const std::string& path, const ColumnMapping& mapping) {
  RICCATI_ASSIGN_OR_RETURN(const std::string bytes, read_whole_file(path));
  return parse_mat(bytes, mapping, base_name(path));
}

Result<Dataset> read_dataset_file(const std::string& path, const ColumnMapping& mapping) {
  std::string extension = std::filesystem::path(path).extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (extension == ".csv") return read_csv_file(path, mapping);
  if (extension == ".mat") return read_mat_file(path, mapping);
  return invalid_argument("cannot read " + in_quotes(path) + ": unsupported file type" +
                          (extension.empty() ? std::string() : " " + in_quotes(extension)) +
                          "; supported formats are CSV (.csv) and MAT (.mat)");
}

}  // namespace riccati
