// Waiting on what a test can observe, with a deadline, instead of sleeping
// for a time hoped to be long enough: a sleep that is too short makes a
// test flaky, one that is long enough today proves nothing tomorrow.
//
//   ASSERT_TRUE(testing::wait_until([&] { return state_of(job) == RUNNING; },
//                                   std::chrono::seconds(30), "the job runs"));
#pragma once

#include <gtest/gtest.h>

#include <chrono>
#include <string>
#include <thread>

namespace riccati::testing {

// Calls `done` every `every` until it returns true (success), or until
// `timeout` has passed (failure, naming `what` and how long was waited).
// `done` is called once more at the deadline, so a slow poll cannot time
// out a condition that holds by then.
template <typename Predicate>
[[nodiscard]] ::testing::AssertionResult wait_until(Predicate&& done, std::chrono::milliseconds timeout,
                                                    const std::string& what,
                                                    std::chrono::milliseconds every = std::chrono::milliseconds(10)) {
  const auto start = std::chrono::steady_clock::now();
  const auto deadline = start + timeout;
  for (;;) {
    const bool last_chance = std::chrono::steady_clock::now() >= deadline;
    if (done()) return ::testing::AssertionSuccess();
    if (last_chance) {
      return ::testing::AssertionFailure() << "timed out after " << timeout.count() << " ms waiting until " << what;
    }
    std::this_thread::sleep_for(every);
  }
}

}  // namespace riccati::testing
