// The models a tenant can use: the daemon's built-in ones (its models
// directory: plugins and text files, for every tenant) and the text models
// the tenant uploaded (CreateModel), kept in the store, every revision.
//
// A stored model is named by its name (the latest revision) or by
// name@revision (that one, even after a newer upload or a DeleteModel). A job
// is stored with the name@revision it was checked against at submit
// (resolve().reference), so a new upload never changes a job's model behind
// its back. Compiled models are cached per (tenant, name, revision); another
// tenant's models are never found (NOT_FOUND, as a missing one).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include "engine/models/plugin_loader.hpp"
#include "store/store.hpp"

namespace riccati::service {

// One model as ListModels and GetModel show it.
struct CatalogEntry {
  ModelPtr model;
  JacobianCheck jacobian_check;
  const TextModelSummary* text = nullptr;  // a text model's equations and sparsity (owned by the catalog)
  std::int64_t revision = 0;               // a stored model's; 0 for a built-in one
  std::string sha256;                      // of its file or its source
  std::string source;                      // a text model's YAML
};

struct ResolvedModel {
  ModelPtr model;
  std::string reference;  // what names exactly this model: name@revision if stored, else the name
};

class ModelCatalog {
 public:
  ModelCatalog(const ModelRegistry& builtins, Store& store) : builtins_(builtins), store_(store) {}

  Result<ResolvedModel> resolve(const std::string& tenant, std::string_view name) const;
  Result<ModelPtr> get(const std::string& tenant, std::string_view name) const;

  // Built-in models first, then the tenant's, by name.
  Result<std::vector<CatalogEntry>> list(const std::string& tenant) const;
  Result<CatalogEntry> describe(const std::string& tenant, std::string_view name) const;

  // Compiles `source` and stores it as the next revision of its name for
  // `tenant`. INVALID_ARGUMENT (the compiler's message: line, column, caret)
  // and nothing stored when it is refused; ALREADY_EXISTS when a built-in
  // model has its name.
  // `origin` names the text in messages (the client's file name).
  Result<CatalogEntry> create(const std::string& tenant, const std::string& source, const std::string& origin) const;
  Status remove(const std::string& tenant, const std::string& name) const;

 private:
  struct Compiled {
    ModelPtr model;
    TextModelSummary summary;
    JacobianCheck jacobian_check;
  };
  Result<std::shared_ptr<const Compiled>> compiled(const ModelRecord& record) const;
  CatalogEntry entry_of(const ModelRecord& record, const Compiled& c) const;
  CatalogEntry builtin_entry(const ModelPtr& model) const;

  const ModelRegistry& builtins_;
  Store& store_;
  mutable std::mutex mu_;
  // (tenant, name, revision) -> compiled model; revisions never change.
  mutable std::map<std::tuple<std::string, std::string, std::int64_t>, std::shared_ptr<const Compiled>> cache_;
};

}  // namespace riccati::service
