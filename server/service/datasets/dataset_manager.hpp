// DatasetManager: the tenant's datasets. An upload is parsed (CSV or MAT),
// checked (engine/data/dataset.hpp: sizes, finite values, time strictly
// increasing) and held to the limits once, here, and stored with its
// samples; jobs and the API read them back through it.
#pragma once

#include <cstdint>
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
};

class DatasetManager {
 public:
  DatasetManager(Store& store, Limits limits) : store_(store), limits_(limits) {}

  // RESOURCE_EXHAUSTED (max_dataset_bytes) once an upload of `name` would
  // hold more than the limit: checked as its chunks arrive.
  Status check_upload_size(std::int64_t bytes, const std::string& name) const;
  // Parses, checks and stores an upload; the stored record.
  Result<DatasetRecord> upload(const std::string& tenant, const DatasetUpload& upload);

  Result<DatasetRecord> get(const std::string& tenant, const std::string& id);
  Result<Dataset> load(const std::string& tenant, const std::string& id);
  Result<std::vector<DatasetRecord>> list(const std::string& tenant);
  Status remove(const std::string& tenant, const std::string& id);

 private:
  Result<Dataset> parse(const DatasetUpload& upload, const std::string& name, DatasetFormat format) const;
  // max_tenant_dataset_bytes, with `adding` bytes more.
  Status check_tenant_room(const std::string& tenant, std::int64_t adding);

  Store& store_;
  const Limits limits_;  // max_dataset_bytes, max_dataset_samples, max_tenant_dataset_bytes
};

}  // namespace riccati::service
