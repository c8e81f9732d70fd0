#include "service/datasets/dataset_manager.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <utility>

#include "engine/sha256.hpp"
#include "service/convert.hpp"
#include "service/ids.hpp"

namespace riccati::service {

UploadTicket::UploadTicket(UploadTicket&& other) noexcept
    : manager_(std::exchange(other.manager_, nullptr)),
      tenant_(std::move(other.tenant_)),
      name_(std::move(other.name_)),
      stored_(other.stored_),
      bytes_(std::exchange(other.bytes_, 0)) {}

UploadTicket::~UploadTicket() {
  if (manager_ == nullptr) return;
  std::lock_guard lock(manager_->mu_);
  --manager_->uploads_;
  if (--manager_->tenant_uploads_[tenant_] == 0) manager_->tenant_uploads_.erase(tenant_);
  if ((manager_->in_flight_bytes_[tenant_] -= bytes_) == 0) manager_->in_flight_bytes_.erase(tenant_);
}

Status UploadTicket::grow(std::int64_t bytes) {
  const Limits& limits = manager_->limits_;
  if (bytes > limits.max_dataset_bytes) {
    return limit_reached("max_dataset_bytes", limits.max_dataset_bytes, "the upload of " + name_ + " is larger");
  }
  std::lock_guard lock(manager_->mu_);
  std::int64_t& in_flight = manager_->in_flight_bytes_[tenant_];
  const std::int64_t used = stored_ + in_flight - bytes_ + bytes;
  if (used > limits.max_tenant_dataset_bytes) return manager_->quota_error(used);
  in_flight += bytes - bytes_;
  bytes_ = bytes;
  return Status::ok();
}

Result<std::int64_t> DatasetManager::stored_bytes(const std::string& tenant) {
  RICCATI_ASSIGN_OR_RETURN(const std::vector<DatasetRecord> stored, store_.list_datasets(tenant));
  std::int64_t bytes = 0;
  for (const DatasetRecord& r : stored) bytes += r.size_bytes;
  return bytes;
}

Status DatasetManager::quota_error(std::int64_t used) const {
  return limit_reached("max_tenant_dataset_bytes", limits_.max_tenant_dataset_bytes,
                       "this tenant's datasets, with its uploads in flight, would take " + std::to_string(used) +
                           " bytes; delete some (DeleteDataset) first");
}

Result<UploadTicket> DatasetManager::begin_upload(const std::string& tenant, const std::string& name) {
  RICCATI_RETURN_IF_ERROR(check_client_string("the dataset's name", name, kMaxNameBytes));
  std::unique_lock stored_lock(stored_mu_);
  RICCATI_ASSIGN_OR_RETURN(const std::int64_t stored, stored_bytes(tenant));
  stored_lock.unlock();
  std::lock_guard lock(mu_);
  if (uploads_ >= limits_.max_uploads) {
    return limit_reached("max_uploads", limits_.max_uploads, "as many uploads are in flight; try again shortly");
  }
  // A share per tenant, so that one tenant's uploads (slow ones too) cannot
  // hold every place.
  std::int64_t& own = tenant_uploads_[tenant];
  if (own >= limits_.max_tenant_uploads) {
    if (own == 0) tenant_uploads_.erase(tenant);
    return limit_reached("max_tenant_uploads", limits_.max_tenant_uploads,
                         "this tenant has as many uploads in flight; wait for one to end");
  }
  ++own;
  ++uploads_;
  return UploadTicket(this, tenant, name.empty() ? "upload" : name, stored);
}

Result<Dataset> DatasetManager::parse(std::string bytes, const ColumnMapping& mapping, const std::string& name,
                                      DatasetFormat format) const {
  if (format == DatasetFormat::kCsv) return parse_csv_releasing(std::move(bytes), mapping, name);
  Result<Dataset> parsed =
      parse_mat(bytes, mapping, name, static_cast<std::uint64_t>(limits_.max_dataset_bytes));
  if (parsed.status().code() == StatusCode::kResourceExhausted) {
    return limit_reached("max_dataset_bytes", limits_.max_dataset_bytes, parsed.status().message());
  }
  return parsed;
}

namespace {

// What a dataset may declare as its true parameters: names as models give
// them (what the result table matches them by), finite values.
Status check_true_parameters(const std::map<std::string, double>& values, const std::string& name) {
  constexpr std::size_t kMaxValues = 64, kMaxName = 64;
  if (values.size() > kMaxValues) {
    return invalid_argument("true_parameters of " + name + ": " + std::to_string(values.size()) +
                            " given, at most " + std::to_string(kMaxValues));
  }
  for (const auto& [parameter, value] : values) {
    const bool well_formed =
        !parameter.empty() && parameter.size() <= kMaxName && std::isdigit(static_cast<unsigned char>(parameter[0])) == 0 &&
        std::all_of(parameter.begin(), parameter.end(),
                    [](char c) { return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_'; });
    if (!well_formed) {
      return invalid_argument("true_parameters of " + name + ": \"" + printable(parameter.substr(0, kMaxName)) +
                              "\" is not a parameter name (letters, digits and '_', at most 64)");
    }
    if (!std::isfinite(value)) {
      return invalid_argument("true_parameters of " + name + ": " + parameter + " is " + std::to_string(value) +
                              ", not a finite number");
    }
  }
  return Status::ok();
}

}  // namespace

Result<DatasetRecord> DatasetManager::upload(UploadTicket& ticket, DatasetUpload& upload) {
  const std::string& tenant = ticket.tenant();
  const std::string name = upload.name.empty() ? "upload" : upload.name;
  const auto size = static_cast<std::int64_t>(upload.bytes.size());
  if (upload.bytes.empty()) return invalid_argument("upload of " + name + " is empty");
  RICCATI_RETURN_IF_ERROR(check_client_string("request_id", upload.request_id, kMaxRequestIdBytes));
  RICCATI_RETURN_IF_ERROR(check_client_string("time_column", upload.mapping.time, kMaxNameBytes));
  for (const auto* columns : {&upload.mapping.inputs, &upload.mapping.outputs}) {
    for (const std::string& column : *columns) {
      RICCATI_RETURN_IF_ERROR(check_client_string(columns == &upload.mapping.inputs ? "an input column's name"
                                                                                     : "an output column's name",
                                                  column, kMaxNameBytes));
    }
  }
  RICCATI_RETURN_IF_ERROR(check_true_parameters(upload.true_parameters, name));
  const std::string extension = std::filesystem::path(name).extension().string();
  const DatasetFormat format =
      upload.format.value_or(extension == ".mat" || extension == ".MAT" ? DatasetFormat::kMat : DatasetFormat::kCsv);
  const std::string digest = sha256_hex(upload.bytes);
  // The bytes are parsed's to let go as soon as they are read: memory peaks
  // once, at the text and its table, not again at the samples and the store.
  RICCATI_ASSIGN_OR_RETURN(const Dataset data, parse(std::exchange(upload.bytes, std::string()), upload.mapping, name, format));
  if (data.size() > limits_.max_dataset_samples) {
    return limit_reached("max_dataset_samples", limits_.max_dataset_samples,
                         name + " has " + std::to_string(data.size()) + " samples");
  }
  // Again with what is stored now: uploads that ended since this one began
  // are stored, those still in flight (this one too) hold their room, so
  // every byte is counted at least once however uploads interleave; and
  // only once: this upload's room is given back as it is stored, while no
  // other upload reads what is stored (stored_mu_).
  std::lock_guard stored_lock(stored_mu_);
  RICCATI_ASSIGN_OR_RETURN(const std::int64_t stored, stored_bytes(tenant));
  {
    std::lock_guard lock(mu_);
    const auto in_flight = in_flight_bytes_.find(tenant);
    const std::int64_t used = stored + (in_flight != in_flight_bytes_.end() ? in_flight->second : 0);
    if (used > limits_.max_tenant_dataset_bytes) return quota_error(used);
  }

  DatasetRecord record;
  record.id = new_id("ds");
  if (!upload.request_id.empty()) {
    // A retry of an upload that was stored gets that dataset. Claimed only
    // now, past every check: a refused upload stores nothing.
    RICCATI_ASSIGN_OR_RETURN(record.id, store_.claim_request_id(tenant, upload.request_id, "dataset", record.id));
    if (Result<DatasetRecord> made = store_.get_dataset(tenant, record.id);
        made.is_ok() || made.status().code() != StatusCode::kNotFound) {
      return made;
    }
  }
  record.tenant = tenant;
  record.name = name;
  record.format = format == DatasetFormat::kMat ? "mat" : "csv";
  record.input_names = data.input_names;
  record.output_names = data.output_names;
  record.samples = data.size();
  record.t_start = data.t[0];
  record.t_end = data.t[data.size() - 1];
  record.size_bytes = size;
  record.sha256 = digest;
  record.true_parameters = upload.true_parameters;
  record.created_ms = now_ms();
  const Status put = store_.put_dataset(record, data);
  if (put.code() == StatusCode::kAlreadyExists && !upload.request_id.empty()) {
    return store_.get_dataset(tenant, record.id);  // a retry of the same upload stored it first
  }
  RICCATI_RETURN_IF_ERROR(put);
  {
    std::lock_guard lock(mu_);
    in_flight_bytes_[tenant] -= std::exchange(ticket.bytes_, 0);
  }
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
