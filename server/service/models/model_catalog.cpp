#include "service/models/model_catalog.hpp"

#include <charconv>

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

Status no_model(std::string_view name) { return not_found("no model \"" + std::string(name) + "\" is loaded"); }

}  // namespace

Result<std::shared_ptr<const ModelCatalog::Compiled>> ModelCatalog::compiled(const ModelRecord& record) const {
  const auto key = std::make_tuple(record.tenant, record.name, record.revision);
  {
    std::lock_guard lock(mu_);
    if (const auto it = cache_.find(key); it != cache_.end()) return it->second;
  }
  RICCATI_ASSIGN_OR_RETURN(TextModel text,
                           compile_text_model(record.source, record.name + "@" + std::to_string(record.revision)));
  auto c = std::make_shared<Compiled>();
  c->model = std::move(text.model);
  c->summary = std::move(text.summary);
  Result<JacobianCheck> check = check_jacobians(*c->model, generic_points(*c->model));
  if (check.is_ok()) c->jacobian_check = std::move(check).value();
  std::lock_guard lock(mu_);
  return cache_.emplace(key, std::move(c)).first->second;
}

Result<ResolvedModel> ModelCatalog::resolve(const std::string& tenant, std::string_view name) const {
  RICCATI_ASSIGN_OR_RETURN(const Name n, parse_name(name));
  if (n.revision == 0) {
    if (ModelPtr builtin = builtins_.find(n.name)) return ResolvedModel{std::move(builtin), n.name};
  }
  Result<ModelRecord> record = store_.get_model(tenant, n.name, n.revision);
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

CatalogEntry ModelCatalog::builtin_entry(const ModelPtr& model) const {
  CatalogEntry e;
  e.model = model;
  e.jacobian_check = builtins_.jacobian_check(*model);
  e.text = builtins_.text_summary(*model);
  e.sha256 = builtins_.sha256(*model);
  return e;
}

CatalogEntry ModelCatalog::entry_of(const ModelRecord& record, const Compiled& c) const {
  CatalogEntry e;
  e.model = c.model;
  e.jacobian_check = c.jacobian_check;
  e.text = &c.summary;
  e.revision = record.revision;
  e.sha256 = record.sha256;
  e.source = record.source;
  return e;
}

Result<std::vector<CatalogEntry>> ModelCatalog::list(const std::string& tenant) const {
  std::vector<CatalogEntry> out;
  for (const ModelPtr& m : builtins_.models()) out.push_back(builtin_entry(m));
  RICCATI_ASSIGN_OR_RETURN(const std::vector<ModelRecord> stored, store_.list_models(tenant));
  for (const ModelRecord& r : stored) {
    // A revision that no longer compiles (a newer riccatid with stricter
    // rules) is left out of the list rather than failing it.
    const auto c = compiled(r);
    if (c.is_ok()) out.push_back(entry_of(r, *c.value()));
  }
  return out;
}

Result<CatalogEntry> ModelCatalog::describe(const std::string& tenant, std::string_view name) const {
  RICCATI_ASSIGN_OR_RETURN(const Name n, parse_name(name));
  if (n.revision == 0) {
    if (ModelPtr builtin = builtins_.find(n.name)) return builtin_entry(builtin);
  }
  Result<ModelRecord> record = store_.get_model(tenant, n.name, n.revision);
  if (!record.is_ok()) {
    if (record.status().code() == StatusCode::kNotFound) return no_model(name);
    return record.status();
  }
  RICCATI_ASSIGN_OR_RETURN(const auto c, compiled(record.value()));
  return entry_of(record.value(), *c);
}

Result<CatalogEntry> ModelCatalog::create(const std::string& tenant, const std::string& source,
                                          const std::string& origin) const {
  RICCATI_ASSIGN_OR_RETURN(TextModel text, compile_text_model(source, origin));
  const std::string& name = text.model->name();
  if (builtins_.find(name) != nullptr) {
    return Status(StatusCode::kAlreadyExists,
                  "model \"" + name + "\" is built into this riccatid (" + builtins_.find(name)->origin() +
                      "): give the text model another name");
  }
  ModelRecord record;
  record.tenant = tenant;
  record.name = name;
  record.source = source;
  record.sha256 = sha256_hex(source);
  record.created_ms = now_ms();
  RICCATI_ASSIGN_OR_RETURN(const ModelRecord stored, store_.put_model(record));
  RICCATI_ASSIGN_OR_RETURN(const auto c, compiled(stored));
  return entry_of(stored, *c);
}

Status ModelCatalog::remove(const std::string& tenant, const std::string& name) const {
  if (builtins_.find(name) != nullptr) {
    return failed_precondition("model \"" + name + "\" is built into this riccatid: remove its file from the models "
                               "directory instead");
  }
  const Status s = store_.delete_model(tenant, name);
  if (s.code() == StatusCode::kNotFound) return no_model(name);
  return s;
}

}  // namespace riccati::service
