// libFuzzer target: the CSV reader. Any bytes either give a dataset that
// passes validate_dataset or an error; never a crash, a hang or a dataset
// that breaks what every filter relies on.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "engine/data/dataset.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  // The mapping of the two-tank data, so mutations of the seed corpus reach
  // the value parser, not only the header check.
  static const riccati::ColumnMapping mapping{"t", {"F1", "F2"}, {"h1", "h2"}};
  auto parsed = riccati::parse_csv(text, mapping, "fuzz.csv");
  if (parsed.is_ok() && !riccati::validate_dataset(parsed.value()).is_ok()) std::abort();
  return 0;
}
