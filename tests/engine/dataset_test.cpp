#include "engine/data/dataset.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <iterator>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "support/mat_files.hpp"

namespace riccati {
namespace {

namespace fs = std::filesystem;

const std::string kDataDir = RICCATI_TEST_DATA_DIR;

ColumnMapping two_tank_mapping() { return {"t", {"F1", "F2"}, {"h1", "h2"}}; }
ColumnMapping rotating_arm_mapping() { return {"t", {"i"}, {"q", "qdot"}}; }

// Passes when `status` failed with `code` and its message contains every part.
::testing::AssertionResult FailsWith(const Status& status, StatusCode code, std::initializer_list<std::string_view> parts) {
  if (status.is_ok()) return ::testing::AssertionFailure() << "succeeded; expected " << status_code_name(code);
  if (status.code() != code) return ::testing::AssertionFailure() << "wrong code: " << status.to_string();
  for (const std::string_view part : parts) {
    if (status.message().find(part) == std::string::npos) {
      return ::testing::AssertionFailure() << "message \"" << status.message() << "\" lacks \"" << part << "\"";
    }
  }
  return ::testing::AssertionSuccess();
}

// Element-wise |a - b| <= tolerance * max(|a|, |b|).
::testing::AssertionResult RelativelyEqual(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b, double tolerance) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) {
    return ::testing::AssertionFailure() << "sizes differ: " << a.rows() << "x" << a.cols() << " vs " << b.rows() << "x"
                                       << b.cols();
  }
  for (Eigen::Index j = 0; j < a.cols(); ++j) {
    for (Eigen::Index i = 0; i < a.rows(); ++i) {
      if (std::abs(a(i, j) - b(i, j)) > tolerance * std::max(std::abs(a(i, j)), std::abs(b(i, j)))) {
        return ::testing::AssertionFailure() << "(" << i << ", " << j << "): " << a(i, j) << " vs " << b(i, j);
      }
    }
  }
  return ::testing::AssertionSuccess();
}

std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_bytes(const fs::path& path, std::string_view bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  ASSERT_TRUE(out.good()) << path;
}

using testing::MatVariable;
using testing::mat5_file;

// Five samples of a one-input, two-output rig.
const std::vector<double> kTime = {0, 0.5, 1, 1.5, 2};
const std::vector<double> kInputs = {1, 2, 3, 4, 5};
const std::vector<double> kOutputs = {10, 20, 11, 21, 12, 22, 13, 23, 14, 24};  // [2 x 5], column-major

class DatasetFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::path(::testing::TempDir()) / (std::string("riccati_dataset_") + info->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string write(const std::string& name, std::string_view bytes) {
    write_bytes(dir_ / name, bytes);
    return (dir_ / name).string();
  }

  std::string write_mat(const std::vector<MatVariable>& variables) { return write("crafted.mat", mat5_file(variables)); }

  fs::path dir_;
};

// ------------------------------------------------------------------ fixtures

TEST(DatasetFixtures, TwoTankCsvMatchesItsText) {
  const Result<Dataset> data = read_csv_file(kDataDir + "/two_tank.csv", two_tank_mapping());
  ASSERT_TRUE(data.is_ok()) << data.status().to_string();
  EXPECT_EQ(data->name, "two_tank.csv");
  EXPECT_EQ(data->input_names, (std::vector<std::string>{"F1", "F2"}));
  EXPECT_EQ(data->output_names, (std::vector<std::string>{"h1", "h2"}));
  ASSERT_EQ(data->size(), 2000);
  ASSERT_EQ(data->u.rows(), 2);
  ASSERT_EQ(data->y.rows(), 2);
  // First line: 0,0.095046369632593539,0.030650165052652025,0.40000000000000002,0.14999999999999999
  EXPECT_EQ(data->t(0), 0.0);
  EXPECT_EQ(data->u(0, 0), 0.095046369632593539);
  EXPECT_EQ(data->u(1, 0), 0.030650165052652025);
  EXPECT_EQ(data->y(0, 0), 0.40000000000000002);
  EXPECT_EQ(data->y(1, 0), 0.14999999999999999);
  // Last line: 1999,0.062348975553750047,0.031966569003329393,0.23505661724908528,0.27483961796968293
  EXPECT_EQ(data->t(1999), 1999.0);
  EXPECT_EQ(data->u(0, 1999), 0.062348975553750047);
  EXPECT_EQ(data->u(1, 1999), 0.031966569003329393);
  EXPECT_EQ(data->y(0, 1999), 0.23505661724908528);
  EXPECT_EQ(data->y(1, 1999), 0.27483961796968293);
}

TEST(DatasetFixtures, TwoTankMatEqualsCsv) {
  const Result<Dataset> csv = read_csv_file(kDataDir + "/two_tank.csv", two_tank_mapping());
  const Result<Dataset> mat = read_mat_file(kDataDir + "/two_tank.mat", two_tank_mapping());
  ASSERT_TRUE(csv.is_ok()) << csv.status().to_string();
  ASSERT_TRUE(mat.is_ok()) << mat.status().to_string();
  EXPECT_EQ(mat->name, "two_tank.mat");
  EXPECT_EQ(mat->input_names, csv->input_names);
  EXPECT_EQ(mat->output_names, csv->output_names);
  EXPECT_TRUE(RelativelyEqual(mat->t, csv->t, 1e-15));
  EXPECT_TRUE(RelativelyEqual(mat->u, csv->u, 1e-15));
  EXPECT_TRUE(RelativelyEqual(mat->y, csv->y, 1e-15));
}

TEST(DatasetFixtures, RotatingArmMatEqualsCsv) {
  const Result<Dataset> csv = read_csv_file(kDataDir + "/rotating_arm.csv", rotating_arm_mapping());
  const Result<Dataset> mat = read_mat_file(kDataDir + "/rotating_arm.mat", rotating_arm_mapping());
  ASSERT_TRUE(csv.is_ok()) << csv.status().to_string();
  ASSERT_TRUE(mat.is_ok()) << mat.status().to_string();
  ASSERT_EQ(mat->size(), 3000);
  ASSERT_EQ(mat->num_inputs(), 1);
  ASSERT_EQ(mat->num_outputs(), 2);
  // Last line of the CSV: 29.990000000000002,0.41178771289606608,-6.7245102956359064,-1.0536542754912479
  EXPECT_EQ(csv->t(2999), 29.990000000000002);
  EXPECT_EQ(csv->y(0, 2999), -6.7245102956359064);
  EXPECT_TRUE(RelativelyEqual(mat->t, csv->t, 1e-15));
  EXPECT_TRUE(RelativelyEqual(mat->u, csv->u, 1e-15));
  EXPECT_TRUE(RelativelyEqual(mat->y, csv->y, 1e-15));
}

TEST(DatasetFixtures, MatWithoutNamesGetsDefaultNames) {
  const Result<Dataset> mat = read_mat_file(kDataDir + "/two_tank.mat", ColumnMapping{});
  ASSERT_TRUE(mat.is_ok()) << mat.status().to_string();
  EXPECT_EQ(mat->input_names, (std::vector<std::string>{"u1", "u2"}));
  EXPECT_EQ(mat->output_names, (std::vector<std::string>{"y1", "y2"}));
}

TEST(DatasetFixtures, MatMappingMustMatchRowCounts) {
  EXPECT_TRUE(FailsWith(read_mat_file(kDataDir + "/two_tank.mat", {"t", {"F1"}, {"h1", "h2"}}).status(),
                        StatusCode::kInvalidArgument, {"two_tank.mat", "names 1 input but U has 2 rows"}));
  EXPECT_TRUE(FailsWith(read_mat_file(kDataDir + "/two_tank.mat", {"t", {}, {"h1", "h2", "h3"}}).status(),
                        StatusCode::kInvalidArgument, {"names 3 outputs but Y has 2 rows"}));
}

// ------------------------------------------------------------------ CSV

constexpr std::string_view kSmallCsv =
    "t,F1,F2,h1,h2\n"
    "0,1,2,3,4\n"
    "1,1.5,2.5,3.5,4.5\n"
    "2,1.25,2.25,3.25,4.25\n";

TEST(ParseCsv, SelectsColumnsByNameInMappingOrder) {
  // Columns in another order than the mapping; "note" is not selected and may hold text.
  const std::string_view text =
      "h2,note,t,F1,h1\n"
      "4,start,0,1,3\n"
      "4.5,n/a,1,1.5,3.5\n";
  const Result<Dataset> data = parse_csv(text, {"t", {"F1"}, {"h1", "h2"}}, "rig.csv");
  ASSERT_TRUE(data.is_ok()) << data.status().to_string();
  EXPECT_EQ(data->name, "rig.csv");
  ASSERT_EQ(data->size(), 2);
  EXPECT_EQ(data->t(1), 1.0);
  EXPECT_EQ(data->u(0, 1), 1.5);
  EXPECT_EQ(data->y(0, 0), 3.0);  // h1 first, as in the mapping
  EXPECT_EQ(data->y(1, 0), 4.0);
  EXPECT_EQ(data->y(1, 1), 4.5);
}

// The upload path's parse lets the text go early; what it reads is the same,
// and so are its errors.
TEST(ParseCsv, ReleasingTheTextReadsTheSameAndFailsTheSame) {
  const std::string text = "h2,note,t,F1,h1\n4,start,0,1,3\n4.5,n/a,1,1.5,3.5\n";
  const ColumnMapping mapping{"t", {"F1"}, {"h1", "h2"}};
  const Result<Dataset> kept = parse_csv(text, mapping, "rig.csv");
  const Result<Dataset> released = parse_csv_releasing(text, mapping, "rig.csv");
  ASSERT_TRUE(kept.is_ok() && released.is_ok()) << released.status().to_string();
  EXPECT_EQ(released->name, "rig.csv");
  EXPECT_EQ(released->t, kept->t);
  EXPECT_EQ(released->u, kept->u);
  EXPECT_EQ(released->y, kept->y);
  EXPECT_EQ(released->output_names, kept->output_names);
  const Result<Dataset> bad = parse_csv_releasing("t,y\n0,1\n1,2.5x\n", {"t", {}, {"y"}}, "x.csv");
  EXPECT_EQ(bad.status().message(), parse_csv("t,y\n0,1\n1,2.5x\n", {"t", {}, {"y"}}, "x.csv").status().message());
  EXPECT_NE(bad.status().message().find("line 3"), std::string::npos) << bad.status().message();
}

TEST(ParseCsv, AcceptsBomQuotedHeaderCrlfAndTrailingBlankLines) {
  const std::string_view text =
      "\xEF\xBB\xBF\"time\" , \"u\",\"y\"\r\n"
      "0, 1e-3 ,-0\r\n"
      "0.1,+2,3E2\r\n"
      "\r\n"
      "  \n";
  const Result<Dataset> data = parse_csv(text, {"time", {"u"}, {"y"}}, "excel.csv");
  ASSERT_TRUE(data.is_ok()) << data.status().to_string();
  ASSERT_EQ(data->size(), 2);
  EXPECT_EQ(data->t(1), 0.1);
  EXPECT_EQ(data->u(0, 0), 1e-3);
  EXPECT_EQ(data->u(0, 1), 2.0);
  EXPECT_EQ(data->y(0, 0), 0.0);
  EXPECT_TRUE(std::signbit(data->y(0, 0)));
  EXPECT_EQ(data->y(0, 1), 300.0);
}

TEST(ParseCsv, NoInputsAndNoTrailingNewline) {
  const Result<Dataset> data = parse_csv("t,y\n0,1\n1,2", {"t", {}, {"y"}}, "x.csv");
  ASSERT_TRUE(data.is_ok()) << data.status().to_string();
  EXPECT_EQ(data->num_inputs(), 0);
  EXPECT_EQ(data->u.cols(), 2);
  EXPECT_EQ(data->y(0, 1), 2.0);
}

TEST(ParseCsv, MissingColumnListsTheColumns) {
  EXPECT_TRUE(FailsWith(parse_csv(kSmallCsv, {"t", {"F1", "F2"}, {"h1", "h3"}}, "two_tank.csv").status(),
                        StatusCode::kInvalidArgument,
                        {"two_tank.csv: missing column \"h3\" (columns are: t, F1, F2, h1, h2)"}));
  EXPECT_TRUE(FailsWith(parse_csv(kSmallCsv, {"time", {}, {"h1"}}, "two_tank.csv").status(),
                        StatusCode::kInvalidArgument, {"missing column \"time\""}));
}

TEST(ParseCsv, NonNumericCellNamesLineAndColumn) {
  const std::string text = std::string(kSmallCsv) + "3,1,2,abc,4\n";
  EXPECT_TRUE(FailsWith(parse_csv(text, two_tank_mapping(), "two_tank.csv").status(), StatusCode::kInvalidArgument,
                        {"two_tank.csv line 5, column \"h1\": \"abc\" is not a number"}));
  // A number followed by junk is not a number either.
  EXPECT_TRUE(FailsWith(parse_csv("t,y\n0,1\n1,2.5x\n", {"t", {}, {"y"}}, "x.csv").status(),
                        StatusCode::kInvalidArgument, {"line 3, column \"y\": \"2.5x\" is not a number"}));
  // A runaway cell (a missing line break, say) is cut short in the message.
  const std::string runaway(500, '7');
  const Status status = parse_csv("t,y\n0,1\n1,x" + runaway + "\n", {"t", {}, {"y"}}, "x.csv").status();
  EXPECT_TRUE(FailsWith(status, StatusCode::kInvalidArgument, {"line 3, column \"y\": \"x777", "...\" is not a number"}));
  EXPECT_LT(status.message().size(), 120u);
}

TEST(ParseCsv, RejectsNanAndInfinity) {
  EXPECT_TRUE(FailsWith(parse_csv("t,y\n0,1\n1,nan\n", {"t", {}, {"y"}}, "x.csv").status(), StatusCode::kInvalidArgument,
                        {"line 3, column \"y\": \"nan\" is not a finite number"}));
  EXPECT_TRUE(FailsWith(parse_csv("t,y\n0,-inf\n1,2\n", {"t", {}, {"y"}}, "x.csv").status(),
                        StatusCode::kInvalidArgument, {"line 2, column \"y\": \"-inf\" is not a finite number"}));
  EXPECT_TRUE(FailsWith(parse_csv("t,y\n0,1\n1e999,2\n", {"t", {}, {"y"}}, "x.csv").status(),
                        StatusCode::kInvalidArgument, {"line 3, column \"t\": \"1e999\" is out of the range"}));
}

TEST(ParseCsv, RejectsEmptyCell) {
  EXPECT_TRUE(FailsWith(parse_csv("t,u,y\n0,1,2\n1,,3\n", {"t", {"u"}, {"y"}}, "x.csv").status(),
                        StatusCode::kInvalidArgument, {"x.csv line 3, column \"u\": empty value"}));
}

TEST(ParseCsv, WrongNumberOfValuesNamesTheLine) {
  const std::string short_row = std::string(kSmallCsv) + "3,1,2,3\n";
  EXPECT_TRUE(FailsWith(parse_csv(short_row, two_tank_mapping(), "two_tank.csv").status(), StatusCode::kInvalidArgument,
                        {"two_tank.csv line 5: expected 5 values, found 4"}));
  const std::string long_row = std::string(kSmallCsv) + "3,1,2,3,4,5\n";
  EXPECT_TRUE(FailsWith(parse_csv(long_row, two_tank_mapping(), "two_tank.csv").status(), StatusCode::kInvalidArgument,
                        {"line 5: expected 5 values, found 6"}));
}

TEST(ParseCsv, BlankLineInsideTheDataIsAnError) {
  EXPECT_TRUE(FailsWith(parse_csv("t,y\n0,1\n\n1,2\n", {"t", {}, {"y"}}, "x.csv").status(), StatusCode::kInvalidArgument,
                        {"line 3: blank line"}));
}

TEST(ParseCsv, DuplicateHeaderName) {
  EXPECT_TRUE(FailsWith(parse_csv("t,h1,F1,h1\n0,1,2,3\n1,1,2,3\n", {"t", {}, {"h1"}}, "x.csv").status(),
                        StatusCode::kInvalidArgument, {"line 1: column name \"h1\" appears twice (columns 2 and 4)"}));
}

TEST(ParseCsv, ColumnRequestedTwice) {
  EXPECT_TRUE(FailsWith(parse_csv(kSmallCsv, {"t", {"F1", "h1"}, {"h1"}}, "x.csv").status(), StatusCode::kInvalidArgument,
                        {"column \"h1\" is requested twice", "input 2 and output 1"}));
  EXPECT_TRUE(FailsWith(parse_csv(kSmallCsv, {"t", {}, {"h1", "t"}}, "x.csv").status(), StatusCode::kInvalidArgument,
                        {"column \"t\" is requested twice", "time and output 2"}));
}

TEST(ParseCsv, MappingWithoutOutputs) {
  EXPECT_TRUE(FailsWith(parse_csv(kSmallCsv, {"t", {"F1"}, {}}, "x.csv").status(), StatusCode::kInvalidArgument,
                        {"x.csv", "no outputs"}));
}

TEST(ParseCsv, EmptyTextHasNoHeader) {
  EXPECT_TRUE(FailsWith(parse_csv("", two_tank_mapping(), "x.csv").status(), StatusCode::kInvalidArgument,
                        {"x.csv: no header row"}));
}

TEST(ParseCsv, NeedsTwoSamples) {
  EXPECT_TRUE(FailsWith(parse_csv("t,y\n0,1\n", {"t", {}, {"y"}}, "x.csv").status(), StatusCode::kInvalidArgument,
                        {"x.csv: at least 2 samples are needed, found 1"}));
  EXPECT_TRUE(FailsWith(parse_csv("t,y\n", {"t", {}, {"y"}}, "x.csv").status(), StatusCode::kInvalidArgument,
                        {"found 0"}));
}

TEST(ParseCsv, TimeMustIncrease) {
  EXPECT_TRUE(FailsWith(parse_csv("t,y\n0,1\n1,1\n2,1\n1,1\n", {"t", {}, {"y"}}, "x.csv").status(),
                        StatusCode::kInvalidArgument, {"x.csv: time goes backwards (or repeats) at sample 4: t = 1 after t = 2"}));
  EXPECT_TRUE(FailsWith(parse_csv("t,y\n0,1\n0.5,1\n0.5,1\n", {"t", {}, {"y"}}, "x.csv").status(),
                        StatusCode::kInvalidArgument, {"at sample 3: t = 0.5 after t = 0.5"}));
}

// A file without a time column, given the sample time: t = k * ts. The
// input and output columns are read as with a time column.
TEST(ParseCsv, ASampleTimeInsteadOfATimeColumn) {
  ColumnMapping mapping{"", {"u"}, {"y"}};
  mapping.sample_time = 0.25;
  const auto data = parse_csv("u,y\n1,10\n2,20\n3,30\n", mapping, "x.csv");
  ASSERT_TRUE(data.is_ok()) << data.status().to_string();
  EXPECT_EQ(data.value().t, (Eigen::Vector3d(0.0, 0.25, 0.5)));
  EXPECT_EQ(data.value().u, (Eigen::RowVector3d(1, 2, 3)));
  EXPECT_EQ(data.value().y, (Eigen::RowVector3d(10, 20, 30)));
  // An input may be called "t" then: there is no time column to clash with.
  ColumnMapping t_input{"", {"t"}, {"y"}};
  t_input.sample_time = 1.0;
  EXPECT_TRUE(parse_csv("t,y\n5,1\n6,1\n", t_input, "x.csv").is_ok());

  mapping.sample_time = -1.0;
  EXPECT_TRUE(FailsWith(parse_csv("u,y\n1,10\n2,20\n", mapping, "x.csv").status(), StatusCode::kInvalidArgument,
                        {"x.csv: the sample time must be a positive number of seconds, not -1"}));
  ColumnMapping both{"t", {"u"}, {"y"}};
  both.sample_time = 1.0;
  EXPECT_TRUE(FailsWith(parse_csv("t,u,y\n0,1,10\n1,2,20\n", both, "x.csv").status(), StatusCode::kInvalidArgument,
                        {"give either a time column (\"t\") or a sample time, not both"}));
  ColumnMapping mat{"", {}, {"y"}};
  mat.sample_time = 1.0;
  EXPECT_TRUE(FailsWith(parse_mat("", mat, "x.mat").status(), StatusCode::kInvalidArgument,
                        {"a MAT file has its times in T"}));
}

// ------------------------------------------------------------------ validate_dataset

Dataset small_dataset() {
  Dataset data;
  data.name = "rig";
  data.input_names = {"F1"};
  data.output_names = {"h1", "h2"};
  data.t = Eigen::VectorXd::LinSpaced(12, 0.0, 11.0);
  data.u = Eigen::MatrixXd::Ones(1, 12);
  data.y = Eigen::MatrixXd::Zero(2, 12);
  return data;
}

TEST(ValidateDataset, AcceptsAConsistentDataset) { EXPECT_TRUE(validate_dataset(small_dataset()).is_ok()); }

TEST(ValidateDataset, NonFiniteValueNamesColumnAndSample) {
  Dataset data = small_dataset();
  data.y(1, 11) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_TRUE(FailsWith(validate_dataset(data), StatusCode::kInvalidArgument,
                        {"rig: output \"h2\" is NaN at sample 12 (t = 11)"}));
  data = small_dataset();
  data.u(0, 3) = -std::numeric_limits<double>::infinity();
  EXPECT_TRUE(FailsWith(validate_dataset(data), StatusCode::kInvalidArgument,
                        {"input \"F1\" is -inf at sample 4 (t = 3)"}));
  data = small_dataset();
  data.t(5) = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(FailsWith(validate_dataset(data), StatusCode::kInvalidArgument, {"time is inf at sample 6"}));
}

TEST(ValidateDataset, TimeGoingBackwards) {
  Dataset data = small_dataset();
  data.t(6) = 5.0;  // t(5) is 5 as well
  EXPECT_TRUE(FailsWith(validate_dataset(data), StatusCode::kInvalidArgument,
                        {"time goes backwards (or repeats) at sample 7: t = 5 after t = 5"}));
}

TEST(ValidateDataset, InconsistentSizes) {
  Dataset data = small_dataset();
  data.y.resize(2, 11);
  EXPECT_TRUE(FailsWith(validate_dataset(data), StatusCode::kInvalidArgument, {"inconsistent sizes", "11 output samples"}));
  data = small_dataset();
  data.output_names.pop_back();
  EXPECT_TRUE(FailsWith(validate_dataset(data), StatusCode::kInvalidArgument, {"1 output name for 2 outputs"}));
  data = small_dataset();
  data.input_names.push_back("F2");
  EXPECT_TRUE(FailsWith(validate_dataset(data), StatusCode::kInvalidArgument, {"2 input names for 1 input"}));
}

// ------------------------------------------------------------------ files

TEST_F(DatasetFileTest, MissingCsvFileNamesThePath) {
  const std::string path = (dir_ / "absent.csv").string();
  EXPECT_TRUE(FailsWith(read_csv_file(path, two_tank_mapping()).status(), StatusCode::kNotFound, {path}));
  EXPECT_TRUE(FailsWith(read_mat_file((dir_ / "absent.mat").string(), two_tank_mapping()).status(), StatusCode::kNotFound,
                        {"absent.mat"}));
}

TEST_F(DatasetFileTest, ChoosesTheReaderByExtensionIgnoringCase) {
  const std::string csv = write("TWO_TANK.CSV", read_bytes(kDataDir + "/two_tank.csv"));
  const Result<Dataset> from_csv = read_dataset_file(csv, two_tank_mapping());
  ASSERT_TRUE(from_csv.is_ok()) << from_csv.status().to_string();
  EXPECT_EQ(from_csv->name, "TWO_TANK.CSV");
  EXPECT_EQ(from_csv->size(), 2000);

  const std::string mat = write("two_tank.Mat", read_bytes(kDataDir + "/two_tank.mat"));
  const Result<Dataset> from_mat = read_dataset_file(mat, two_tank_mapping());
  ASSERT_TRUE(from_mat.is_ok()) << from_mat.status().to_string();
  EXPECT_EQ(from_mat->y, from_csv->y);

  EXPECT_TRUE(FailsWith(read_dataset_file(write("data.txt", kSmallCsv), two_tank_mapping()).status(),
                        StatusCode::kInvalidArgument, {"data.txt", "\".txt\"", ".csv", ".mat"}));
  EXPECT_TRUE(FailsWith(read_dataset_file(write("data", kSmallCsv), two_tank_mapping()).status(),
                        StatusCode::kInvalidArgument, {"unsupported file type", ".csv", ".mat"}));
}

TEST_F(DatasetFileTest, TruncatedMatFileIsAnError) {
  const std::string full = read_bytes(kDataDir + "/two_tank.mat");
  ASSERT_GT(full.size(), 1000u);
  for (const std::size_t length : {std::size_t{0}, std::size_t{64}, std::size_t{132}, std::size_t{200},
                                   full.size() / 2, full.size() - 8, full.size() - 1}) {
    SCOPED_TRACE("truncated to " + std::to_string(length) + " bytes");
    const std::string path = write("two_tank.mat", std::string_view(full).substr(0, length));
    EXPECT_TRUE(FailsWith(read_mat_file(path, two_tank_mapping()).status(), StatusCode::kInvalidArgument,
                          {"two_tank.mat"}));
  }
  const std::string path = write("two_tank.mat", std::string_view(full).substr(0, full.size() / 2));
  EXPECT_TRUE(FailsWith(read_mat_file(path, two_tank_mapping()).status(), StatusCode::kInvalidArgument,
                        {"truncated or corrupt"}));
}

TEST_F(DatasetFileTest, OnlyLevel5MatFilesAreRead) {
  const std::string short_text = "these are not the samples you are looking for\n";
  EXPECT_TRUE(FailsWith(read_mat_file(write("notes.mat", short_text), ColumnMapping{}).status(),
                        StatusCode::kInvalidArgument, {"notes.mat: not a MAT file", "level 5", "-v7"}));
  std::string long_text;
  while (long_text.size() < 300) long_text += short_text;
  EXPECT_TRUE(FailsWith(read_mat_file(write("notes.mat", long_text), ColumnMapping{}).status(),
                        StatusCode::kInvalidArgument, {"notes.mat: not a MAT file of level 5"}));
  // v7.3 is HDF5, which is not given untrusted bytes: the user is told how to save instead.
  std::string v73 = mat5_file({{"T", {1, 5}, kTime}, {"Y", {2, 5}, kOutputs}});
  v73[125] = 0x02;
  EXPECT_TRUE(FailsWith(read_mat_file(write("v73.mat", v73), ColumnMapping{}).status(), StatusCode::kInvalidArgument,
                        {"v73.mat: a MAT file of version 7.3 (HDF5)", "-v7"}));
}

// MATLAB's -v7 compresses each variable; the crafted file's values must come
// back exactly as from the uncompressed one.
TEST_F(DatasetFileTest, CompressedVariablesReadLikeUncompressedOnes) {
  const std::vector<MatVariable> variables = {{"T", {1, 5}, kTime}, {"U", {1, 5}, kInputs}, {"Y", {2, 5}, kOutputs}};
  const Result<Dataset> plain = read_mat_file(write("plain.mat", mat5_file(variables)), ColumnMapping{});
  const Result<Dataset> deflated = read_mat_file(write("deflated.mat", mat5_file(variables, true)), ColumnMapping{});
  ASSERT_TRUE(plain.is_ok()) << plain.status().to_string();
  ASSERT_TRUE(deflated.is_ok()) << deflated.status().to_string();
  EXPECT_EQ(deflated->t, plain->t);
  EXPECT_EQ(deflated->u, plain->u);
  EXPECT_EQ(deflated->y, plain->y);
  EXPECT_EQ(deflated->y(1, 3), 23.0);
}

// Variables other than T, U and Y are not riccati's business, whatever they
// are: a struct of notes is skipped, and so is a cell whose header claims
// 335,544,328 elements in a few bytes, for which matio would have asked for
// 2.7 GB (what the fuzzer found in CI). Named T, a cell is an error.
TEST_F(DatasetFileTest, OtherVariablesAreSkippedUnreadEvenCorruptCells) {
  const std::string others = testing::mat5::struct_with_empty_field("notes", "rig") +
                             testing::mat5::cell("labels", {1, 335'544'328}) +
                             testing::mat5::compressed(testing::mat5::cell("more_labels", {1, 335'544'328}));
  const std::vector<MatVariable> variables = {{"T", {1, 5}, kTime}, {"Y", {2, 5}, kOutputs}};
  for (const bool compress : {false, true}) {
    SCOPED_TRACE(compress ? "compressed" : "uncompressed");
    const Result<Dataset> data = read_mat_file(write("others.mat", mat5_file(variables, compress, others)), ColumnMapping{});
    ASSERT_TRUE(data.is_ok()) << data.status().to_string();
    EXPECT_EQ(data->y(1, 4), 24.0);
  }
  const std::string cell_t = testing::mat5::file_header() + testing::mat5::cell("T", {1, 5}) +
                             testing::mat5::numeric_matrix({"Y", {2, 5}, kOutputs});
  EXPECT_TRUE(FailsWith(read_mat_file(write("cell.mat", cell_t), ColumnMapping{}).status(), StatusCode::kInvalidArgument,
                        {"cell.mat: variable \"T\" must be a real double matrix, found cell"}));
}

// A compressed variable may inflate a thousandfold: the values that T, U and
// Y claim are bounded (the daemon bounds them by max_dataset_bytes).
TEST_F(DatasetFileTest, InflatedValuesAreBoundedBeforeMatioAllocates) {
  const std::string bytes = read_bytes(kDataDir + "/two_tank.mat");
  constexpr std::uint64_t kValueBytes = (1 + 2 + 2) * 2000 * sizeof(double);  // T, U and Y of 2000 samples
  EXPECT_TRUE(parse_mat(bytes, two_tank_mapping(), "two_tank.mat", kValueBytes).is_ok());
  EXPECT_TRUE(FailsWith(parse_mat(bytes, two_tank_mapping(), "two_tank.mat", kValueBytes - 1).status(),
                        StatusCode::kResourceExhausted, {"two_tank.mat: its variables claim 80000 bytes", "79999 allowed"}));
  // A million zero samples deflate to about a kilobyte.
  const std::vector<double> zeros(1'000'000, 0.0);
  const std::string bomb = mat5_file({{"T", {1, 1'000'000}, zeros}, {"Y", {1, 1'000'000}, zeros}}, true);
  ASSERT_LT(bomb.size(), 20'000u);
  EXPECT_TRUE(FailsWith(parse_mat(bomb, ColumnMapping{}, "bomb.mat", 1 << 20).status(), StatusCode::kResourceExhausted,
                        {"bomb.mat: its variables claim 8000000 bytes", "\"T\" is 1 x 1000000"}));
}

TEST_F(DatasetFileTest, CraftedMatFileReadsLikeMatlabWouldWriteIt) {
  // T as a column [N x 1] is accepted too; U is absent: no inputs.
  const std::string path = write_mat({{"T", {5, 1}, kTime}, {"Y", {2, 5}, kOutputs}});
  const Result<Dataset> data = read_mat_file(path, {"t", {}, {"h1", "h2"}});
  ASSERT_TRUE(data.is_ok()) << data.status().to_string();
  EXPECT_EQ(data->name, "crafted.mat");
  EXPECT_EQ(data->num_inputs(), 0);
  EXPECT_EQ(data->u.cols(), 5);
  EXPECT_EQ(data->t(4), 2.0);
  EXPECT_EQ(data->y(0, 1), 11.0);
  EXPECT_EQ(data->y(1, 4), 24.0);
}

TEST_F(DatasetFileTest, EmptyUMeansNoInputs) {
  const std::string path = write_mat({{"T", {1, 5}, kTime}, {"U", {0, 0}, {}}, {"Y", {2, 5}, kOutputs}});
  const Result<Dataset> data = read_mat_file(path, ColumnMapping{});
  ASSERT_TRUE(data.is_ok()) << data.status().to_string();
  EXPECT_EQ(data->num_inputs(), 0);
  EXPECT_EQ(data->output_names, (std::vector<std::string>{"y1", "y2"}));
}

TEST_F(DatasetFileTest, MissingMatVariables) {
  EXPECT_TRUE(FailsWith(read_mat_file(write_mat({{"Y", {2, 5}, kOutputs}}), ColumnMapping{}).status(),
                        StatusCode::kInvalidArgument, {"crafted.mat: missing variable \"T\""}));
  EXPECT_TRUE(FailsWith(read_mat_file(write_mat({{"T", {1, 5}, kTime}, {"U", {1, 5}, kInputs}}), ColumnMapping{}).status(),
                        StatusCode::kInvalidArgument, {"missing variable \"Y\""}));
  EXPECT_TRUE(FailsWith(read_mat_file(write_mat({{"T", {1, 5}, kTime}, {"Y", {0, 5}, {}}}), ColumnMapping{}).status(),
                        StatusCode::kInvalidArgument, {"\"Y\" is empty"}));
  EXPECT_TRUE(FailsWith(read_mat_file(write_mat({{"T", {1, 5}, kTime}, {"Y", {2, 5}, kOutputs}}), {"t", {"F1"}, {}}).status(),
                        StatusCode::kInvalidArgument, {"names 1 input but U has 0 rows"}));
}

TEST_F(DatasetFileTest, WrongMatTypes) {
  using Type = MatVariable::Type;
  EXPECT_TRUE(FailsWith(
      read_mat_file(write_mat({{"T", {1, 5}, kTime, Type::kInt32}, {"Y", {2, 5}, kOutputs}}), ColumnMapping{}).status(),
      StatusCode::kInvalidArgument, {"variable \"T\" must be a real double matrix, found int32"}));
  EXPECT_TRUE(FailsWith(
      read_mat_file(write_mat({{"T", {1, 5}, kTime}, {"Y", {2, 5}, kOutputs, Type::kComplexDouble}}), ColumnMapping{})
          .status(),
      StatusCode::kInvalidArgument, {"variable \"Y\" must be a real double matrix, found complex double"}));
  EXPECT_TRUE(FailsWith(read_mat_file(write_mat({{"T", {1, 5}, kTime}, {"Y", {2, 5, 1, 2}, std::vector<double>(20, 1.0)}}),
                                      ColumnMapping{})
                            .status(),
                        StatusCode::kInvalidArgument, {"\"Y\" must be a 2-D matrix, found 2 x 5 x 1 x 2"}));
  EXPECT_TRUE(FailsWith(
      read_mat_file(write_mat({{"T", {2, 5}, std::vector<double>(10, 1.0)}, {"Y", {2, 5}, kOutputs}}), ColumnMapping{})
          .status(),
      StatusCode::kInvalidArgument, {"\"T\" must be a vector [1 x N], found 2 x 5"}));
}

TEST_F(DatasetFileTest, ImpossibleMatDimensionsAreRejectedBeforeReading) {
  // A corrupt header claiming 1 x 10^9 values in a file of a few hundred
  // bytes: matio would try to allocate 8 GB for it.
  EXPECT_TRUE(FailsWith(
      read_mat_file(write_mat({{"T", {1, 1'000'000'000}, kTime}, {"Y", {2, 5}, kOutputs}}), ColumnMapping{}).status(),
      StatusCode::kInvalidArgument, {"\"T\" claims to be 1 x 1000000000, more than the file can hold"}));
}

// Variable headers matio would believe and allocate for, before reading a
// value: refused first. The compressed one is what the fuzzer found (a 272
// byte file that made matio ask for 7.5 GB); the other has its dimensions'
// byte count overwritten.
TEST_F(DatasetFileTest, CorruptVariableHeadersAreRefusedBeforeMatioAllocates) {
  EXPECT_TRUE(FailsWith(read_mat_file(kDataDir + "/corrupt_compressed_header.mat", ColumnMapping{}).status(),
                        StatusCode::kInvalidArgument, {"corrupt_compressed_header.mat: the file is corrupt", "byte 128"}));
  std::string bytes = mat5_file({{"T", {1, 5}, kTime}, {"Y", {2, 5}, kOutputs}});
  constexpr std::size_t kFirstDimsSize = 128 + 8 + 16 + 4;  // header, matrix tag, array flags, dims type
  for (std::size_t i = 0; i < 4; ++i) bytes[kFirstDimsSize + i] = "\xf0\xff\xff\x7f"[i];
  EXPECT_TRUE(FailsWith(read_mat_file(write("dims.mat", bytes), ColumnMapping{}).status(), StatusCode::kInvalidArgument,
                        {"dims.mat: the file is corrupt (the variable at byte 128: its dimensions are malformed)"}));
}

TEST_F(DatasetFileTest, MismatchedMatLengths) {
  const std::vector<double> four_columns(kOutputs.begin(), kOutputs.begin() + 8);
  EXPECT_TRUE(FailsWith(
      read_mat_file(write_mat({{"T", {1, 5}, kTime}, {"Y", {2, 4}, four_columns}}), ColumnMapping{}).status(),
      StatusCode::kInvalidArgument, {"variable \"Y\" is 2 x 4 but T has 5 samples"}));
  EXPECT_TRUE(FailsWith(read_mat_file(write_mat({{"T", {1, 5}, kTime}, {"Y", {5, 2}, kOutputs}}), ColumnMapping{}).status(),
                        StatusCode::kInvalidArgument, {"\"Y\" is 5 x 2", "transposed"}));
  EXPECT_TRUE(FailsWith(read_mat_file(write_mat({{"T", {1, 5}, kTime}, {"U", {1, 4}, {1, 2, 3, 4}}, {"Y", {2, 5}, kOutputs}}),
                                      ColumnMapping{})
                            .status(),
                        StatusCode::kInvalidArgument, {"variable \"U\" is 1 x 4 but T has 5 samples"}));
}

TEST_F(DatasetFileTest, MatValuesAreValidated) {
  std::vector<double> time = kTime;
  time[3] = 0.5;  // repeats t(2)
  EXPECT_TRUE(FailsWith(read_mat_file(write_mat({{"T", {1, 5}, time}, {"Y", {2, 5}, kOutputs}}), ColumnMapping{}).status(),
                        StatusCode::kInvalidArgument, {"crafted.mat: time goes backwards (or repeats) at sample 4"}));
  std::vector<double> outputs = kOutputs;
  outputs[7] = std::numeric_limits<double>::quiet_NaN();  // output 2, sample 4
  EXPECT_TRUE(FailsWith(
      read_mat_file(write_mat({{"T", {1, 5}, kTime}, {"Y", {2, 5}, outputs}}), {"t", {}, {"h1", "h2"}}).status(),
      StatusCode::kInvalidArgument, {"output \"h2\" is NaN at sample 4 (t = 1.5)"}));
}

}  // namespace
}  // namespace riccati
