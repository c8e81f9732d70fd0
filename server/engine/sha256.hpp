// SHA-256 (OpenSSL's): of plugin files, logged as they load, and of bearer
// tokens, which the tokens file holds only as digests.
#pragma once

#include <string>
#include <string_view>

#include "engine/status.hpp"

namespace riccati {

// 64 lower-case hex digits.
std::string sha256_hex(std::string_view bytes);
Result<std::string> file_sha256(const std::string& path);

}  // namespace riccati
