// StreamSlots: the places for long-lived calls (session streams, job
// watches, uploads over gRPC; the workbench's event streams), per tenant and
// in all, so that one client holding
// thousands of them open cannot take the daemon's memory and file
// descriptors from the other tenants. A call takes its place when it opens
// and gives it back when it ends (the StreamSlot goes out of scope).
#pragma once

#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <utility>

#include "service/limits.hpp"

namespace riccati::service {

class StreamSlots;

// One call's place; empty when moved from.
class StreamSlot {
 public:
  StreamSlot() = default;
  StreamSlot(StreamSlot&& other) noexcept : slots_(std::exchange(other.slots_, nullptr)), tenant_(std::move(other.tenant_)) {}
  StreamSlot& operator=(StreamSlot&& other) noexcept {
    if (this != &other) {
      release();
      slots_ = std::exchange(other.slots_, nullptr);
      tenant_ = std::move(other.tenant_);
    }
    return *this;
  }
  ~StreamSlot() { release(); }

 private:
  friend class StreamSlots;
  StreamSlot(StreamSlots* slots, std::string tenant) : slots_(slots), tenant_(std::move(tenant)) {}
  void release();

  StreamSlots* slots_ = nullptr;
  std::string tenant_;
};

class StreamSlots {
 public:
  explicit StreamSlots(const Limits& limits) : max_(limits.max_streams), max_tenant_(limits.max_tenant_streams) {}
  StreamSlots(const StreamSlots&) = delete;
  StreamSlots& operator=(const StreamSlots&) = delete;

  // A place for a `what` call of `tenant`, or RESOURCE_EXHAUSTED naming
  // max_tenant_streams or max_streams.
  Result<StreamSlot> acquire(const std::string& tenant, const std::string& what) {
    std::lock_guard lock(mu_);
    std::int64_t& mine = open_[tenant];
    if (mine >= max_tenant_) {
      return limit_reached("max_tenant_streams", max_tenant_,
                           "this tenant has as many streams, watches and uploads open; close one to open this " + what);
    }
    if (total_ >= max_) {
      return limit_reached("max_streams", max_,
                           "as many streams, watches and uploads are open; try this " + what + " again shortly");
    }
    ++mine;
    ++total_;
    return StreamSlot(this, tenant);
  }

  std::int64_t open() const {
    std::lock_guard lock(mu_);
    return total_;
  }

 private:
  friend class StreamSlot;
  void release(const std::string& tenant) {
    std::lock_guard lock(mu_);
    auto it = open_.find(tenant);
    if (it != open_.end() && --it->second == 0) open_.erase(it);
    --total_;
  }

  const std::int64_t max_;
  const std::int64_t max_tenant_;
  mutable std::mutex mu_;
  std::map<std::string, std::int64_t> open_;  // tenants with calls open
  std::int64_t total_ = 0;
};

inline void StreamSlot::release() {
  if (slots_ != nullptr) std::exchange(slots_, nullptr)->release(tenant_);
}

}  // namespace riccati::service
