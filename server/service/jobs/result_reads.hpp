// Results being read at once (GetResult over gRPC, and over HTTP as JSON).
// A read holds its result several times while it is decoded and converted
// (the stored bytes, the message, gRPC's encoding or the JSON: 3 to 5 times
// its size), so reads of large results at once would take riccatid's memory:
// they are held to max_result_read_bytes of stored bytes together. A read
// waits a while for room, then is refused naming the limit; a result larger
// than the whole budget is read when nothing else is.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>

#include "engine/status.hpp"
#include "service/limits.hpp"

namespace riccati::service {

class ResultReads {
 public:
  // Reads below this size are not counted: they cost little, and most are.
  static constexpr std::int64_t kSmall = 1 << 20;

  explicit ResultReads(std::int64_t max_bytes, std::chrono::milliseconds wait = std::chrono::seconds(10))
      : max_bytes_(max_bytes), wait_(wait) {}

  // Room for a read of `bytes`, held while the returned handle lives (share
  // it with whatever sends the answer).
  Result<std::shared_ptr<const void>> acquire(std::int64_t bytes) {
    if (bytes < kSmall) return std::shared_ptr<const void>();
    std::unique_lock lock(mu_);
    const bool room = changed_.wait_for(
        lock, wait_, [&] { return stopping_ || reading_ == 0 || reading_ + bytes <= max_bytes_; });
    if (stopping_) return Status(StatusCode::kUnavailable, "riccatid is shutting down: read the result again later");
    if (!room) {
      return limit_reached("max_result_read_bytes", max_bytes_,
                           "results of " + std::to_string(reading_) + " bytes are being read, and this one is " +
                               std::to_string(bytes) + "; try again shortly");
    }
    reading_ += bytes;
    return std::shared_ptr<const void>(nullptr, [this, bytes](const void*) { release(bytes); });
  }

  // Shutdown: reads waiting for room end at once (UNAVAILABLE), so that
  // they do not hold the server's stop.
  void stop() {
    {
      std::lock_guard lock(mu_);
      stopping_ = true;
    }
    changed_.notify_all();
  }

 private:
  void release(std::int64_t bytes) {
    {
      std::lock_guard lock(mu_);
      reading_ -= bytes;
    }
    changed_.notify_all();
  }

  const std::int64_t max_bytes_;
  const std::chrono::milliseconds wait_;
  std::mutex mu_;
  std::condition_variable changed_;
  std::int64_t reading_ = 0;
  bool stopping_ = false;
};

}  // namespace riccati::service
