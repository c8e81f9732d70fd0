// The clock a store reckons its leases in (and stamps what it stores with),
// Unix milliseconds. riccatid uses the system's (SQLite) or the database
// server's (PostgreSQL); tests give one they advance themselves
// (tests/support/manual_clock.hpp), so that an expired lease is a step of
// the clock, not a sleep that a loaded host may stretch.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>

namespace riccati {

class StoreClock {
 public:
  virtual ~StoreClock() = default;
  // Thread-safe: the stores read it from any thread.
  virtual std::int64_t now_ms() = 0;
};

class SystemStoreClock final : public StoreClock {
 public:
  std::int64_t now_ms() override {
    return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
        .count();
  }
};

}  // namespace riccati
