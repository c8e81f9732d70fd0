// The JSON of job results, kept once written: a result never changes once
// stored, and writing it is most of a GetResult over HTTP (100,000 doubles
// formatted: about 10 ms for the two-tank 10-pass result, against under
// 1 ms for gRPC's binary encoding). Bounded by bytes; the least recently
// used go first. Keys are (tenant, job id): a tenant only ever finds its own.
// The caller still asks the store whether the job exists before serving a
// kept one, so a deleted job's result is not served from here.
#pragma once

#include <cstddef>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

namespace riccati::service {

class RenderedResults {
 public:
  explicit RenderedResults(std::size_t max_bytes) : max_bytes_(max_bytes) {}

  // The JSON kept for this job, or null.
  std::shared_ptr<const std::string> find(const std::string& tenant, const std::string& job_id);
  // Keeps `json` (nothing if it alone is over the bound), dropping the least
  // recently used until the rest fits.
  void put(const std::string& tenant, const std::string& job_id, std::shared_ptr<const std::string> json);
  void erase(const std::string& tenant, const std::string& job_id);

  std::size_t bytes() const;
  std::size_t size() const;

 private:
  using Key = std::pair<std::string, std::string>;
  struct Entry {
    Key key;
    std::shared_ptr<const std::string> json;
  };
  void erase_locked(std::map<Key, std::list<Entry>::iterator>::iterator it);

  const std::size_t max_bytes_;
  mutable std::mutex mu_;
  std::list<Entry> recent_;  // most recently used first
  std::map<Key, std::list<Entry>::iterator> index_;
  std::size_t bytes_ = 0;
};

}  // namespace riccati::service
