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

Status check_client_string(std::string_view field, std::string_view value, std::size_t max_bytes) {
  if (value.size() <= max_bytes) return Status::ok();
  return invalid_argument(std::string(field) + " is " + std::to_string(value.size()) + " bytes long; it may be at most " +
                          std::to_string(max_bytes));
}

}  // namespace riccati::service
