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

#include "csv/csv.hpp"
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

std::string plural(std::size_t count, const char* noun) {
  return std::to_string(count) + " " + noun + (count == 1 ? "" : "s");
}

// ---------------------------------------------------------------- CSV

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
  const bool sampled = mapping.sample_time != 0.0;  // no time column
  if (sampled && !(std::isfinite(mapping.sample_time) && mapping.sample_time > 0.0)) {
    return invalid_argument(source + ": the sample time must be a positive number of seconds, not " +
                            format_number(mapping.sample_time));
  }
  if (sampled && !mapping.time.empty()) {
    return invalid_argument(source + ": give either a time column (\"" + mapping.time +
                            "\") or a sample time, not both");
  }
  const MappingSlots slots{mapping};
  for (std::size_t a = sampled ? 1 : 0; a < slots.size(); ++a) {
    if (slots.name(a).empty()) {
      return invalid_argument(source + ": the column mapping gives no column name for " + slots.role(a));
    }
    for (std::size_t b = a + 1; b < slots.size(); ++b) {  // (slot 0 is empty with a sample time)
      if (slots.name(a) == slots.name(b)) {
        return invalid_argument(source + ": column " + in_quotes(slots.name(a)) + " is requested twice in the column mapping (as " +
                                slots.role(a) + " and " + slots.role(b) + ")");
      }
    }
  }
  return Status::ok();
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

Result<SampleRange> sample_range(Eigen::Index first, Eigen::Index end, const Dataset& data) {
  const SampleRange range{first, end < 0 ? data.size() : end};
  if (range.first < 0 || range.end > data.size() || range.size() < 2) {
    return invalid_argument("sample range [" + std::to_string(range.first) + ", " + std::to_string(range.end) +
                            ") must hold at least two of the dataset's " + std::to_string(data.size()) + " samples");
  }
  return range;
}

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

namespace {

// The columns a mapping takes from a CSV file, in the order of its table:
// time (unless sampled), inputs, outputs.
std::vector<std::string> csv_columns(const ColumnMapping& mapping) {
  const MappingSlots slots{mapping};
  const bool sampled = mapping.sample_time != 0.0;  // no time column: t = k * sample_time
  std::vector<std::string> columns;
  columns.reserve(slots.size());
  for (std::size_t slot = sampled ? 1 : 0; slot < slots.size(); ++slot) columns.push_back(slots.name(slot));
  return columns;
}

// The dataset of a table read with csv_columns(mapping).
Result<Dataset> dataset_from_table(const csv::Table& table, const ColumnMapping& mapping, std::string source_name) {
  Dataset data;
  data.name = std::move(source_name);
  const bool sampled = mapping.sample_time != 0.0;
  // Row by row, the table is a ([1 +] nu + ny) x N matrix: time (unless
  // sampled), inputs, outputs.
  const auto nu = static_cast<Index>(mapping.inputs.size()), ny = static_cast<Index>(mapping.outputs.size());
  const auto n = static_cast<Index>(table.rows());
  if (n == 0) {  // no samples (validate_dataset says so); an empty table has no storage to map
    data.t.resize(0);
    data.u.resize(nu, 0);
    data.y.resize(ny, 0);
  } else {
    const Eigen::Map<const Eigen::MatrixXd> samples(table.values.data(), static_cast<Index>(table.columns), n);
    if (sampled) {
      data.t = Eigen::VectorXd::LinSpaced(n, 0.0, static_cast<double>(n - 1)) * mapping.sample_time;
    } else {
      data.t = samples.row(0).transpose();
    }
    data.u = samples.middleRows(sampled ? 0 : 1, nu);
    data.y = samples.bottomRows(ny);
  }
  data.input_names = mapping.inputs;
  data.output_names = mapping.outputs;
  RICCATI_RETURN_IF_ERROR(validate_dataset(data));
  return data;
}

}  // namespace

Result<Dataset> parse_csv(std::string_view text, const ColumnMapping& mapping, std::string source_name) {
  RICCATI_RETURN_IF_ERROR(check_mapping(mapping, source_name));
  csv::Table table;
  if (auto error = csv::parse(text, csv_columns(mapping), source_name, &table)) return invalid_argument(std::move(*error));
  return dataset_from_table(table, mapping, std::move(source_name));
}

Result<Dataset> parse_csv_releasing(std::string text, const ColumnMapping& mapping, std::string source_name) {
  RICCATI_RETURN_IF_ERROR(check_mapping(mapping, source_name));
  csv::Table table;
  if (auto error = csv::parse(text, csv_columns(mapping), source_name, &table)) return invalid_argument(std::move(*error));
  std::string().swap(text);  // the table holds the samples now (assigning an empty string would keep the buffer)
  return dataset_from_table(table, mapping, std::move(source_name));
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
  if (mapping.sample_time != 0.0) {
    return invalid_argument(source + ": a MAT file has its times in T; a sample time is for CSV files without a "
                                     "time column");
  }
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
