#include <openssl/evp.h>

#include <algorithm>
#include <charconv>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>

#include "commands/commands.hpp"
#include "output.hpp"

namespace riccati::cli {

namespace {

constexpr std::size_t kChunkBytes = 64 * 1024;

// The SHA-256 of a file, as riccatid gives it in DatasetInfo.sha256 (64
// lower-case hex digits); empty when the file cannot be read.
std::string file_sha256(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return "";
  EVP_MD_CTX* md = EVP_MD_CTX_new();
  EVP_DigestInit_ex(md, EVP_sha256(), nullptr);
  std::string buffer(kChunkBytes, '\0');
  while (in.read(buffer.data(), static_cast<std::streamsize>(buffer.size())) || in.gcount() > 0) {
    EVP_DigestUpdate(md, buffer.data(), static_cast<std::size_t>(in.gcount()));
  }
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int size = 0;
  EVP_DigestFinal_ex(md, digest, &size);
  EVP_MD_CTX_free(md);
  if (in.bad()) return "";
  static constexpr char kHexDigits[] = "0123456789abcdef";
  std::string hex;
  for (unsigned int i = 0; i < size; ++i) {
    hex += kHexDigits[digest[i] >> 4];
    hex += kHexDigits[digest[i] & 0xf];
  }
  return hex;
}

// A dataset of the caller's tenant uploaded from the same bytes with the
// same input and output names: what an upload of `o` would make again.
std::optional<v1::DatasetInfo> identical_upload(Client& c, const UploadOptions& o, const std::string& sha256) {
  auto ctx = c.context();
  v1::ListDatasetsResponse list;
  if (sha256.empty() || !c.datasets->ListDatasets(ctx.get(), {}, &list).ok()) return std::nullopt;
  for (const v1::DatasetInfo& d : list.datasets()) {
    if (d.sha256() == sha256 && std::equal(d.input_names().begin(), d.input_names().end(), o.inputs.begin(), o.inputs.end()) &&
        std::equal(d.output_names().begin(), d.output_names().end(), o.outputs.begin(), o.outputs.end())) {
      return d;
    }
  }
  return std::nullopt;
}

}  // namespace

bool is_local_file(const std::string& path) {
  std::error_code ec;
  return std::filesystem::is_regular_file(path, ec);
}

int data_upload(Client& c, const UploadOptions& o, std::string* dataset_id) {
  std::ifstream in(o.file, std::ios::binary);
  if (!in) {
    std::fprintf(stderr, "riccati: cannot open %s\n", o.file.c_str());
    return kExitUsage;
  }
  auto ctx = c.stream_context();
  v1::DatasetInfo info;
  auto writer = c.datasets->UploadDataset(ctx.get(), &info);
  v1::UploadDatasetRequest header;
  auto* h = header.mutable_header();
  h->set_name(o.name.empty() ? std::filesystem::path(o.file).filename().string() : o.name);
  if (o.sample_time != 0.0) {
    h->set_sample_time(o.sample_time);  // and no time column
  } else {
    h->set_time_column(o.time);
  }
  for (const auto& i : o.inputs) h->add_input_columns(i);
  for (const auto& n : o.outputs) h->add_output_columns(n);
  h->mutable_true_parameters()->insert(o.truth.begin(), o.truth.end());
  // Declared, so that the daemon reserves the quota for the whole file at once.
  std::error_code size_error;
  const auto size = std::filesystem::file_size(o.file, size_error);
  if (!size_error) h->set_size_bytes(size);
  bool open = writer->Write(header);
  std::string buffer(kChunkBytes, '\0');
  while (open && in) {
    in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    const auto got = in.gcount();
    if (got <= 0) break;
    v1::UploadDatasetRequest chunk;
    chunk.set_chunk(buffer.data(), static_cast<std::size_t>(got));
    open = writer->Write(chunk);
  }
  writer->WritesDone();
  const grpc::Status s = writer->Finish();
  if (!s.ok()) return c.fail("uploading " + o.file, s);
  if (dataset_id != nullptr) {
    *dataset_id = info.id();
    return kExitOk;
  }
  if (c.json) {
    std::printf("%s\n", to_json(info).c_str());
  } else {
    std::printf("%s\n", info.id().c_str());
  }
  return kExitOk;
}

int data_list(Client& c) {
  auto ctx = c.context();
  v1::ListDatasetsResponse list;
  const grpc::Status s = c.datasets->ListDatasets(ctx.get(), {}, &list);
  if (!s.ok()) return c.fail("listing datasets", s);
  if (c.json) {
    std::printf("%s\n", to_json(list).c_str());
    return kExitOk;
  }
  std::printf("%-22s %-24s %8s %12s %12s\n", "id", "name", "samples", "t start", "t end");
  for (const auto& d : list.datasets()) {
    std::printf("%-22s %-24s %8llu %12.6g %12.6g\n", d.id().c_str(), d.name().c_str(),
                static_cast<unsigned long long>(d.samples()), d.t_start(), d.t_end());
  }
  return kExitOk;
}

int data_show(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::GetDatasetRequest request;
  request.set_id(id);
  v1::DatasetInfo info;
  const grpc::Status s = c.datasets->GetDataset(ctx.get(), request, &info);
  if (!s.ok()) return c.fail("dataset " + id, s);
  if (c.json) {
    std::printf("%s\n", to_json(info).c_str());
    return kExitOk;
  }
  std::printf("%s  %s\n  samples: %llu, t from %.6g to %.6g s\n  inputs:  %s\n  outputs: %s\n  size: %s\n",
              info.id().c_str(), info.name().c_str(), static_cast<unsigned long long>(info.samples()), info.t_start(),
              info.t_end(), join(info.input_names()).c_str(), join(info.output_names()).c_str(),
              counted(info.size_bytes(), "byte").c_str());
  if (!info.true_parameters().empty()) {
    // In name order, as a map's are not.
    const std::map<std::string, double> truth(info.true_parameters().begin(), info.true_parameters().end());
    std::string line;
    char number[32];
    for (const auto& [name, value] : truth) {
      // As given: the shortest text that reads back as the same double.
      const auto end = std::to_chars(number, number + sizeof number, value).ptr;
      line += (line.empty() ? "" : ", ") + name + " = " + std::string(number, end);
    }
    std::printf("  true parameters: %s\n", line.c_str());
  }
  return kExitOk;
}

int data_delete(Client& c, const std::string& id) {
  auto ctx = c.context();
  v1::DeleteDatasetRequest request;
  request.set_id(id);
  v1::DeleteDatasetResponse response;
  const grpc::Status s = c.datasets->DeleteDataset(ctx.get(), request, &response);
  if (!s.ok()) return c.fail("deleting dataset " + id, s);
  if (c.json) std::printf("%s\n", to_json(nlohmann::json{{"id", id}, {"deleted", true}}).c_str());
  return kExitOk;
}

int dataset_for(Client& c, const std::string& data, const std::vector<std::string>& inputs,
                const std::vector<std::string>& outputs, std::string* id, const std::string& model) {
  if (!is_local_file(data)) {
    *id = data;
    return kExitOk;
  }
  UploadOptions upload{data, std::filesystem::path(data).filename().string(), "t", inputs, outputs};
  if (inputs.empty() && outputs.empty() && !model.empty()) {
    // The file's columns named as the model's inputs and outputs.
    v1::ModelInfo info;
    if (const grpc::Status s = c.get_model(model, &info); !s.ok()) return c.fail("model " + model, s);
    upload.inputs.assign(info.input_names().begin(), info.input_names().end());
    upload.outputs.assign(info.output_names().begin(), info.output_names().end());
  }
  // Uploaded before (the same bytes, columns named the same): used again.
  if (const auto same = identical_upload(c, upload, file_sha256(data))) {
    *id = same->id();
    std::fprintf(stderr, "reusing dataset %s (%s): the same bytes as %s (SHA-256), the same columns\n",
                 id->c_str(), same->name().c_str(), data.c_str());
    return kExitOk;
  }
  const int rc = data_upload(c, upload, id);
  if (rc == kExitOk) std::fprintf(stderr, "uploaded %s as dataset %s\n", data.c_str(), id->c_str());
  return rc;
}

}  // namespace riccati::cli
