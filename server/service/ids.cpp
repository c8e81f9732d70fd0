#include "service/ids.hpp"

#include <chrono>
#include <cstdio>
#include <random>

namespace riccati::service {

std::int64_t now_ms() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

std::string new_id(std::string_view prefix) {
  thread_local std::mt19937_64 rng{std::random_device{}()};
  char digits[17];
  std::snprintf(digits, sizeof digits, "%016llx", static_cast<unsigned long long>(rng()));
  return std::string(prefix) + "-" + digits;
}

}  // namespace riccati::service
