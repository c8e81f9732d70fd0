#include "service/http/rendered_results.hpp"

namespace riccati::service {

std::shared_ptr<const std::string> RenderedResults::find(const std::string& tenant, const std::string& job_id) {
  std::lock_guard lock(mu_);
  const auto it = index_.find(Key{tenant, job_id});
  if (it == index_.end()) return nullptr;
  recent_.splice(recent_.begin(), recent_, it->second);
  return it->second->json;
}

void RenderedResults::put(const std::string& tenant, const std::string& job_id,
                          std::shared_ptr<const std::string> json) {
  if (json == nullptr || json->size() > max_bytes_) return;
  std::lock_guard lock(mu_);
  Key key{tenant, job_id};
  if (const auto it = index_.find(key); it != index_.end()) erase_locked(it);
  bytes_ += json->size();
  recent_.push_front(Entry{key, std::move(json)});
  index_.emplace(std::move(key), recent_.begin());
  while (bytes_ > max_bytes_) erase_locked(index_.find(recent_.back().key));
}

void RenderedResults::erase(const std::string& tenant, const std::string& job_id) {
  std::lock_guard lock(mu_);
  if (const auto it = index_.find(Key{tenant, job_id}); it != index_.end()) erase_locked(it);
}

void RenderedResults::erase_locked(std::map<Key, std::list<Entry>::iterator>::iterator it) {
  bytes_ -= it->second->json->size();
  recent_.erase(it->second);
  index_.erase(it);
}

std::size_t RenderedResults::bytes() const {
  std::lock_guard lock(mu_);
  return bytes_;
}

std::size_t RenderedResults::size() const {
  std::lock_guard lock(mu_);
  return index_.size();
}

}  // namespace riccati::service
