// libFuzzer target: the MAT reader (matio underneath). The bytes go to an
// in-memory file, read back by path as an upload is.
#include <sys/mman.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "engine/dataset.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const int fd = memfd_create("fuzz.mat", 0);
  if (fd < 0) std::abort();
  for (std::size_t done = 0; done < size;) {
    const ssize_t n = write(fd, data + done, size - done);
    if (n <= 0) std::abort();
    done += static_cast<std::size_t>(n);
  }
  const std::string path = "/proc/self/fd/" + std::to_string(fd);
  auto parsed = riccati::read_mat_file(path, riccati::ColumnMapping{});
  if (parsed.is_ok() && !riccati::validate_dataset(parsed.value()).is_ok()) std::abort();
  close(fd);
  return 0;
}
