#include "service/datasets/dataset_manager.hpp"

#include <spdlog/spdlog.h>

#include <filesystem>

#include "service/ids.hpp"

namespace riccati::service {

Status DatasetManager::check_upload_size(std::int64_t bytes, const std::string& name) const {
  if (bytes <= limits_.max_dataset_bytes) return Status::ok();
  return limit_reached("max_dataset_bytes", limits_.max_dataset_bytes, "the upload of " + name + " is larger");
}

Result<Dataset> DatasetManager::parse(const DatasetUpload& upload, const std::string& name,
                                      DatasetFormat format) const {
  if (format == DatasetFormat::kCsv) return parse_csv(upload.bytes, upload.mapping, name);
  Result<Dataset> parsed =
      parse_mat(upload.bytes, upload.mapping, name, static_cast<std::uint64_t>(limits_.max_dataset_bytes));
  if (parsed.status().code() == StatusCode::kResourceExhausted) {
    return limit_reached("max_dataset_bytes", limits_.max_dataset_bytes, parsed.status().message());
  }
  return parsed;
}

Status DatasetManager::check_tenant_room(const std::string& tenant, std::int64_t adding) {
  // Checked before storing, so concurrent uploads of one tenant may pass it
  // together: a soft limit, by at most one upload per connection.
  RICCATI_ASSIGN_OR_RETURN(const std::vector<DatasetRecord> stored, store_.list_datasets(tenant));
  std::int64_t used = adding;
  for (const DatasetRecord& r : stored) used += r.size_bytes;
  if (used <= limits_.max_tenant_dataset_bytes) return Status::ok();
  return limit_reached("max_tenant_dataset_bytes", limits_.max_tenant_dataset_bytes,
                       "this tenant's datasets would take " + std::to_string(used) +
                           " bytes; delete some (DeleteDataset) first");
}

Result<DatasetRecord> DatasetManager::upload(const std::string& tenant, const DatasetUpload& upload) {
  const std::string name = upload.name.empty() ? "upload" : upload.name;
  const auto size = static_cast<std::int64_t>(upload.bytes.size());
  RICCATI_RETURN_IF_ERROR(check_upload_size(size, name));
  if (upload.bytes.empty()) return invalid_argument("upload of " + name + " is empty");
  const std::string extension = std::filesystem::path(name).extension().string();
  const DatasetFormat format =
      upload.format.value_or(extension == ".mat" || extension == ".MAT" ? DatasetFormat::kMat : DatasetFormat::kCsv);
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, parse(upload, name, format));
  if (data.size() > limits_.max_dataset_samples) {
    return limit_reached("max_dataset_samples", limits_.max_dataset_samples,
                         name + " has " + std::to_string(data.size()) + " samples");
  }
  RICCATI_RETURN_IF_ERROR(check_tenant_room(tenant, size));

  DatasetRecord record;
  record.id = new_id("ds");
  record.tenant = tenant;
  record.name = name;
  record.format = format == DatasetFormat::kMat ? "mat" : "csv";
  record.input_names = data.input_names;
  record.output_names = data.output_names;
  record.samples = data.size();
  record.t_start = data.t[0];
  record.t_end = data.t[data.size() - 1];
  record.size_bytes = size;
  record.created_ms = now_ms();
  RICCATI_RETURN_IF_ERROR(store_.put_dataset(record, data));
  spdlog::info("dataset stored id={} name={} samples={} tenant={}", record.id, record.name, record.samples,
               record.tenant);
  return record;
}

Result<DatasetRecord> DatasetManager::get(const std::string& tenant, const std::string& id) {
  return store_.get_dataset(tenant, id);
}

Result<Dataset> DatasetManager::load(const std::string& tenant, const std::string& id) {
  return store_.load_dataset(tenant, id);
}

Result<std::vector<DatasetRecord>> DatasetManager::list(const std::string& tenant) {
  return store_.list_datasets(tenant);
}

Status DatasetManager::remove(const std::string& tenant, const std::string& id) {
  return store_.delete_dataset(tenant, id);
}

}  // namespace riccati::service
