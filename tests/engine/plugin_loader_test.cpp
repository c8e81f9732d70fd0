// Loading model plugins: every deliberately broken plugin of
// tests/engine/bad_plugins is refused with a message naming the file and the
// fault, faults at evaluation time come back as Status, and the built-in
// models directory loads cleanly.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "engine/bad_plugins/pendulum_table.hpp"
#include "engine/models/jacobian_check.hpp"
#include "engine/models/model.hpp"
#include "engine/models/plugin_loader.hpp"

namespace riccati {
namespace {

namespace fs = std::filesystem;

std::string bad_plugin(const std::string& file) { return std::string(RICCATI_TEST_BAD_PLUGIN_DIR) + "/" + file; }
std::string builtin_plugin(const std::string& file) { return std::string(RICCATI_TEST_PLUGIN_DIR) + "/" + file; }

ModelPtr load_or_fail(const std::string& path) {
  auto loaded = load_model_plugin(path);
  EXPECT_TRUE(loaded.is_ok()) << loaded.status().to_string();
  return loaded.is_ok() ? std::move(loaded).value() : nullptr;
}

// ---------------------------------------------------------------------------
// Plugins refused at load time

struct RefusedCase {
  std::string file;
  std::string reason;  // must appear in the message
};

std::ostream& operator<<(std::ostream& os, const RefusedCase& c) { return os << c.file; }

const std::vector<RefusedCase>& refused_cases() {
  static const std::vector<RefusedCase> cases = {
      {"bad_abi_version.so", "ABI version 999"},
      {"zero_states.so", "nx = 0"},
      {"zero_outputs.so", "ny = 0"},
      {"missing_f.so", "does not provide f and g"},
      {"null_state_name.so", "state name 1"},
      {"duplicate_param_names.so", "parameter name \"k\" is repeated"},
      {"nonfinite_default.so", "default of parameter k is not finite"},
      {"lower_above_upper.so", "bounds of parameter c are inconsistent"},
      {"entry_returns_null.so", "cannot serve model ABI version 1"},
      {"no_entry_symbol.so", "does not export riccati_model_entry"},
      {"junk.so", "cannot load it"},
  };
  return cases;
}

class RefusedPluginTest : public testing::TestWithParam<RefusedCase> {};

TEST_P(RefusedPluginTest, RefusedWithFileAndReason) {
  const RefusedCase& c = GetParam();
  const std::string path = bad_plugin(c.file);
  ASSERT_TRUE(fs::exists(path)) << path;
  auto loaded = load_model_plugin(path);
  ASSERT_FALSE(loaded.is_ok());
  EXPECT_EQ(loaded.status().code(), StatusCode::kInvalidArgument) << loaded.status().to_string();
  EXPECT_NE(loaded.status().message().find(path), std::string::npos) << loaded.status().message();
  EXPECT_NE(loaded.status().message().find(c.reason), std::string::npos) << loaded.status().message();
}

INSTANTIATE_TEST_SUITE_P(BadPlugins, RefusedPluginTest, testing::ValuesIn(refused_cases()),
                         [](const testing::TestParamInfo<RefusedCase>& param_info) {
                           return param_info.param.file.substr(0, param_info.param.file.find('.'));
                         });

TEST(PluginLoaderTest, MissingFileIsRefused) {
  const std::string path = bad_plugin("does_not_exist.so");
  auto loaded = load_model_plugin(path);
  ASSERT_FALSE(loaded.is_ok());
  EXPECT_EQ(loaded.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(loaded.status().message().find(path), std::string::npos) << loaded.status().message();
}

// ---------------------------------------------------------------------------
// Plugins that load but fail (or degrade) when evaluated

TEST(PluginLoaderTest, ExceptionInFBecomesInternalError) {
  const ModelPtr m = load_or_fail(bad_plugin("throwing_f.so"));
  ASSERT_NE(m, nullptr);
  const double x[] = {1.0}, theta[] = {1.0};
  double out[1], jac[2];

  const Status f = m->f(0.0, nullptr, 1, 1, x, theta, out);
  EXPECT_EQ(f.code(), StatusCode::kInternal) << f.to_string();
  EXPECT_NE(f.message().find("deliberate exception from throwing_f's f"), std::string::npos) << f.message();

  const Status g = m->g(0.0, nullptr, 1, 1, x, theta, out);
  EXPECT_EQ(g.code(), StatusCode::kInternal) << g.to_string();
  EXPECT_NE(g.message().find("deliberate exception from throwing_f's g"), std::string::npos) << g.message();

  // The Jacobian goes through the dual-number instantiation: caught as well.
  const Status fj = m->f_jacobian(0.0, nullptr, x, theta, out, jac);
  EXPECT_EQ(fj.code(), StatusCode::kInternal) << fj.to_string();
  EXPECT_NE(fj.message().find("deliberate exception from throwing_f's f"), std::string::npos) << fj.message();
}

TEST(PluginLoaderTest, NanFromFIsFailedPreconditionNamingTheState) {
  const ModelPtr m = load_or_fail(bad_plugin("nan_f.so"));
  ASSERT_NE(m, nullptr);
  const double x[] = {0.5, 0.25}, theta[] = {1.0};
  double out[2], jac[2 * 3];

  const Status f = m->f(2.0, nullptr, 1, 1, x, theta, out);
  EXPECT_EQ(f.code(), StatusCode::kFailedPrecondition) << f.to_string();
  EXPECT_NE(f.message().find("state velocity"), std::string::npos) << f.message();

  const Status fj = m->f_jacobian(2.0, nullptr, x, theta, out, jac);
  EXPECT_EQ(fj.code(), StatusCode::kFailedPrecondition) << fj.to_string();
  EXPECT_NE(fj.message().find("state velocity"), std::string::npos) << fj.message();

  // g is fine.
  EXPECT_TRUE(m->g(2.0, nullptr, 1, 1, x, theta, out).is_ok());
}

// The plain pendulum of bad_plugins/pendulum_table.hpp gives no Jacobians; the
// host's central differences must match the exact ones. Their error is about
// eps^(2/3) ~ 1e-11 relative to O(1) entries, so 1e-7 is a wide margin.
TEST(PluginLoaderTest, MissingJacobiansFallBackToFiniteDifferences) {
  const ModelPtr m = load_or_fail(bad_plugin("no_jacobians.so"));
  ASSERT_NE(m, nullptr);
  EXPECT_FALSE(m->has_f_jacobian());
  EXPECT_FALSE(m->has_g_jacobian());

  const double angle = 0.7, velocity = -1.3, k = 9.0, c = 0.5, torque = 0.2;
  const double x[] = {angle, velocity}, theta[] = {k, c}, u[] = {torque};
  double value[2], jac[2 * 4];
  ASSERT_TRUE(m->f_jacobian(0.0, u, x, theta, value, jac).is_ok());

  EXPECT_DOUBLE_EQ(value[0], velocity);
  EXPECT_DOUBLE_EQ(value[1], -k * std::sin(angle) - c * velocity + torque);
  // d f / d [angle, velocity, k, c], column-major, 2 rows.
  const double exact[2 * 4] = {0.0, -k * std::cos(angle), 1.0, -c, 0.0, -std::sin(angle), 0.0, -velocity};
  for (int e = 0; e < 2 * 4; ++e) EXPECT_NEAR(jac[e], exact[e], 1e-7) << "entry " << e;

  double y[1], gjac[1 * 4];
  ASSERT_TRUE(m->g_jacobian(0.0, u, x, theta, y, gjac).is_ok());
  EXPECT_DOUBLE_EQ(y[0], angle);
  const double gexact[4] = {1.0, 0.0, 0.0, 0.0};
  for (int j = 0; j < 4; ++j) EXPECT_NEAR(gjac[j], gexact[j], 1e-7) << "column " << j;
}

// ---------------------------------------------------------------------------
// Jacobian check

// A sign error in one entry of df/dz (bad_plugins/wrong_jacobian.cpp): found
// at every generic point, named by its row and column, with both values; the
// right g Jacobian is not reported. The scaled error of a flipped sign is
// |2 k cos(angle)| / |k cos(angle)| = 2.
TEST(JacobianCheckTest, WrongSignIsFoundAndNamed) {
  const ModelPtr m = load_or_fail(bad_plugin("wrong_jacobian.so"));
  ASSERT_NE(m, nullptr);
  const Result<JacobianCheck> check = check_jacobians(*m, generic_points(*m));
  ASSERT_TRUE(check.is_ok()) << check.status().to_string();
  EXPECT_TRUE(check->checked);
  EXPECT_EQ(check->points, 3);
  EXPECT_FALSE(check->agrees());
  EXPECT_NEAR(check->max_error, 2.0, 1e-6);
  ASSERT_EQ(check->disagreements.size(), 1u);
  const std::string& d = check->disagreements.front();
  EXPECT_NE(d.find("df/d[x; theta]: d velocity' / d angle"), std::string::npos) << d;
  EXPECT_NE(d.find("finite differences give"), std::string::npos) << d;
  EXPECT_NE(d.find("theta = [9, 0.5]"), std::string::npos) << d;
}

// The pendulum table with hand-written Jacobians, one entry (d velocity' /
// d c = -velocity) scaled by kScale: the check's tolerance in both directions.
double g_scale = 1.0;

int scaled_f_jac(double t, const double* u, const double* x, const double* theta, double* out, double* jac,
                 char* err, size_t err_len) {
  bad_plugin::pendulum_f(1, 1, t, u, x, theta, out, err, err_len);
  const double angle = x[0], velocity = x[1], k = theta[0], c = theta[1];
  const double exact[2 * 4] = {0.0, -k * std::cos(angle), 1.0, -c, 0.0, -std::sin(angle), 0.0, -velocity * g_scale};
  std::copy(exact, exact + 8, jac);
  return 0;
}

TEST(JacobianCheckTest, ToleranceSeparatesRoundingFromErrors) {
  riccati_model_v1 t = bad_plugin::pendulum_table("pendulum");
  t.f_jac = &scaled_f_jac;
  auto m = Model::create(&t, nullptr, "pendulum (in-process)");
  ASSERT_TRUE(m.is_ok()) << m.status().to_string();
  struct Case {
    double scale;
    bool agrees;
  };
  // 1e-8 relative: far below the tolerance, far above the oracle's error;
  // 1e-3: a term wrong by a tenth of a percent is reported.
  for (const Case c : {Case{1.0, true}, Case{1.0 + 1e-8, true}, Case{1.0 + 1e-3, false}, Case{0.0, false}}) {
    g_scale = c.scale;
    const Result<JacobianCheck> check = check_jacobians(*m.value(), generic_points(*m.value()));
    ASSERT_TRUE(check.is_ok()) << check.status().to_string();
    EXPECT_EQ(check->agrees(), c.agrees) << "scale " << c.scale << ": " << check->detail;
    if (!c.agrees) {
      ASSERT_EQ(check->disagreements.size(), 1u);
      EXPECT_NE(check->disagreements.front().find("d velocity' / d c"), std::string::npos)
          << check->disagreements.front();
    }
  }
  g_scale = 1.0;
}

TEST(JacobianCheckTest, ModelWithoutJacobiansIsNotChecked) {
  const ModelPtr m = load_or_fail(bad_plugin("no_jacobians.so"));
  ASSERT_NE(m, nullptr);
  const Result<JacobianCheck> check = check_jacobians(*m, generic_points(*m));
  ASSERT_TRUE(check.is_ok());
  EXPECT_FALSE(check->checked);
  EXPECT_NE(check->detail.find("no Jacobians"), std::string::npos) << check->detail;
}

// The four shipped models (dual numbers through the SDK, and the
// manipulator's mechanical form) agree, at their loaded check and at a
// point of the caller's.
TEST(JacobianCheckTest, ShippedModelsAgree) {
  auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR);
  ASSERT_TRUE(registry.is_ok()) << registry.status().to_string();
  ASSERT_EQ(registry->models().size(), 4u);
  for (const ModelPtr& m : registry->models()) {
    const JacobianCheck& check = registry->jacobian_check(*m);
    EXPECT_TRUE(check.checked) << m->name() << ": " << check.detail;
    EXPECT_TRUE(check.agrees()) << m->name() << ": " << (check.agrees() ? "" : check.disagreements.front());
    EXPECT_LT(check.max_error, 1e-8) << m->name();  // measured: 3e-12 to 3e-10
  }
  const ModelPtr tank = registry->find("two_tank");
  ASSERT_NE(tank, nullptr);
  JacobianPoint p{0.0, Eigen::Vector2d(0.1, 0.03), Eigen::Vector2d(0.4, 0.15), tank->theta_default()};
  const Result<JacobianCheck> at = check_jacobians(*tank, {p});
  ASSERT_TRUE(at.is_ok());
  EXPECT_TRUE(at->agrees());
  EXPECT_EQ(at->points, 1);
  EXPECT_FALSE(check_jacobians(*tank, {JacobianPoint{0.0, Eigen::Vector2d(0.1, 0.03), Eigen::Vector3d::Ones(),
                                                      tank->theta_default()}}).is_ok())
      << "a point of the wrong size is an error";
}

// ---------------------------------------------------------------------------
// Directories

// The table only grows (model_abi.h): a plugin built before the mechanical
// form was appended has a smaller struct_size, still loads, and the host
// reads nothing past it.
TEST(PluginLoaderTest, TableFromBeforeAppendedFieldsStillLoads) {
  riccati_model_v1 t = bad_plugin::pendulum_table("old_pendulum");
  t.struct_size = RICCATI_MODEL_V1_BASE_SIZE;
  t.ndof = 3;  // past struct_size: whatever an old plugin has there is not read
  auto old = Model::create(&t, nullptr, "old_pendulum (in-process)");
  ASSERT_TRUE(old.is_ok()) << old.status().to_string();
  EXPECT_EQ(old.value()->ndof(), 0);
  EXPECT_FALSE(old.value()->has_mechanical_form());

  // Nor the units, appended later still: a table that ends before them has none.
  static const char* const kUnits[] = {"m", "m", "m", "m"};
  t.state_units = kUnits;
  t.ndof = 0;
  t.struct_size = offsetof(riccati_model_v1, state_units);
  auto before_units = Model::create(&t, nullptr, "before_units (in-process)");
  ASSERT_TRUE(before_units.is_ok()) << before_units.status().to_string();
  EXPECT_EQ(before_units.value()->state_units(), std::vector<std::string>(static_cast<std::size_t>(t.nx), ""));
  t.struct_size = sizeof(riccati_model_v1);
  auto with_units = Model::create(&t, nullptr, "with_units (in-process)");
  ASSERT_TRUE(with_units.is_ok()) << with_units.status().to_string();
  EXPECT_EQ(with_units.value()->state_units().front(), "m");
  EXPECT_EQ(with_units.value()->param_units(), std::vector<std::string>(static_cast<std::size_t>(t.ntheta), ""));

  t.struct_size = RICCATI_MODEL_V1_BASE_SIZE - 1;
  auto truncated = Model::create(&t, nullptr, "truncated (in-process)");
  ASSERT_FALSE(truncated.is_ok());
  EXPECT_NE(truncated.status().message().find("bytes"), std::string::npos) << truncated.status().message();
}

int no_mech(double, const double*, const double*, double*, double*, double*, double*, char*, size_t) { return 0; }

TEST(PluginLoaderTest, MechanicalFormNeedsPositionsAndVelocitiesAndItsFunction) {
  riccati_model_v1 t = bad_plugin::pendulum_table("pendulum");
  t.ndof = 1;  // nx = 2: one position, one velocity
  t.mech = nullptr;
  auto without = Model::create(&t, nullptr, "pendulum (in-process)");
  ASSERT_FALSE(without.is_ok());
  EXPECT_NE(without.status().message().find("mech function"), std::string::npos) << without.status().message();
  t.ndof = 2;  // would need nx = 4
  t.mech = &no_mech;
  auto wrong = Model::create(&t, nullptr, "pendulum (in-process)");
  ASSERT_FALSE(wrong.is_ok());
  EXPECT_NE(wrong.status().message().find("nx = 2 ndof"), std::string::npos) << wrong.status().message();
  t.ndof = 1;
  auto right = Model::create(&t, nullptr, "pendulum (in-process)");
  ASSERT_TRUE(right.is_ok()) << right.status().to_string();
  EXPECT_EQ(right.value()->ndof(), 1);
}

TEST(ModelRegistryTest, BadDirectoryLoadsTheValidAndListsTheRefused) {
  auto registry = ModelRegistry::load_directory(RICCATI_TEST_BAD_PLUGIN_DIR);
  ASSERT_TRUE(registry.is_ok()) << registry.status().to_string();

  std::set<std::string> loaded;
  for (const ModelPtr& m : registry->models()) loaded.insert(m->name());
  EXPECT_EQ(loaded, (std::set<std::string>{"nan_f", "no_jacobians", "throwing_f", "wrong_jacobian"}));
  // Loaded, but its Jacobian check says what is wrong with it.
  const ModelPtr wrong = registry->find("wrong_jacobian");
  ASSERT_NE(wrong, nullptr);
  EXPECT_TRUE(registry->jacobian_check(*wrong).checked);
  EXPECT_FALSE(registry->jacobian_check(*wrong).agrees());

  std::set<std::string> refused_files;
  for (const RefusedPlugin& r : registry->refused()) {
    refused_files.insert(fs::path(r.path).filename().string());
    EXPECT_NE(r.reason.find(r.path), std::string::npos) << r.reason;
  }
  std::set<std::string> expected_files;
  for (const RefusedCase& c : refused_cases()) {
    expected_files.insert(c.file);
    for (const RefusedPlugin& r : registry->refused()) {
      if (fs::path(r.path).filename() == c.file) {
        EXPECT_NE(r.reason.find(c.reason), std::string::npos) << r.reason;
      }
    }
  }
  EXPECT_EQ(refused_files, expected_files);
}

struct BuiltinSizes {
  std::string name;
  int nx, ntheta, nu, ny;
};

TEST(ModelRegistryTest, BuiltinDirectoryHasExactlyTheFourModels) {
  auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR);
  ASSERT_TRUE(registry.is_ok()) << registry.status().to_string();
  for (const RefusedPlugin& r : registry->refused()) ADD_FAILURE() << r.reason;

  const std::vector<BuiltinSizes> expected = {
      {"flexible_manipulator", 4, 6, 1, 2},
      {"rotary_pendulum", 4, 3, 1, 2},
      {"rotating_arm", 2, 8, 1, 2},
      {"two_tank", 2, 4, 2, 2},
  };
  ASSERT_EQ(registry->models().size(), expected.size());
  for (const BuiltinSizes& e : expected) {
    const ModelPtr m = registry->find(e.name);
    ASSERT_NE(m, nullptr) << e.name;
    EXPECT_EQ(m->nx(), e.nx) << e.name;
    EXPECT_EQ(m->ntheta(), e.ntheta) << e.name;
    EXPECT_EQ(m->nu(), e.nu) << e.name;
    EXPECT_EQ(m->ny(), e.ny) << e.name;
    EXPECT_TRUE(m->has_f_jacobian()) << e.name;
    EXPECT_TRUE(m->has_g_jacobian()) << e.name;
  }
  EXPECT_EQ(registry->find("no_such_model"), nullptr);
}

TEST(ModelRegistryTest, MissingDirectoryIsNotFound) {
  auto registry = ModelRegistry::load_directory(bad_plugin("no_such_directory"));
  ASSERT_FALSE(registry.is_ok());
  EXPECT_EQ(registry.status().code(), StatusCode::kNotFound) << registry.status().to_string();
}

// A scratch directory removed at the end of the test.
class ScratchDir {
 public:
  ScratchDir()
      : path_(fs::temp_directory_path() /
              ("riccati_plugin_loader_test_" + std::to_string(::getpid()) + "_" +
               testing::UnitTest::GetInstance()->current_test_info()->name())) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~ScratchDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

TEST(ModelRegistryTest, SecondPluginWithTheSameModelNameIsRefused) {
  const ScratchDir dir;
  fs::copy_file(builtin_plugin("two_tank.so"), dir.path() / "a_two_tank.so");
  fs::copy_file(builtin_plugin("two_tank.so"), dir.path() / "b_two_tank.so");

  auto registry = ModelRegistry::load_directory(dir.path().string());
  ASSERT_TRUE(registry.is_ok()) << registry.status().to_string();
  ASSERT_EQ(registry->models().size(), 1u);
  EXPECT_EQ(registry->models()[0]->origin(), (dir.path() / "a_two_tank.so").string());
  ASSERT_EQ(registry->refused().size(), 1u);
  const RefusedPlugin& refused = registry->refused()[0];
  EXPECT_EQ(refused.path, (dir.path() / "b_two_tank.so").string());
  EXPECT_NE(refused.reason.find("\"two_tank\" is already provided by"), std::string::npos) << refused.reason;
  EXPECT_NE(refused.reason.find("a_two_tank.so"), std::string::npos) << refused.reason;
}

// sha256sum's digest of a file: an implementation independent of ours.
std::string sha256sum(const fs::path& file) {
  const std::string command = "sha256sum '" + file.string() + "'";
  std::FILE* pipe = ::popen(command.c_str(), "r");
  char digest[65] = {};
  const bool read = pipe != nullptr && std::fscanf(pipe, "%64s", digest) == 1;
  if (pipe != nullptr) ::pclose(pipe);
  return read ? digest : "";
}

TEST(ModelRegistryTest, OnlyFilesNoOneElseCanWriteAreLoadedWithTheirChecksums) {
  const ScratchDir dir;
  fs::copy_file(builtin_plugin("two_tank.so"), dir.path() / "two_tank.so");
  fs::copy_file(builtin_plugin("rotary_pendulum.so"), dir.path() / "rotary_pendulum.so");
  fs::permissions(dir.path() / "rotary_pendulum.so", fs::perms::others_write, fs::perm_options::add);
  fs::create_symlink(builtin_plugin("rotating_arm.so"), dir.path() / "rotating_arm.so");

  auto registry = ModelRegistry::load_directory(dir.path().string());
  ASSERT_TRUE(registry.is_ok()) << registry.status().to_string();
  ASSERT_EQ(registry->models().size(), 1u);
  const ModelPtr two_tank = registry->find("two_tank");
  ASSERT_NE(two_tank, nullptr);
  const std::string expected = sha256sum(dir.path() / "two_tank.so");
  ASSERT_EQ(expected.size(), 64u);
  EXPECT_EQ(registry->sha256(*two_tank), expected);

  std::map<std::string, std::string> refused;
  for (const RefusedPlugin& r : registry->refused()) refused[fs::path(r.path).filename().string()] = r.reason;
  ASSERT_EQ(refused.size(), 2u);
  EXPECT_NE(refused["rotary_pendulum.so"].find("others can write to it"), std::string::npos)
      << refused["rotary_pendulum.so"];
  EXPECT_NE(refused["rotating_arm.so"].find("symbolic link"), std::string::npos) << refused["rotating_arm.so"];

  // A directory anyone can write to is refused as a whole: nothing loads.
  fs::permissions(dir.path(), fs::perms::others_write, fs::perm_options::add);
  auto open_dir = ModelRegistry::load_directory(dir.path().string());
  ASSERT_FALSE(open_dir.is_ok());
  EXPECT_EQ(open_dir.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(open_dir.status().message().find(dir.path().string()), std::string::npos) << open_dir.status().message();
  EXPECT_NE(open_dir.status().message().find("writable by others"), std::string::npos) << open_dir.status().message();
}

// A models directory that is safe itself but inside one others can write to
// (not sticky) is refused, naming that parent: whoever writes there can put
// another directory in its place. Inside a sticky one (/tmp) it loads.
TEST(ModelRegistryTest, AnAncestorOthersCanWriteToIsRefused) {
  const ScratchDir scratch;  // under the system's temporary directory, sticky
  const fs::path open_parent = scratch.path() / "open";
  const fs::path models = open_parent / "models";
  fs::create_directories(models);
  fs::copy_file(builtin_plugin("two_tank.so"), models / "two_tank.so");
  auto loaded = ModelRegistry::load_directory(models.string());
  ASSERT_TRUE(loaded.is_ok()) << loaded.status().to_string();
  EXPECT_EQ(loaded->models().size(), 1u);

  fs::permissions(open_parent, fs::perms::others_write, fs::perm_options::add);
  auto refused = ModelRegistry::load_directory(models.string());
  ASSERT_FALSE(refused.is_ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(refused.status().message().find("is inside " + fs::canonical(open_parent).string()), std::string::npos)
      << refused.status().message();
  EXPECT_NE(refused.status().message().find("chmod go-w"), std::string::npos) << refused.status().message();

  // Sticky, as /tmp is: others cannot rename what is not theirs.
  fs::permissions(open_parent, fs::perms::sticky_bit, fs::perm_options::add);
  EXPECT_TRUE(ModelRegistry::load_directory(models.string()).is_ok());
}

// The shared_ptr<const Model> keeps the plugin's library loaded: calling f
// after the registry (and every other holder) is gone must still work.
TEST(ModelRegistryTest, ModelOutlivesItsRegistry) {
  ModelPtr two_tank;
  {
    auto registry = ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR);
    ASSERT_TRUE(registry.is_ok()) << registry.status().to_string();
    two_tank = registry->find("two_tank");
    ASSERT_NE(two_tank, nullptr);
  }
  const double x[] = {0.4, 0.15}, theta[] = {10.0, 5.0, 0.0791, 0.1342}, u[] = {0.1, 0.03};
  double dx[2], jac[2 * 6];
  ASSERT_TRUE(two_tank->f(0.0, u, 1, 1, x, theta, dx).is_ok());
  EXPECT_DOUBLE_EQ(dx[0], (0.1 - 0.0791 * std::sqrt(0.4)) / 10.0);
  EXPECT_DOUBLE_EQ(dx[1], (0.03 + 0.0791 * std::sqrt(0.4) - 0.1342 * std::sqrt(0.15)) / 5.0);
  EXPECT_TRUE(two_tank->f_jacobian(0.0, u, x, theta, dx, jac).is_ok());
  EXPECT_EQ(two_tank->name(), "two_tank");
  EXPECT_EQ(two_tank->state_names()[1], "h2");
}

}  // namespace
}  // namespace riccati
