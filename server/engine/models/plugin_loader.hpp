// Finding and loading models: plugins (shared libraries, with dlopen) and
// text models (YAML, compiled by engine/models/text).
#pragma once

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/models/jacobian_check.hpp"
#include "engine/models/model.hpp"
#include "engine/models/text/text_model.hpp"
#include "engine/status.hpp"

namespace riccati {

// Loads one plugin file (again, if an older version of it is loaded: from a
// private copy, so that the new code is what runs). A file that is not a plugin, has the wrong ABI
// version or an inconsistent table is refused with a message naming it; the
// host is never brought down by a bad plugin's table.
Result<ModelPtr> load_model_plugin(const std::string& path);

// Reads and compiles one text model file (at most kMaxTextModelBytes).
Result<TextModel> load_text_model(const std::string& path);

struct RefusedPlugin {
  std::string path;
  std::string reason;
};

// The models available to a daemon or a tool: every plugin (*.so) and text
// model (*.yaml, *.yml) of one directory, by name.
class ModelRegistry {
 public:
  // Loads every *.so, *.yaml and *.yml in `dir` (sorted by file name). A plugin is code run
  // inside the daemon, so only what the daemon's user (or root) controls is
  // loaded: a missing directory, or one that others can write to, is an
  // error; a file others can write to, a file owned by someone else, a
  // symbolic link (it may lead out of the directory) or a bad plugin is
  // recorded in refused() and skipped, as is a second plugin with a name
  // already taken.
  //
  // With `previous` (a reload): a file whose path and SHA-256 are those of a
  // model `previous` loaded gives that same model (not loaded or checked
  // again); a changed plugin is loaded anew even while its old version is
  // held (load_model_plugin).
  static Result<ModelRegistry> load_directory(const std::string& dir, const ModelRegistry* previous = nullptr);

  ModelPtr find(std::string_view name) const;
  // The model of that name; NOT_FOUND ("no model \"x\" is loaded") if none.
  Result<ModelPtr> get(std::string_view name) const;
  const std::vector<ModelPtr>& models() const { return models_; }
  const std::vector<RefusedPlugin>& refused() const { return refused_; }
  // SHA-256 of the file a loaded model came from (64 hex digits).
  const std::string& sha256(const Model& model) const;
  // Its exact Jacobians against finite differences at generic_points(),
  // checked when it was loaded.
  const JacobianCheck& jacobian_check(const Model& model) const;
  // The equations and Jacobian structure of a text model; nullptr for a plugin.
  const TextModelSummary* text_summary(const Model& model) const;

 private:
  // models_'s index of the model loaded from `path` with that content, if any.
  std::optional<std::size_t> index_of_file(const std::string& path, const std::string& sha256) const;

  std::vector<ModelPtr> models_;
  std::vector<std::string> sha256_;  // of models_[i]'s file
  std::vector<std::string> paths_;   // models_[i]'s file
  std::vector<JacobianCheck> jacobian_checks_;  // of models_[i]
  std::vector<std::optional<TextModelSummary>> text_summaries_;  // of models_[i], if it is a text model
  std::vector<RefusedPlugin> refused_;
};

// Where the built-in plugins sit relative to the running executable:
// <dir of executable>/../lib/riccati/models (the same in the build tree and in
// an install).
std::string default_models_dir();

}  // namespace riccati
