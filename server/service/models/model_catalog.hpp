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
//
// The models directory is read again by reload() (ReloadModels, SIGHUP): the
// new set of built-in models replaces the old one at once, and whoever holds
// a ModelPtr of the old set (a session, a running job) keeps running on it.
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
#include "service/limits.hpp"
#include "store/store.hpp"

namespace riccati::service {

// One model as ListModels and GetModel show it.
struct CatalogEntry {
  ModelPtr model;
  JacobianCheck jacobian_check;
  // A text model's equations and sparsity; null for a plugin. Shares the
  // ownership of what holds it (a registry, a compiled revision), so it
  // outlives a reload.
  std::shared_ptr<const TextModelSummary> text;
  std::int64_t revision = 0;               // a stored model's; 0 for a built-in one
  std::vector<std::int64_t> revisions;     // a stored model's revisions not deleted, oldest first
  std::string sha256;                      // of its file or its source
  std::string source;                      // a text model's YAML
};

struct ResolvedModel {
  ModelPtr model;
  std::string reference;  // what names exactly this model: name@revision if stored, else the name
};

// What a reload found, by model name.
struct ReloadReport {
  std::vector<std::string> added, changed, removed, unchanged;
  std::vector<RefusedPlugin> refused;
};

class ModelCatalog {
 public:
  // `models_dir` is what reload() reads again; empty: reload() is refused.
  ModelCatalog(ModelRegistry builtins, Store& store, Limits limits = {}, std::string models_dir = "");

  Result<ResolvedModel> resolve(const std::string& tenant, std::string_view name) const;
  Result<ModelPtr> get(const std::string& tenant, std::string_view name) const;

  // Built-in models first, then the tenant's, by name.
  Result<std::vector<CatalogEntry>> list(const std::string& tenant) const;
  Result<CatalogEntry> describe(const std::string& tenant, std::string_view name) const;

  // Compiles `source` and stores it as the next revision of its name for
  // `tenant`. INVALID_ARGUMENT (the compiler's message: line, column, caret)
  // and nothing stored when it is refused; ALREADY_EXISTS when a built-in
  // model has its name; RESOURCE_EXHAUSTED naming max_tenant_models or
  // max_tenant_model_bytes when the tenant's stored models would pass them.
  // With `validate_only` the same checks but the quota's, and nothing is
  // stored (the entry's revision is 0). A model whose Jacobian check would
  // cost more than max_model_check_operations is refused before it runs
  // (RESOURCE_EXHAUSTED); compiling and checking hold no lock.
  // `origin` names the text in messages (the client's file name).
  Result<CatalogEntry> create(const std::string& tenant, const std::string& source, const std::string& origin,
                              bool validate_only = false) const;
  Status remove(const std::string& tenant, const std::string& name) const;

  // Reads the models directory again. On an error (the directory is gone,
  // or others can write to it) the models in use stay as they were.
  Result<ReloadReport> reload();
  // The built-in models now (a snapshot that a reload does not change).
  std::shared_ptr<const ModelRegistry> builtins() const;

 private:
  struct Compiled {
    ModelPtr model;
    TextModelSummary summary;
    JacobianCheck jacobian_check;
  };
  // The record compiled and checked (cached); `checked`: its check, done already.
  Result<std::shared_ptr<const Compiled>> compiled(const ModelRecord& record,
                                                   const JacobianCheck* checked = nullptr) const;
  // RESOURCE_EXHAUSTED naming max_model_check_operations when the model's
  // Jacobian check would cost more.
  Status check_cost(const std::string& name, const TextModelSummary& summary) const;
  CatalogEntry entry_of(const ModelRecord& record, const std::shared_ptr<const Compiled>& c) const;
  static CatalogEntry builtin_entry(const std::shared_ptr<const ModelRegistry>& registry, const ModelPtr& model);
  Status check_quota(const std::string& tenant, std::int64_t source_bytes) const;

  Store& store_;
  const Limits limits_;
  const std::string models_dir_;
  mutable std::mutex builtins_mu_;
  std::shared_ptr<const ModelRegistry> builtins_;  // replaced whole by reload()
  std::mutex reload_mu_;                           // one reload at a time
  mutable std::mutex create_mu_;                   // a quota's check and the store's put together
  mutable std::mutex mu_;
  // (tenant, name, revision) -> compiled model; revisions never change.
  // `text` with the models directory's path taken out (a file's path is its
  // name within it): what a tenant is shown of the server's files.
  std::string without_server_paths(std::string text) const;
  static constexpr std::size_t kMaxCompiledModels = 256;
  mutable std::map<std::tuple<std::string, std::string, std::int64_t>, std::shared_ptr<const Compiled>> cache_;
};

// Logs what a registry loaded and refused (at start and after a reload).
void log_models(const ModelRegistry& registry);

}  // namespace riccati::service
