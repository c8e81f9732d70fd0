// Files riccatid reads at start or on a signal: its config, the tokens
// file, TLS certificates and keys. Each must be a regular file of bounded
// size: a FIFO would block the start forever (and SIGTERM with it), and a
// device such as /dev/zero would be read without end.
#pragma once

#include <cstddef>
#include <string>

#include "engine/status.hpp"

namespace riccati::service {

// The whole file, or INVALID_ARGUMENT naming `what`, the path and the fault
// (cannot be opened, not a regular file, larger than `max_bytes`).
Result<std::string> read_regular_file(const std::string& path, const char* what, std::size_t max_bytes);

inline constexpr std::size_t kMaxConfigFileBytes = 1 << 20;    // riccatid's YAML config, a PEM file
inline constexpr std::size_t kMaxTokensFileBytes = 64 << 20;   // ~700,000 tokens

}  // namespace riccati::service
