// A store clock (store/clock.hpp) that moves only when the test moves it:
// a lease expires at a step of advance(), whatever the host's load. It
// starts at the real time, so that what it stamps looks as it would.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>

#include "store/clock.hpp"

namespace riccati::testing {

class ManualClock final : public StoreClock {
 public:
  // `step_per_read`: how far each read moves it (0: it stands still), for a
  // test that tells the store's reads apart by the time they give.
  explicit ManualClock(std::int64_t step_per_read = 0)
      : now_(SystemStoreClock().now_ms()), step_(step_per_read) {}

  std::int64_t now_ms() override { return now_.fetch_add(step_); }
  // What the next read gives, without moving it.
  std::int64_t peek() const { return now_.load(); }
  void advance(std::chrono::milliseconds by) { now_ += by.count(); }

 private:
  std::atomic<std::int64_t> now_;
  const std::int64_t step_;
};

}  // namespace riccati::testing
