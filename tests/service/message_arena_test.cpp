// The stream's message arena allocates nothing per message once it has
// parsed its first, even when the messages come on different threads, as
// gRPC's callbacks do; and it keeps no more than its first block between
// messages (counted per thread: support/counted_malloc.hpp).
#include "service/rpc/message_arena.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <cstddef>
#include <string>
#include <thread>

#include "riccati/v1/sessions.pb.h"
#include "support/counted_malloc.hpp"

namespace riccati {
namespace {

// A batch as a rig sends it: `count` measurements of two outputs and two inputs.
std::string batch_bytes(int count) {
  v1::StreamRequest request;
  for (int i = 0; i < count; ++i) {
    auto* m = request.mutable_batch()->add_measurements();
    m->set_t(0.1 * i);
    m->add_y(1.0);
    m->add_y(2.0);
    m->add_u(3.0);
    m->add_u(4.0);
  }
  return request.SerializeAsString();
}

// Parses `bytes` into a fresh message, then trims the arena as the stream
// does after each message; the testing::allocations this made on this thread.
std::size_t parse(MessageArena& arena, const std::string& bytes, int expected) {
  const std::size_t before = testing::allocations;
  v1::StreamRequest& request = arena.fresh<v1::StreamRequest>();
  EXPECT_TRUE(request.ParseFromString(bytes));
  EXPECT_EQ(request.batch().measurements_size(), expected);
  arena.trim();
  return testing::allocations - before;
}

// The blocks `trim()` testing::frees after parsing `bytes`.
std::size_t freed_by_trim(MessageArena& arena, const std::string& bytes) {
  EXPECT_TRUE(arena.fresh<v1::StreamRequest>().ParseFromString(bytes));
  const std::size_t before = testing::frees;
  arena.trim();
  return testing::frees - before;
}

TEST(MessageArena, OneThreadParsesWithoutAllocating) {
  MessageArena arena;
  const std::string bytes = batch_bytes(8);
  parse(arena, bytes, 8);
  std::size_t made = 0;
  for (int i = 0; i < 100; ++i) made += parse(arena, bytes, 8);
  EXPECT_EQ(made, 0u);
}

// Two threads take turns, each parsing the next message, as two of gRPC's
// threads run one stream's callbacks: no turn allocates.
TEST(MessageArena, ThreadsTakingTurnsParseWithoutAllocating) {
  MessageArena arena;
  const std::string bytes = batch_bytes(8);
  parse(arena, bytes, 8);
  constexpr int kTurns = 200;
  std::atomic<int> turn{0};
  std::size_t made[2] = {0, 0};
  auto worker = [&](int me) {
    for (int t = me; t < kTurns; t += 2) {
      while (turn.load(std::memory_order_acquire) != t) std::this_thread::yield();
      made[me] += parse(arena, bytes, 8);
      turn.store(t + 1, std::memory_order_release);
    }
  };
  std::thread a(worker, 0), b(worker, 1);
  a.join();
  b.join();
  EXPECT_EQ(made[0] + made[1], 0u) << "allocations in " << kTurns << " messages parsed on alternating threads";
}

// A batch larger than the first block takes more blocks, freed as soon as
// it is answered rather than kept while the stream waits for its next
// message; a small message's first block stays.
TEST(MessageArena, ALargeBatchDoesNotKeepItsBlocks) {
  MessageArena arena;
  const std::string small = batch_bytes(8), large = batch_bytes(2000);
  parse(arena, small, 8);
  EXPECT_EQ(freed_by_trim(arena, small), 0u);
  EXPECT_GT(freed_by_trim(arena, large), 0u);
  EXPECT_EQ(parse(arena, small, 8), 0u);
}

}  // namespace
}  // namespace riccati
