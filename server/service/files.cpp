#include "service/files.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace riccati::service {

Result<std::string> read_regular_file(const std::string& path, const char* what, std::size_t max_bytes) {
  // O_NONBLOCK: opening a FIFO for reading would wait for a writer.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) return invalid_argument(std::string(what) + " " + path + " cannot be read: " + std::strerror(errno));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    return invalid_argument(std::string(what) + " " + path + " cannot be read: " + std::strerror(errno));
  }
  if (!S_ISREG(st.st_mode)) {
    return invalid_argument(std::string(what) + " " + path +
                            " is not a regular file (a FIFO, a device or a directory): give the path of a file");
  }
  if (static_cast<std::size_t>(st.st_size) > max_bytes) {
    return invalid_argument(std::string(what) + " " + path + " is " + std::to_string(st.st_size) +
                            " bytes, more than the " + std::to_string(max_bytes) + " such a file may have");
  }
  // Read up to one byte past the limit: a file growing while it is read
  // is still held to it.
  std::string text(static_cast<std::size_t>(st.st_size), '\0');
  std::size_t got = 0;
  char extra = 0;
  for (;;) {
    char* at = got < text.size() ? text.data() + got : &extra;
    const std::size_t room = got < text.size() ? text.size() - got : 1;
    const ssize_t n = ::read(fd, at, room);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return invalid_argument(std::string(what) + " " + path + " cannot be read: " + std::strerror(errno));
    if (n == 0) break;
    if (got >= text.size()) {
      return invalid_argument(std::string(what) + " " + path + " grew while it was read");
    }
    got += static_cast<std::size_t>(n);
  }
  text.resize(got);
  return text;
}

}  // namespace riccati::service
