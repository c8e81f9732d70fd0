// ResultReads: large result reads share a budget of stored bytes; a read
// waits for room, is refused naming the limit when none comes, and one larger
// than the budget goes alone.
#include "service/jobs/result_reads.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <thread>

namespace riccati::service {
namespace {

using namespace std::chrono_literals;
constexpr std::int64_t kMiB = 1 << 20;

TEST(ResultReads, SmallReadsAreNotCounted) {
  ResultReads reads(2 * kMiB, 10ms);
  auto big = reads.acquire(2 * kMiB);
  ASSERT_TRUE(big.is_ok());
  // The budget is taken, yet reads under 1 MiB go through at once.
  for (int i = 0; i < 100; ++i) EXPECT_TRUE(reads.acquire(ResultReads::kSmall - 1).is_ok());
}

TEST(ResultReads, AReadWaitsForRoomThenIsRefusedNamingTheLimit) {
  ResultReads reads(3 * kMiB, 50ms);
  auto first = reads.acquire(2 * kMiB);
  ASSERT_TRUE(first.is_ok());
  const auto refused = reads.acquire(2 * kMiB);
  ASSERT_EQ(refused.status().code(), StatusCode::kResourceExhausted);
  EXPECT_NE(refused.status().message().find("limit max_result_read_bytes = 3145728 reached: results of 2097152 bytes "
                                            "are being read, and this one is 2097152; try again shortly"),
            std::string::npos)
      << refused.status().message();
  EXPECT_TRUE(reads.acquire(kMiB).is_ok()) << "one that fits beside it goes through";
  first.value().reset();  // the first read's answer is sent
  EXPECT_TRUE(reads.acquire(2 * kMiB).is_ok());
}

TEST(ResultReads, AWaitingReadGoesOnceRoomIsGivenBack) {
  ResultReads reads(2 * kMiB, 10s);
  auto first = reads.acquire(2 * kMiB);
  ASSERT_TRUE(first.is_ok());
  std::atomic<bool> got{false};
  std::thread waiter([&] {
    auto second = reads.acquire(2 * kMiB);
    got = second.is_ok();
  });
  std::this_thread::sleep_for(50ms);
  EXPECT_FALSE(got.load()) << "the second read did not wait for room";
  first.value().reset();
  waiter.join();
  EXPECT_TRUE(got.load());
}

TEST(ResultReads, AtShutdownAWaitingReadEndsAtOnce) {
  ResultReads reads(2 * kMiB, 60s);
  auto first = reads.acquire(2 * kMiB);
  ASSERT_TRUE(first.is_ok());
  std::thread stopper([&] {
    std::this_thread::sleep_for(50ms);
    reads.stop();
  });
  const auto began = std::chrono::steady_clock::now();
  const auto waiting = reads.acquire(2 * kMiB);
  stopper.join();
  EXPECT_EQ(waiting.status().code(), StatusCode::kUnavailable);
  EXPECT_LT(std::chrono::steady_clock::now() - began, 10s) << "the waiting read held the stop";
}

TEST(ResultReads, AReadLargerThanTheBudgetGoesAlone) {
  ResultReads reads(2 * kMiB, 20ms);
  auto huge = reads.acquire(10 * kMiB);
  ASSERT_TRUE(huge.is_ok()) << "a result larger than the budget could never be read";
  EXPECT_FALSE(reads.acquire(kMiB).is_ok()) << "nothing beside it";
  huge.value().reset();
  EXPECT_TRUE(reads.acquire(kMiB).is_ok());
}

}  // namespace
}  // namespace riccati::service
