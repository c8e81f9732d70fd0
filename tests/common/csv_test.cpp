// The shared CSV reader on its own: what it accepts and what its errors say.
// (tests/engine/dataset_test.cpp checks the engine's datasets built on it.)
#include "csv/csv.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace riccati::csv {
namespace {

// The error of reading `text` for `select`, or "" when it reads.
std::string error_of(std::string_view text, const std::vector<std::string>& select) {
  Table table;
  return parse(text, select, "x.csv", &table).value_or("");
}

TEST(Csv, SelectsColumnsByNameInTheOrderAsked) {
  Table table;
  const std::vector<std::string> select{"t", "h1", "F1"};
  ASSERT_EQ(parse("h2,note,t,F1,h1\n4,start,0,1,3\n4.5,n/a,1,1.5,3.5\n", select, "rig.csv", &table), std::nullopt);
  ASSERT_EQ(table.columns, 3u);
  ASSERT_EQ(table.rows(), 2u);
  EXPECT_EQ(std::vector<double>(table.row(0).begin(), table.row(0).end()), (std::vector<double>{0, 3, 1}));
  EXPECT_EQ(std::vector<double>(table.row(1).begin(), table.row(1).end()), (std::vector<double>{1, 3.5, 1.5}));
}

TEST(Csv, AcceptsBomQuotedHeaderCrlfBlanksAndTrailingBlankLines) {
  Table table;
  const std::vector<std::string> select{"time", "u", "y"};
  ASSERT_EQ(parse("\xEF\xBB\xBF\"time\" , \"u\",\"y\"\r\n0, 1e-3 ,-0\r\n0.1,+2,3E2\r\n\r\n  \n", select, "excel.csv",
                  &table),
            std::nullopt);
  ASSERT_EQ(table.rows(), 2u);
  EXPECT_EQ(table.row(0)[1], 1e-3);
  EXPECT_TRUE(std::signbit(table.row(0)[2]));
  EXPECT_EQ(table.row(1)[0], 0.1);
  EXPECT_EQ(table.row(1)[1], 2.0);
  EXPECT_EQ(table.row(1)[2], 300.0);
}

TEST(Csv, AColumnMayBeAskedForTwiceAndNoRowsIsATable) {
  Table table;
  const std::vector<std::string> twice{"y", "y"};
  ASSERT_EQ(parse("t,y\n0,1\n1,2", twice, "x.csv", &table), std::nullopt);  // no newline at the end
  EXPECT_EQ(table.values, (std::vector<double>{1, 1, 2, 2}));
  ASSERT_EQ(parse("t,y\n", twice, "x.csv", &table), std::nullopt);
  EXPECT_EQ(table.rows(), 0u);
}

TEST(Csv, ErrorsNameTheSourceTheLineTheColumnAndTheCell) {
  const std::vector<std::string> ty{"t", "y"};
  EXPECT_EQ(error_of("", ty), "x.csv: no header row (the first line must name the columns)");
  EXPECT_EQ(error_of("t,z\n0,1\n", ty), "x.csv: missing column \"y\" (columns are: t, z)");
  EXPECT_EQ(error_of(",t,y\n0,1,2\n", {""}), "x.csv: missing column \"\" (columns are: t, y)");
  EXPECT_EQ(error_of("t,y,t\n0,1,2\n", ty), "x.csv line 1: column name \"t\" appears twice (columns 1 and 3)");
  EXPECT_EQ(error_of("t,y\n0,1\n\n1,2\n", ty),
            "x.csv line 3: blank line inside the data (only trailing blank lines are allowed)");
  EXPECT_EQ(error_of("t,y\n0,1\n1,2,3\n", ty), "x.csv line 3: expected 2 values, found 3");
  EXPECT_EQ(error_of("t,y\n0,1\n1,2.5x\n", ty), "x.csv line 3, column \"y\": \"2.5x\" is not a number");
  EXPECT_EQ(error_of("t,y\n0,\n", ty), "x.csv line 2, column \"y\": empty value");
  EXPECT_EQ(error_of("t,y\n0,nan\n", ty), "x.csv line 2, column \"y\": \"nan\" is not a finite number");
  EXPECT_EQ(error_of("t,y\n1e999,1\n", ty), "x.csv line 2, column \"t\": \"1e999\" is out of the range of a double");
  // The first bad cell from the left, whatever the order asked for.
  EXPECT_EQ(error_of("t,y\na,b\n", {"y", "t"}), "x.csv line 2, column \"t\": \"a\" is not a number");
  // A runaway cell is cut short.
  const std::string message = error_of("t,y\n0,x" + std::string(500, '7') + "\n", ty);
  EXPECT_NE(message.find("column \"y\": \"x777"), std::string::npos) << message;
  EXPECT_LT(message.size(), 120u);
}

// " F2" is F2; a header ending in a comma has no column named "" in
// messages, and its rows may have the trailing empty cell or not.
TEST(Csv, HeaderNamesAreTrimmedAndATrailingCommaIsNoColumnName) {
  Table table;
  const std::vector<std::string> select{"t", "F2", "h1"};
  ASSERT_EQ(parse("t, F1, F2 ,h1,\n0,1,2,3,\n1,1.5,2.5,3.5\n", select, "rig.csv", &table), std::nullopt);
  ASSERT_EQ(table.rows(), 2u);
  EXPECT_EQ(std::vector<double>(table.row(1).begin(), table.row(1).end()), (std::vector<double>{1, 2.5, 3.5}));
  EXPECT_EQ(error_of("t, F1, F2 ,h1,\n0,1,2,3\n", {"h2"}), "x.csv: missing column \"h2\" (columns are: t, F1, F2, h1)");
  EXPECT_EQ(error_of("t,y,\n0,1,,\n", {"y"}), "x.csv line 2: expected 2 to 3 values, found 4");
  EXPECT_EQ(error_of("t,y,\n0\n", {"y"}), "x.csv line 2: expected 2 to 3 values, found 1");
}

TEST(Csv, UnselectedColumnsAreNotRead) {
  Table table;
  const std::vector<std::string> select{"y"};
  EXPECT_EQ(parse("t,note,y\n,text, 1\nnan,,2\n", select, "x.csv", &table), std::nullopt);
  EXPECT_EQ(table.values, (std::vector<double>{1, 2}));
}

TEST(Csv, ReadsAFileAndNamesItsPath) {
  const auto path = std::filesystem::temp_directory_path() / "riccati-csv-test.csv";
  std::ofstream(path) << "t,y\n0,1\n1,oops\n";
  Table table;
  const std::vector<std::string> select{"t", "y"};
  EXPECT_EQ(read_file(path.string(), select, &table),
            path.string() + " line 3, column \"y\": \"oops\" is not a number");
  std::filesystem::remove(path);
  const auto missing = read_file(path.string(), select, &table);
  ASSERT_TRUE(missing.has_value());
  EXPECT_EQ(*missing, "cannot open \"" + path.string() + "\": No such file or directory");
}

}  // namespace
}  // namespace riccati::csv
