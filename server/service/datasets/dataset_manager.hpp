// DatasetManager: the tenant's datasets. An upload is parsed (CSV or MAT),
// checked (engine/data/dataset.hpp: sizes, finite values, time strictly
// increasing) and held to the limits once, here, and stored with its
// samples; jobs and the API read them back through it.
#pragma once

#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "engine/data/dataset.hpp"
#include "service/limits.hpp"
#include "store/store.hpp"

namespace riccati::service {

enum class DatasetFormat { kCsv, kMat };

struct DatasetUpload {
  std::string name;                     // as the client calls it (a file name); empty: "upload"
  std::optional<DatasetFormat> format;  // none: from the name's extension (.mat, else CSV)
  ColumnMapping mapping;
  std::string bytes;                    // the whole file
  std::string request_id;               // the client's, for an idempotent upload; empty: none
  std::map<std::string, double> true_parameters;  // declared by the client; empty: none
};

class DatasetManager;

// An upload in flight: the room it holds, counted against the uploads in
// flight (max_uploads) and, with what the tenant has stored and its other
// uploads in flight, against its quota (max_tenant_dataset_bytes) before the
// bytes are accepted. Released when it goes.
class UploadTicket {
 public:
  UploadTicket(UploadTicket&& other) noexcept;
  UploadTicket& operator=(UploadTicket&&) = delete;
  ~UploadTicket();
  // The upload now holds `bytes` in all: RESOURCE_EXHAUSTED naming
  // max_dataset_bytes or max_tenant_dataset_bytes if that is too much.
  Status grow(std::int64_t bytes);
  const std::string& tenant() const { return tenant_; }
  std::int64_t bytes() const { return bytes_; }

 private:
  friend class DatasetManager;
  UploadTicket(DatasetManager* manager, std::string tenant, std::string name, std::int64_t stored)
      : manager_(manager), tenant_(std::move(tenant)), name_(std::move(name)), stored_(stored) {}
  DatasetManager* manager_;
  std::string tenant_, name_;
  std::int64_t stored_;  // the tenant's stored bytes when the upload began
  std::int64_t bytes_ = 0;
};

class DatasetManager {
 public:
  DatasetManager(Store& store, Limits limits) : store_(store), limits_(limits) {}

  // Room for an upload of `name` by `tenant`: RESOURCE_EXHAUSTED naming
  // max_uploads when that many are in flight, or the quota when it is full.
  Result<UploadTicket> begin_upload(const std::string& tenant, const std::string& name);
  // Parses, checks and stores an upload whose bytes `ticket` holds; the
  // stored record. The bytes are released once parsed.
  Result<DatasetRecord> upload(UploadTicket& ticket, DatasetUpload& upload);

  Result<DatasetRecord> get(const std::string& tenant, const std::string& id);
  Result<Dataset> load(const std::string& tenant, const std::string& id);
  Result<std::vector<DatasetRecord>> list(const std::string& tenant);
  Status remove(const std::string& tenant, const std::string& id);
  const Limits& limits() const { return limits_; }
  // Uploads holding a place now (of max_uploads), all tenants.
  std::int64_t uploads_in_flight() const {
    std::lock_guard lock(mu_);
    return uploads_;
  }

 private:
  friend class UploadTicket;
  Result<Dataset> parse(std::string bytes, const ColumnMapping& mapping, const std::string& name, DatasetFormat format) const;
  Result<std::int64_t> stored_bytes(const std::string& tenant);
  Status quota_error(std::int64_t used) const;

  Store& store_;
  const Limits limits_;  // max_dataset_bytes, max_dataset_samples, max_tenant_dataset_bytes, max_uploads, max_tenant_uploads
  std::mutex stored_mu_;  // reading what a tenant has stored, and storing an upload and giving back its room
  mutable std::mutex mu_;
  std::int64_t uploads_ = 0;                             // in flight, all tenants
  std::map<std::string, std::int64_t> tenant_uploads_;  // in flight, per tenant
  std::map<std::string, std::int64_t> in_flight_bytes_;  // per tenant
};

}  // namespace riccati::service
