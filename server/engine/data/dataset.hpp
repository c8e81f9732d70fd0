// Datasets: sampled inputs and outputs of a rig, read from CSV or MAT files.
//
// Layout follows the 1999 toolbox: time t [N], inputs U [nu x N] and outputs
// Y [ny x N], one column per sample, so a sample's values are contiguous.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "engine/status.hpp"

namespace riccati {

struct Dataset {
  std::string name;                       // file name or upload name, for messages
  std::vector<std::string> input_names;   // nu
  std::vector<std::string> output_names;  // ny
  Eigen::VectorXd t;                      // [N] seconds, strictly increasing
  Eigen::MatrixXd u;                      // [nu x N]
  Eigen::MatrixXd y;                      // [ny x N]

  Eigen::Index size() const { return t.size(); }
  Eigen::Index num_inputs() const { return u.rows(); }
  Eigen::Index num_outputs() const { return y.rows(); }
};

// The samples a run uses: [first, end) of a dataset.
struct SampleRange {
  Eigen::Index first = 0;
  Eigen::Index end = 0;
  Eigen::Index size() const { return end - first; }
};

// [first, end) of `data` (end < 0: through its last sample), refused unless it
// lies within the dataset and holds at least two samples.
Result<SampleRange> sample_range(Eigen::Index first, Eigen::Index end, const Dataset& data);

// Which columns of a file are time, inputs and outputs, by name.
struct ColumnMapping {
  std::string time = "t";
  std::vector<std::string> inputs;
  std::vector<std::string> outputs;
  // CSV without a time column: t = k * sample_time (s), k = 0, 1, ...; `time`
  // must then be empty. 0: time is the column `time`.
  double sample_time = 0.0;
};

// Checks what every filter relies on: at least two samples, every value
// finite, time strictly increasing, sizes consistent. The message names the
// dataset, the column and the sample (1-based row as a user counts it).
Status validate_dataset(const Dataset& data);

// CSV with a header row; values separated by commas; the columns named in
// `mapping` are taken, others ignored. Errors name the line and column.
Result<Dataset> parse_csv(std::string_view text, const ColumnMapping& mapping, std::string source_name);
// The same, letting the text go once it is read, before the samples are
// copied out: an upload's memory peaks at its text and its samples once,
// not twice.
Result<Dataset> parse_csv_releasing(std::string text, const ColumnMapping& mapping, std::string source_name);
Result<Dataset> read_csv_file(const std::string& path, const ColumnMapping& mapping);

// A level 5 MAT file (MATLAB's -v6 and -v7, compressed or not; see
// mat_screen.hpp for what is refused) holding T [1 x N], U [nu x N] and
// Y [ny x N]; other variables are ignored. Names are taken from `mapping`
// when given, else "u1".., "y1"...; U may be absent or empty (no inputs);
// mapping.time is not used (time is always T). `max_value_bytes` bounds the
// values T, U and Y claim (RESOURCE_EXHAUSTED past it), which a compressed
// file could otherwise inflate a thousandfold.
Result<Dataset> parse_mat(std::string_view bytes, const ColumnMapping& mapping, std::string source_name,
                          std::uint64_t max_value_bytes = std::numeric_limits<std::uint64_t>::max());
Result<Dataset> read_mat_file(const std::string& path, const ColumnMapping& mapping);

// Reads a CSV or MAT file, chosen by its extension (.csv, .mat).
Result<Dataset> read_dataset_file(const std::string& path, const ColumnMapping& mapping);

}  // namespace riccati
