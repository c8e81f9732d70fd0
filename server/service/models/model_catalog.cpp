#include "service/models/model_catalog.hpp"

#include <spdlog/spdlog.h>

#include <charconv>
#include <filesystem>

#include "engine/sha256.hpp"
#include "service/ids.hpp"

namespace riccati::service {

namespace {

struct Name {
  std::string name;
  std::int64_t revision = 0;  // 0: the latest
};

Result<Name> parse_name(std::string_view s) {
  const auto at = s.find('@');
  if (at == std::string_view::npos) return Name{std::string(s), 0};
  Name n{std::string(s.substr(0, at)), 0};
  const std::string_view digits = s.substr(at + 1);
  const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), n.revision);
  if (ec != std::errc() || ptr != digits.data() + digits.size() || n.revision <= 0) {
    return invalid_argument("model \"" + std::string(s) + "\": a revision is a positive number (name@3)");
  }
  return n;
}

// A stored revision; a deleted one that was purged (Store::purge_unused_models
// keeps its number, not its source) is NOT_FOUND.
Result<ModelRecord> stored_model(Store& store, const std::string& tenant, const Name& n) {
  RICCATI_ASSIGN_OR_RETURN(ModelRecord record, store.get_model(tenant, n.name, n.revision));
  if (record.deleted && record.source.empty()) return not_found("model " + n.name + " was deleted");
  return record;
}

Status no_model(std::string_view name) { return not_found("no model \"" + std::string(name) + "\" is loaded"); }

// The revisions of `name` among a tenant's, oldest first.
std::vector<std::int64_t> revisions_of(const std::vector<ModelRevision>& all, const std::string& name) {
  std::vector<std::int64_t> out;
  for (const ModelRevision& r : all) {
    if (r.name == name) out.push_back(r.revision);
  }
  return out;
}

}  // namespace

void log_models(const ModelRegistry& registry) {
  for (const auto& m : registry.models()) {
    spdlog::info("model loaded name={} version={} path={} sha256={}", m->name(), m->version(), m->origin(),
                 registry.sha256(*m));
    for (const std::string& d : registry.jacobian_check(*m).disagreements) {
      spdlog::warn("model Jacobian disagrees with finite differences name={} detail=\"{}\"", m->name(), d);
    }
  }
  for (const auto& r : registry.refused()) spdlog::warn("model refused path={} reason=\"{}\"", r.path, r.reason);
}

ModelCatalog::ModelCatalog(ModelRegistry builtins, Store& store, Limits limits, std::string models_dir)
    : store_(store),
      limits_(limits),
      models_dir_(std::move(models_dir)),
      builtins_(std::make_shared<const ModelRegistry>(std::move(builtins))) {}

std::shared_ptr<const ModelRegistry> ModelCatalog::builtins() const {
  std::lock_guard lock(builtins_mu_);
  return builtins_;
}

std::string ModelCatalog::without_server_paths(std::string text) const {
  std::string dir = std::filesystem::path(models_dir_).lexically_normal().string();
  while (dir.size() > 1 && dir.back() == '/') dir.pop_back();
  if (dir.empty()) return text;
  for (const auto& [from, to] : {std::pair{dir + "/", std::string()}, std::pair{dir, std::string("the models directory")}}) {
    for (std::size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size())) {
      text.replace(at, from.size(), to);
    }
  }
  return text;
}

Result<ReloadReport> ModelCatalog::reload() {
  if (models_dir_.empty()) return failed_precondition("this riccatid was started without a models directory to reload");
  std::lock_guard one_at_a_time(reload_mu_);
  const std::shared_ptr<const ModelRegistry> before = builtins();
  Result<ModelRegistry> loaded_or = ModelRegistry::load_directory(models_dir_, before.get());
  if (!loaded_or.is_ok()) {
    spdlog::warn("models not reloaded dir={} error=\"{}\"", models_dir_, loaded_or.status().message());
    return Status(loaded_or.status().code(), without_server_paths(loaded_or.status().message()));
  }
  ModelRegistry loaded = std::move(loaded_or).value();
  auto after = std::make_shared<const ModelRegistry>(std::move(loaded));
  ReloadReport report;
  for (const ModelPtr& m : after->models()) {
    const ModelPtr old = before->find(m->name());
    if (old == nullptr) {
      report.added.push_back(m->name());
    } else if (old == m) {
      report.unchanged.push_back(m->name());
    } else {
      report.changed.push_back(m->name());
    }
  }
  for (const ModelPtr& m : before->models()) {
    if (after->find(m->name()) == nullptr) report.removed.push_back(m->name());
  }
  report.refused = after->refused();
  {
    std::lock_guard lock(builtins_mu_);
    builtins_ = after;
  }
  auto names = [](const std::vector<std::string>& v) {
    std::string out;
    for (const auto& n : v) out += (out.empty() ? "" : ",") + n;
    return out;
  };
  for (const ModelPtr& m : after->models()) {
    if (before->find(m->name()) != m) {
      spdlog::info("model loaded name={} version={} path={} sha256={}", m->name(), m->version(), m->origin(),
                   after->sha256(*m));
    }
  }
  for (const auto& r : report.refused) spdlog::warn("model refused path={} reason=\"{}\"", r.path, r.reason);
  spdlog::info("models reloaded dir={} added=[{}] changed=[{}] removed=[{}] unchanged={} refused={}", models_dir_,
               names(report.added), names(report.changed), names(report.removed), report.unchanged.size(),
               report.refused.size());
  // The log has the server's paths; the caller gets each file's name within
  // the models directory.
  for (RefusedPlugin& r : report.refused) {
    r.path = without_server_paths(r.path);
    r.reason = without_server_paths(r.reason);
  }
  return report;
}

Status ModelCatalog::check_cost(const std::string& name, const TextModelSummary& summary) const {
  if (summary.check_operations <= static_cast<double>(limits_.max_model_check_operations)) return Status::ok();
  return limit_reached("max_model_check_operations", limits_.max_model_check_operations,
                       "checking the Jacobians of model \"" + name + "\" would take about " +
                           message_number(summary.check_operations, 2) +
                           " operations (fourth-order differences of every derivative at 3 points, from its tapes' "
                           "sizes); make the model smaller (a dense mass matrix costs about n^5), or raise "
                           "--max-model-check-operations");
}

Result<std::shared_ptr<const ModelCatalog::Compiled>> ModelCatalog::compiled(const ModelRecord& record,
                                                                             const JacobianCheck* checked) const {
  const auto key = std::make_tuple(record.tenant, record.name, record.revision);
  {
    std::lock_guard lock(mu_);
    if (const auto it = cache_.find(key); it != cache_.end()) return it->second;
  }
  // Compiled and checked outside the lock: another tenant's models are not held up.
  RICCATI_ASSIGN_OR_RETURN(TextModel text,
                           compile_text_model(record.source, record.name + "@" + std::to_string(record.revision)));
  auto c = std::make_shared<Compiled>();
  c->model = std::move(text.model);
  c->summary = std::move(text.summary);
  if (checked != nullptr) {
    c->jacobian_check = *checked;
  } else if (const Status affordable = check_cost(record.name, c->summary); !affordable.is_ok()) {
    // Stored under a higher limit: it stays usable, unchecked.
    c->jacobian_check.detail = "not checked: " + affordable.message();
  } else {
    Result<JacobianCheck> check = check_jacobians(*c->model, generic_points(*c->model));
    if (check.is_ok()) c->jacobian_check = std::move(check).value();
  }
  std::lock_guard lock(mu_);
  // Bounded: a tenant's many uploads must not hold riccatid's memory. When
  // full, the cache starts again (a job running a model holds its own).
  if (cache_.size() >= kMaxCompiledModels) cache_.clear();
  return cache_.emplace(key, std::move(c)).first->second;
}

Result<ResolvedModel> ModelCatalog::resolve(const std::string& tenant, std::string_view name) const {
  RICCATI_ASSIGN_OR_RETURN(const Name n, parse_name(name));
  if (n.revision == 0) {
    if (ModelPtr builtin = builtins()->find(n.name)) return ResolvedModel{std::move(builtin), n.name};
  }
  Result<ModelRecord> record = stored_model(store_, tenant, n);
  if (!record.is_ok()) {
    if (record.status().code() == StatusCode::kNotFound) return no_model(name);
    return record.status();
  }
  RICCATI_ASSIGN_OR_RETURN(const auto c, compiled(record.value()));
  return ResolvedModel{c->model, record->name + "@" + std::to_string(record->revision)};
}

Result<ModelPtr> ModelCatalog::get(const std::string& tenant, std::string_view name) const {
  RICCATI_ASSIGN_OR_RETURN(ResolvedModel r, resolve(tenant, name));
  return std::move(r.model);
}

CatalogEntry ModelCatalog::builtin_entry(const std::shared_ptr<const ModelRegistry>& registry, const ModelPtr& model) {
  CatalogEntry e;
  e.model = model;
  e.jacobian_check = registry->jacobian_check(*model);
  if (const TextModelSummary* summary = registry->text_summary(*model)) {
    e.text = std::shared_ptr<const TextModelSummary>(registry, summary);  // lives as long as the registry
  }
  e.sha256 = registry->sha256(*model);
  return e;
}

CatalogEntry ModelCatalog::entry_of(const ModelRecord& record, const std::shared_ptr<const Compiled>& c) const {
  CatalogEntry e;
  e.model = c->model;
  e.jacobian_check = c->jacobian_check;
  e.text = std::shared_ptr<const TextModelSummary>(c, &c->summary);
  e.revision = record.revision;
  e.sha256 = record.sha256;
  e.source = record.source;
  return e;
}

Result<std::vector<CatalogEntry>> ModelCatalog::list(const std::string& tenant) const {
  std::vector<CatalogEntry> out;
  const std::shared_ptr<const ModelRegistry> registry = builtins();
  for (const ModelPtr& m : registry->models()) out.push_back(builtin_entry(registry, m));
  RICCATI_ASSIGN_OR_RETURN(const std::vector<ModelRecord> stored, store_.list_models(tenant));
  RICCATI_ASSIGN_OR_RETURN(const std::vector<ModelRevision> revisions, store_.list_model_revisions(tenant));
  for (const ModelRecord& r : stored) {
    // A revision that no longer compiles (a newer riccatid with stricter
    // rules) is left out of the list rather than failing it.
    const auto c = compiled(r);
    if (!c.is_ok()) continue;
    out.push_back(entry_of(r, c.value()));
    out.back().revisions = revisions_of(revisions, r.name);
  }
  return out;
}

Result<CatalogEntry> ModelCatalog::describe(const std::string& tenant, std::string_view name) const {
  RICCATI_ASSIGN_OR_RETURN(const Name n, parse_name(name));
  if (n.revision == 0) {
    const std::shared_ptr<const ModelRegistry> registry = builtins();
    if (ModelPtr builtin = registry->find(n.name)) return builtin_entry(registry, builtin);
  }
  Result<ModelRecord> record = stored_model(store_, tenant, n);
  if (!record.is_ok()) {
    if (record.status().code() == StatusCode::kNotFound) return no_model(name);
    return record.status();
  }
  RICCATI_ASSIGN_OR_RETURN(const auto c, compiled(record.value()));
  RICCATI_ASSIGN_OR_RETURN(const std::vector<ModelRevision> revisions, store_.list_model_revisions(tenant));
  CatalogEntry e = entry_of(record.value(), c);
  e.revisions = revisions_of(revisions, n.name);
  return e;
}

Status ModelCatalog::check_quota(const std::string& tenant, std::int64_t source_bytes) const {
  RICCATI_ASSIGN_OR_RETURN(const std::vector<ModelRevision> revisions, store_.list_model_revisions(tenant));
  std::int64_t bytes = 0;
  for (const ModelRevision& r : revisions) bytes += r.source_bytes;
  const auto count = static_cast<std::int64_t>(revisions.size());
  if (count + 1 > limits_.max_tenant_models) {
    return limit_reached("max_tenant_models", limits_.max_tenant_models,
                         "this tenant has " + std::to_string(count) +
                             " stored model revisions; remove a model (riccati models remove NAME) to make room");
  }
  if (bytes + source_bytes > limits_.max_tenant_model_bytes) {
    return limit_reached("max_tenant_model_bytes", limits_.max_tenant_model_bytes,
                         "this tenant's stored models are " + std::to_string(bytes) + " bytes and this one is " +
                             std::to_string(source_bytes) +
                             "; remove a model (riccati models remove NAME) to make room");
  }
  return Status::ok();
}

Result<CatalogEntry> ModelCatalog::create(const std::string& tenant, const std::string& source,
                                          const std::string& origin, bool validate_only) const {
  RICCATI_ASSIGN_OR_RETURN(TextModel text, compile_text_model(source, origin));
  const std::string& name = text.model->name();
  if (const ModelPtr builtin = builtins()->find(name)) {
    return Status(StatusCode::kAlreadyExists, "model \"" + name +
                                                  "\" is built into this riccatid (a model of its models directory): "
                                                  "give the text model another name");
  }
  // Refused before the check when it would cost too much (the workbench
  // sends validate_only after every key), and checked here, outside every lock.
  RICCATI_RETURN_IF_ERROR(check_cost(name, text.summary));
  auto checked = std::make_shared<Compiled>();
  checked->model = std::move(text.model);
  checked->summary = std::move(text.summary);
  Result<JacobianCheck> check = check_jacobians(*checked->model, generic_points(*checked->model));
  if (check.is_ok()) checked->jacobian_check = std::move(check).value();
  if (validate_only) {
    ModelRecord unstored;
    unstored.name = name;
    unstored.source = source;
    unstored.sha256 = sha256_hex(source);
    return entry_of(unstored, checked);
  }
  ModelRecord record;
  record.tenant = tenant;
  record.name = name;
  record.source = source;
  record.sha256 = sha256_hex(source);
  record.created_ms = now_ms();
  Result<ModelRecord> put = [&]() -> Result<ModelRecord> {
    std::lock_guard lock(create_mu_);  // the quota's check and the put together, nothing else
    // The same source as the name's newest revision is that revision: a
    // CreateModel retried (after a lost answer, or riccatid's restart)
    // stores nothing and counts once.
    if (Result<ModelRecord> newest = store_.get_model(tenant, name, 0);
        newest.is_ok() && !newest->deleted && newest->sha256 == record.sha256) {
      return newest;
    }
    RICCATI_RETURN_IF_ERROR(check_quota(tenant, static_cast<std::int64_t>(source.size())));
    return store_.put_model(record);
  }();
  if (!put.is_ok()) return put.status();
  const ModelRecord& stored = put.value();
  // Compiled again under its stored name (name@revision), not checked again.
  RICCATI_ASSIGN_OR_RETURN(const auto c, compiled(stored, &checked->jacobian_check));
  CatalogEntry e = entry_of(stored, c);
  RICCATI_ASSIGN_OR_RETURN(const std::vector<ModelRevision> revisions, store_.list_model_revisions(tenant));
  e.revisions = revisions_of(revisions, name);
  return e;
}

Status ModelCatalog::remove(const std::string& tenant, const std::string& name) const {
  if (builtins()->find(name) != nullptr) {
    return failed_precondition("model \"" + name + "\" is built into this riccatid: remove its file from the models "
                               "directory instead");
  }
  const Status s = store_.delete_model(tenant, name);
  if (s.code() == StatusCode::kNotFound) return no_model(name);
  RICCATI_RETURN_IF_ERROR(s);
  {
    // Its compiled revisions go from the cache (a job running one holds it).
    std::lock_guard lock(mu_);
    std::erase_if(cache_, [&](const auto& entry) {
      return std::get<0>(entry.first) == tenant && std::get<1>(entry.first) == name;
    });
  }
  // And its revisions from the store, unless a queued or running job names them.
  if (Result<int> purged = store_.purge_unused_models(); !purged.is_ok()) {
    spdlog::warn("deleted models not purged error=\"{}\"", purged.status().message());
  }
  return Status::ok();
}

}  // namespace riccati::service
