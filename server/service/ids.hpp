// Ids and times of the records the service creates.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

namespace riccati::service {

// Unix time in milliseconds.
std::int64_t now_ms();
// A new random id such as "job-3f9a0c1d5e7b2a64" (64 random bits).
std::string new_id(std::string_view prefix);

}  // namespace riccati::service
