// libFuzzer target: the MAT reader, the screen of mat_screen.hpp and then
// matio on what the screen kept, as an upload is read. The values may claim
// 64 MiB at most, as a daemon's max_dataset_bytes would allow.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "engine/data/dataset.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  constexpr std::uint64_t kMaxValueBytes = 64 << 20;
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  auto parsed = riccati::parse_mat(bytes, riccati::ColumnMapping{}, "fuzz.mat", kMaxValueBytes);
  if (parsed.is_ok() && !riccati::validate_dataset(parsed.value()).is_ok()) std::abort();
  return 0;
}
