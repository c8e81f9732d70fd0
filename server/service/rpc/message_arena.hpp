// A protobuf arena that holds one message at a time, for a stream that
// parses message after message: parsing into a reused message would still
// free and allocate its oneof members and every repeated element, while an
// arena emptied between messages reuses its first block.
#pragma once

#include <google/protobuf/arena.h>

#include <cstddef>
#include <memory>

namespace riccati {

class MessageArena {
 public:
  static constexpr std::size_t kBlockBytes = 16 * 1024;

  MessageArena() = default;
  MessageArena(const MessageArena&) = delete;
  MessageArena& operator=(const MessageArena&) = delete;

  // The message before is gone; a new, empty one on this arena. The arena
  // is emptied here, on the thread that parses: protobuf gives its first
  // block to the thread that last emptied it, and any other thread a block
  // of its own (a 16 KiB malloc), while gRPC runs a stream's callbacks on
  // whichever of its threads is free.
  template <class Message>
  Message& fresh() {
    arena_.Reset();
    return *google::protobuf::Arena::CreateMessage<Message>(&arena_);
  }

  // Frees the blocks beyond the first (a large batch's) now rather than at
  // the next message.
  void trim() {
    if (arena_.SpaceAllocated() > kBlockBytes) arena_.Reset();
  }

 private:
  static google::protobuf::ArenaOptions options(char* first_block) {
    google::protobuf::ArenaOptions o;
    o.initial_block = first_block;
    o.initial_block_size = kBlockBytes;
    o.start_block_size = kBlockBytes;
    return o;
  }

  std::unique_ptr<char[]> first_block_ = std::make_unique<char[]>(kBlockBytes);
  google::protobuf::Arena arena_{options(first_block_.get())};
};

}  // namespace riccati
