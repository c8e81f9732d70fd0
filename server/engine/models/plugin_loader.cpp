#include "engine/models/plugin_loader.hpp"

#include <dlfcn.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <iterator>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <optional>
#include <memory>
#include <system_error>

#include "engine/sha256.hpp"

namespace riccati {

namespace fs = std::filesystem;

namespace {

// dlopen knows a loaded library by the name it was opened with: a plugin
// file replaced in place and loaded again while its old version is still
// held (by a session, a job) would give back the old code. So when a library
// of that path is loaded already, the new file is loaded from a private
// copy, an anonymous memory file opened as /proc/self/fd/N, whose descriptor
// stays open while the library is loaded (so no other copy gets its name).
Result<std::shared_ptr<void>> open_library(const std::string& path) {
  // RTLD_LOCAL: two plugins may define the same internal symbols without
  // clashing. RTLD_NOW: a missing symbol is found here, not mid-filter.
  constexpr int kFlags = RTLD_NOW | RTLD_LOCAL;
  auto cannot = [&path](const std::string& why) {
    return invalid_argument("plugin " + path + " refused: cannot load it: " + why);
  };
  auto dl_error = [] {
    const char* why = ::dlerror();
    return std::string(why != nullptr ? why : "unknown error");
  };
  void* loaded = ::dlopen(path.c_str(), kFlags | RTLD_NOLOAD);
  if (loaded == nullptr) {
    void* handle = ::dlopen(path.c_str(), kFlags);
    if (handle == nullptr) return cannot(dl_error());
    return std::shared_ptr<void>(handle, [](void* h) { ::dlclose(h); });
  }
  ::dlclose(loaded);
  std::ifstream in(path, std::ios::binary);
  const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  if (!in.good() && !in.eof()) return cannot("cannot read it");
  const int fd = ::memfd_create("riccati-plugin", MFD_CLOEXEC);
  if (fd < 0) return cannot(std::string("memfd_create: ") + std::strerror(errno));
  for (std::size_t at = 0; at < bytes.size();) {
    const ssize_t n = ::write(fd, bytes.data() + at, bytes.size() - at);
    if (n <= 0) {
      ::close(fd);
      return cannot(std::string("copying it: ") + std::strerror(errno));
    }
    at += static_cast<std::size_t>(n);
  }
  void* handle = ::dlopen(("/proc/self/fd/" + std::to_string(fd)).c_str(), kFlags);
  if (handle == nullptr) {
    ::close(fd);
    return cannot(dl_error());
  }
  return std::shared_ptr<void>(handle, [fd](void* h) {
    ::dlclose(h);
    ::close(fd);
  });
}

}  // namespace

Result<ModelPtr> load_model_plugin(const std::string& path) {
  RICCATI_ASSIGN_OR_RETURN(std::shared_ptr<void> library, open_library(path));
  void* handle = library.get();

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

namespace {

// World-writable, or group-writable by a group other than ours. Group write
// for our own group is let through: with the user-private groups of Debian
// (umask 002) every file a user builds is group-writable by a group that
// holds that user alone.
bool writable_by_others(const struct stat& st) {
  return (st.st_mode & S_IWOTH) != 0 || ((st.st_mode & S_IWGRP) != 0 && st.st_gid != ::getegid());
}
bool owned_by_us_or_root(const struct stat& st) { return st.st_uid == ::geteuid() || st.st_uid == 0; }

// Why `path` (a plugin file) may not be loaded, or "" if it may.
std::string unsafe_file(const fs::path& path) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0) return "cannot stat it";
  if (S_ISLNK(st.st_mode)) return "it is a symbolic link: copy the plugin into the models directory";
  if (!S_ISREG(st.st_mode)) return "it is not a regular file";
  if (writable_by_others(st)) return "others can write to it (chmod go-w " + path.string() + ")";
  if (!owned_by_us_or_root(st)) return "it is owned by uid " + std::to_string(st.st_uid) + ", not by this user or root";
  return "";
}

}  // namespace

Result<ModelRegistry> ModelRegistry::load_directory(const std::string& dir, const ModelRegistry* previous) {
  struct stat st {};
  if (::stat(dir.c_str(), &st) != 0) return not_found("models directory " + dir + " does not exist");
  if (!S_ISDIR(st.st_mode)) return invalid_argument("models directory " + dir + " is a file, not a directory");
  if (writable_by_others(st) || !owned_by_us_or_root(st)) {
    return failed_precondition("models directory " + dir +
                               " is writable by others or owned by another user: anyone who can write there can run "
                               "code in riccatid (chmod go-w " + dir + ")");
  }
  // Whoever can write to an ancestor can put another directory in this
  // one's place (as sshd's StrictModes reasons). A sticky directory (/tmp)
  // lets no one rename what others own, so it is safe.
  std::error_code canonical_error;
  const fs::path real = fs::canonical(dir, canonical_error);
  for (fs::path parent = real.parent_path(); !canonical_error && !parent.empty(); parent = parent.parent_path()) {
    struct stat up {};
    if (::stat(parent.c_str(), &up) == 0 && (up.st_mode & S_ISVTX) == 0 &&
        (writable_by_others(up) || !owned_by_us_or_root(up))) {
      return failed_precondition("models directory " + dir + " is inside " + parent.string() +
                                 ", which others can write to or another user owns: they could replace the "
                                 "plugins (chmod go-w " + parent.string() + ", or move the models elsewhere)");
    }
    if (parent == parent.root_path()) break;
  }

  std::error_code ec;
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    const fs::path ext = entry.path().extension();
    if (ext == ".so" || ext == ".yaml" || ext == ".yml") files.push_back(entry.path());
  }
  if (ec) return invalid_argument("cannot read models directory " + dir + ": " + ec.message());
  std::sort(files.begin(), files.end());

  ModelRegistry registry;
  for (const auto& file : files) {
    if (const std::string why = unsafe_file(file); !why.empty()) {
      registry.refused_.push_back({file.string(), "plugin " + file.string() + " refused: " + why});
      continue;
    }
    auto checksum = file_sha256(file.string());
    if (!checksum.is_ok()) {
      registry.refused_.push_back({file.string(), "plugin " + file.string() + " refused: " + checksum.status().message()});
      continue;
    }
    if (previous != nullptr) {
      // The same file as last time: the same model, not loaded and checked again.
      if (const auto same = previous->index_of_file(file.string(), checksum.value())) {
        if (const ModelPtr other = registry.find(previous->models_[*same]->name())) {
          registry.refused_.push_back({file.string(), "plugin " + file.string() + " refused: model name \"" +
                                                          other->name() + "\" is already provided by " + other->origin()});
          continue;
        }
        registry.models_.push_back(previous->models_[*same]);
        registry.text_summaries_.push_back(previous->text_summaries_[*same]);
        registry.sha256_.push_back(previous->sha256_[*same]);
        registry.paths_.push_back(file.string());
        registry.jacobian_checks_.push_back(previous->jacobian_checks_[*same]);
        continue;
      }
    }
    const bool is_text = file.extension() != ".so";
    std::optional<TextModelSummary> summary;
    Result<ModelPtr> loaded = is_text ? Result<ModelPtr>(not_found("")) : load_model_plugin(file.string());
    if (is_text) {
      Result<TextModel> compiled = load_text_model(file.string());
      if (compiled.is_ok()) {
        loaded = std::move(compiled->model);
        summary = std::move(compiled->summary);
      } else {
        loaded = compiled.status();
      }
    }
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
    registry.text_summaries_.push_back(std::move(summary));
    registry.sha256_.push_back(std::move(checksum).value());
    registry.paths_.push_back(file.string());
    Result<JacobianCheck> jacobians = check_jacobians(*registry.models_.back(), generic_points(*registry.models_.back()));
    registry.jacobian_checks_.push_back(jacobians.is_ok() ? std::move(jacobians).value() : JacobianCheck{});
  }
  return registry;
}

std::optional<std::size_t> ModelRegistry::index_of_file(const std::string& path, const std::string& sha256) const {
  for (std::size_t i = 0; i < models_.size(); ++i) {
    if (paths_[i] == path && sha256_[i] == sha256) return i;
  }
  return std::nullopt;
}

const std::string& ModelRegistry::sha256(const Model& model) const {
  static const std::string kNone;
  for (std::size_t i = 0; i < models_.size(); ++i) {
    if (models_[i].get() == &model) return sha256_[i];
  }
  return kNone;
}

const TextModelSummary* ModelRegistry::text_summary(const Model& model) const {
  for (std::size_t i = 0; i < models_.size(); ++i) {
    if (models_[i].get() == &model) return text_summaries_[i] ? &*text_summaries_[i] : nullptr;
  }
  return nullptr;
}

Result<TextModel> load_text_model(const std::string& path) {
  std::error_code ec;
  const auto size = fs::file_size(path, ec);
  if (ec) return invalid_argument("text model " + path + " refused: cannot read it: " + ec.message());
  if (size > kMaxTextModelBytes) {
    return invalid_argument("text model " + path + " refused: it is " + std::to_string(size) +
                            " bytes, more than the limit of " + std::to_string(kMaxTextModelBytes));
  }
  std::ifstream in(path, std::ios::binary);
  std::string text(static_cast<std::size_t>(size), '\0');
  if (!in.read(text.data(), static_cast<std::streamsize>(size))) {
    return invalid_argument("text model " + path + " refused: cannot read it");
  }
  return compile_text_model(text, path);
}

const JacobianCheck& ModelRegistry::jacobian_check(const Model& model) const {
  static const JacobianCheck kNone{false, "not loaded by this registry", 0, 0.0, {}};
  for (std::size_t i = 0; i < models_.size(); ++i) {
    if (models_[i].get() == &model) return jacobian_checks_[i];
  }
  return kNone;
}

ModelPtr ModelRegistry::find(std::string_view name) const {
  for (const auto& m : models_) {
    if (m->name() == name) return m;
  }
  return nullptr;
}

Result<ModelPtr> ModelRegistry::get(std::string_view name) const {
  ModelPtr model = find(name);
  if (model == nullptr) return not_found("no model \"" + std::string(name) + "\" is loaded");
  return model;
}

std::string default_models_dir() {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (ec) return "lib/riccati/models";
  return (exe.parent_path() / ".." / "lib" / "riccati" / "models").lexically_normal().string();
}

}  // namespace riccati
