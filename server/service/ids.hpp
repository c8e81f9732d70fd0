// Ids and times of the records the service creates.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

#include "engine/status.hpp"

namespace riccati::service {

// Unix time in milliseconds.
std::int64_t now_ms();
// A new random id such as "job-3f9a0c1d5e7b2a64" (64 random bits).
std::string new_id(std::string_view prefix);

// Strings a client stores beside an object and names it by: a request_id
// (idempotent creation), a dataset's name, its columns' names. Each is held
// to a size fit for a name, so no one stores megabytes in a field that no
// quota counts. INVALID_ARGUMENT naming the field, its size and the limit.
inline constexpr std::size_t kMaxRequestIdBytes = 128;  // a UUID is 36
inline constexpr std::size_t kMaxNameBytes = 256;
Status check_client_string(std::string_view field, std::string_view value, std::size_t max_bytes);

// How long a request_id answers retries (Store::delete_request_ids).
inline constexpr std::int64_t kRequestIdRetentionMs = 7ll * 24 * 3600 * 1000;

}  // namespace riccati::service
