#include "engine/plugin_loader.hpp"

#include <dlfcn.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <memory>
#include <system_error>

namespace riccati {

namespace fs = std::filesystem;

Result<ModelPtr> load_model_plugin(const std::string& path) {
  // RTLD_LOCAL: two plugins may define the same internal symbols without
  // clashing. RTLD_NOW: a missing symbol is found here, not mid-filter.
  void* handle = ::dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (handle == nullptr) {
    const char* why = ::dlerror();
    return invalid_argument("plugin " + path + " refused: cannot load it: " + (why != nullptr ? why : "unknown error"));
  }
  std::shared_ptr<void> library(handle, [](void* h) { ::dlclose(h); });

  ::dlerror();  // clear, so a NULL symbol can be told from an error
  void* symbol = ::dlsym(handle, RICCATI_MODEL_ENTRY_SYMBOL);
  if (symbol == nullptr) {
    return invalid_argument("plugin " + path + " refused: it does not export " RICCATI_MODEL_ENTRY_SYMBOL
                            " (is it a riccati model plugin?)");
  }
  auto entry = reinterpret_cast<riccati_model_entry_fn>(symbol);
  const riccati_model_v1* table = entry(RICCATI_MODEL_ABI_VERSION);
  if (table == nullptr) {
    return invalid_argument("plugin " + path + " refused: it cannot serve model ABI version " +
                            std::to_string(RICCATI_MODEL_ABI_VERSION));
  }
  return Model::create(table, std::move(library), path);
}

Result<ModelRegistry> ModelRegistry::load_directory(const std::string& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return not_found("models directory " + dir + " does not exist");

  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    if (entry.is_regular_file() && entry.path().extension() == ".so") files.push_back(entry.path());
  }
  if (ec) return invalid_argument("cannot read models directory " + dir + ": " + ec.message());
  std::sort(files.begin(), files.end());

  ModelRegistry registry;
  for (const auto& file : files) {
    auto loaded = load_model_plugin(file.string());
    if (!loaded.is_ok()) {
      registry.refused_.push_back({file.string(), loaded.status().message()});
      continue;
    }
    ModelPtr model = std::move(loaded).value();
    if (const ModelPtr other = registry.find(model->name())) {
      registry.refused_.push_back({file.string(), "plugin " + file.string() + " refused: model name \"" +
                                                      model->name() + "\" is already provided by " + other->origin()});
      continue;
    }
    registry.models_.push_back(std::move(model));
  }
  return registry;
}

ModelPtr ModelRegistry::find(std::string_view name) const {
  for (const auto& m : models_) {
    if (m->name() == name) return m;
  }
  return nullptr;
}

std::string default_models_dir() {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (ec) return "lib/riccati/models";
  return (exe.parent_path() / ".." / "lib" / "riccati" / "models").lexically_normal().string();
}

}  // namespace riccati
