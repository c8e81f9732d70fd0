// The models directory read again without a restart (ReloadModels and
// SIGHUP), with sessions that keep the model they were created with; the
// per-tenant quota of stored text models; a check of a text model that
// stores nothing (validate_only); units and revisions in ModelInfo. Each
// against a real riccatid on its own models directory.
#include <signal.h>

#include <cmath>

#include "engine/data/dataset.hpp"
#include "service/daemon_fixture.hpp"

namespace riccati {
namespace {

namespace fs = std::filesystem;
using testing::DaemonProcess;
using testing::read_file;
using testing::TempDir;

const std::string kData = RICCATI_TEST_DATA_DIR;

std::string shipped(const std::string& name) {
  return read_file(std::string(RICCATI_TEST_TEXT_MODEL_DIR) + "/" + name + ".yaml");
}

// The shipped two-tank text model with A1's default set to `a1`.
std::string two_tank_text_with_a1(double a1) {
  std::string source = shipped("two_tank");
  const auto at = source.find("value: 10,");
  EXPECT_NE(at, std::string::npos);
  source.replace(at, 10, "value: " + std::to_string(a1) + ",");
  return source;
}

// Written as an operator would replace a file: a new file renamed over the old.
void replace_file(const fs::path& path, const std::string& bytes) {
  const fs::path temporary = path.string() + ".new";
  std::ofstream(temporary, std::ios::binary) << bytes;
  fs::permissions(temporary, fs::perms::owner_read | fs::perms::owner_write | fs::perms::group_read |
                                 fs::perms::others_read);
  fs::rename(temporary, path);
}

const Dataset& two_tank_data() {
  static const Dataset data =
      read_csv_file(kData + "/two_tank.csv", ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}).value();
  return data;
}

class ModelCatalogService : public ::testing::Test {
 protected:
  // A models directory of its own: the two-tank plugin and a text model file.
  void SetUp() override {
    fs::create_directories(models_dir_);
    fs::permissions(models_dir_, fs::perms::owner_all);
    fs::copy_file(fs::path(RICCATI_TEST_PLUGIN_DIR) / "two_tank.so", models_dir_ / "two_tank.so");
    replace_file(models_dir_ / "tank.yaml", two_tank_text_with_a1(10));
  }

  void start(std::vector<std::string> extra = {}) {
    extra.insert(extra.begin(), {"--models-dir", models_dir_.string()});
    daemon_ = std::make_unique<DaemonProcess>(dir_.path() / "data", extra);
    daemon_->start();
    models_ = v1::ModelService::NewStub(daemon_->channel());
    sessions_ = v1::SessionService::NewStub(daemon_->channel());
  }

  v1::ModelInfo get(const std::string& name) {
    grpc::ClientContext ctx;
    v1::GetModelRequest request;
    request.set_name(name);
    v1::ModelInfo info;
    const grpc::Status s = models_->GetModel(&ctx, request, &info);
    EXPECT_TRUE(s.ok()) << name << ": " << s.error_message();
    return info;
  }

  v1::ReloadModelsResponse reload() {
    grpc::ClientContext ctx;
    v1::ReloadModelsResponse report;
    const grpc::Status s = models_->ReloadModels(&ctx, {}, &report);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return report;
  }

  std::string create_session(const std::string& model) {
    v1::CreateSessionRequest request = testing::two_tank_session();
    request.set_model(model);
    grpc::ClientContext ctx;
    v1::SessionInfo info;
    const grpc::Status s = sessions_->CreateSession(&ctx, request, &info);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return info.id();
  }

  // The estimate after streaming samples [from, to) into `id`.
  v1::Estimate stream(const std::string& id, Eigen::Index from, Eigen::Index to) {
    grpc::ClientContext ctx;
    const auto estimates = testing::stream_samples(*sessions_, &ctx, id, two_tank_data(), from, to, 10);
    EXPECT_EQ(estimates.size(), static_cast<std::size_t>(to - from));
    return estimates.empty() ? v1::Estimate() : estimates.back();
  }
  static double a1(const v1::Estimate& e) { return e.state_size() > 2 ? e.state(2) : NAN; }  // z = [h1, h2, A1, ...]

  // The text model with A1 = 10 is the plugin to rounding (text_model_test):
  // a session on it and one on the plugin, fed the same samples, agree.
  static void expect_same_estimate(const v1::Estimate& a, const v1::Estimate& b) {
    ASSERT_EQ(a.state_size(), b.state_size());
    for (int i = 0; i < a.state_size(); ++i) EXPECT_NEAR(a.state(i), b.state(i), 1e-9 * std::abs(b.state(i))) << i;
  }

  grpc::Status create_model(const std::string& source, v1::ModelInfo* info, bool validate_only = false) {
    grpc::ClientContext ctx;
    v1::CreateModelRequest request;
    request.set_source(source);
    request.set_file_name("model.yaml");
    request.set_validate_only(validate_only);
    return models_->CreateModel(&ctx, request, info);
  }

  TempDir dir_;
  fs::path models_dir_ = dir_.path() / "models";
  std::unique_ptr<DaemonProcess> daemon_;
  std::unique_ptr<v1::ModelService::Stub> models_;
  std::unique_ptr<v1::SessionService::Stub> sessions_;
};

// A text model file replaced in the directory: after ReloadModels a new
// session runs on the new file, and the session created before runs on
// what it was created with; then the same through SIGHUP.
TEST_F(ModelCatalogService, AReloadGivesNewSessionsTheNewModelAndLeavesTheOldSessionsOnTheirs) {
  start();
  EXPECT_EQ(get("two_tank_text").theta_default(0), 10.0);
  const std::string plugin = create_session("two_tank");  // the reference: the same model as a plugin
  const std::string before = create_session("two_tank_text");
  EXPECT_NEAR(a1(stream(before, 0, 1)), 10.0, 0.1);  // the first estimate: the model's default

  replace_file(models_dir_ / "tank.yaml", two_tank_text_with_a1(12));
  EXPECT_EQ(get("two_tank_text").theta_default(0), 10.0);  // nothing changes until asked
  const v1::ReloadModelsResponse report = reload();
  ASSERT_EQ(report.changed_size(), 1);
  EXPECT_EQ(report.changed(0), "two_tank_text");
  ASSERT_EQ(report.unchanged_size(), 1);
  EXPECT_EQ(report.unchanged(0), "two_tank");
  EXPECT_EQ(report.added_size(), 0);
  EXPECT_EQ(report.removed_size(), 0);
  EXPECT_EQ(get("two_tank_text").theta_default(0), 12.0);

  const std::string after = create_session("two_tank_text");
  EXPECT_NEAR(a1(stream(after, 0, 1)), 12.0, 0.1);
  // The old session goes on on A1 = 10's model: as the plugin does.
  expect_same_estimate(stream(before, 1, 40), stream(plugin, 0, 40));

  // SIGHUP: the same, with a file added and one removed.
  replace_file(models_dir_ / "tank.yaml", two_tank_text_with_a1(14));
  fs::copy_file(fs::path(RICCATI_TEST_PLUGIN_DIR) / "rotary_pendulum.so", models_dir_ / "rotary_pendulum.so");
  fs::remove(models_dir_ / "two_tank.so");
  ::kill(daemon_->pid(), SIGHUP);
  ASSERT_TRUE(testing::wait_until(
      [&] {
        grpc::ClientContext ctx;
        v1::GetModelRequest request;
        request.set_name("rotary_pendulum");
        v1::ModelInfo info;
        return models_->GetModel(&ctx, request, &info).ok();
      },
      testing::kWait, "riccatid reloads its models directory on SIGHUP"));
  EXPECT_EQ(get("two_tank_text").theta_default(0), 14.0);
  {
    grpc::ClientContext ctx;
    v1::GetModelRequest request;
    request.set_name("two_tank");
    v1::ModelInfo info;
    EXPECT_EQ(models_->GetModel(&ctx, request, &info).error_code(), grpc::StatusCode::NOT_FOUND);
  }
  EXPECT_NEAR(a1(stream(create_session("two_tank_text"), 0, 1)), 14.0, 0.1);
  // Sessions on the removed plugin and on the replaced text file run on.
  expect_same_estimate(stream(before, 40, 60), stream(plugin, 40, 60));
  EXPECT_EQ(stream(after, 1, 40).state_size(), 6);
}

// A changed plugin is loaded anew even while its old version is in use: the
// library at the same path would otherwise be the one already loaded.
TEST_F(ModelCatalogService, AChangedPluginIsLoadedAnewWhileTheOldOneIsInUse) {
  start();
  const std::string session = create_session("two_tank");
  ASSERT_FALSE(session.empty());
  // Another plugin file under the two-tank plugin's name: a changed two_tank.so.
  replace_file(models_dir_ / "two_tank.so", read_file(fs::path(RICCATI_TEST_PLUGIN_DIR) / "rotating_arm.so"));
  const v1::ReloadModelsResponse report = reload();
  ASSERT_EQ(report.added_size(), 1);
  EXPECT_EQ(report.added(0), "rotating_arm");
  ASSERT_EQ(report.removed_size(), 1);
  EXPECT_EQ(report.removed(0), "two_tank");
  EXPECT_EQ(get("rotating_arm").name(), "rotating_arm");
  // The session on the old library runs on.
  EXPECT_NEAR(a1(stream(session, 0, 1)), 10.0, 0.1);
}

TEST_F(ModelCatalogService, AReloadOfADirectoryThatIsGoneKeepsTheModelsInUse) {
  start();
  fs::remove_all(models_dir_);
  grpc::ClientContext ctx;
  v1::ReloadModelsResponse report;
  const grpc::Status s = models_->ReloadModels(&ctx, {}, &report);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << s.error_message();
  EXPECT_NE(s.error_message().find("does not exist"), std::string::npos) << s.error_message();
  EXPECT_EQ(get("two_tank").name(), "two_tank");
}

// Units as the model declares them: the plugin's SDK spec, the text file's
// `unit:` (an output that is a state takes its unit).
TEST_F(ModelCatalogService, ModelInfoCarriesTheUnitsOfPluginsAndTextModels) {
  start();
  for (const std::string name : {"two_tank", "two_tank_text"}) {
    const v1::ModelInfo info = get(name);
    ASSERT_EQ(info.state_units_size(), 2) << name;
    EXPECT_EQ(info.state_units(0), "m") << name;
    ASSERT_EQ(info.param_units_size(), 4) << name;
    EXPECT_EQ(info.param_units(0), "m^2") << name;
    EXPECT_EQ(info.param_units(2), "m^2.5/s") << name;
    ASSERT_EQ(info.input_units_size(), 2) << name;
    EXPECT_EQ(info.input_units(1), "m^3/s") << name;
    ASSERT_EQ(info.output_units_size(), 2) << name;
    EXPECT_EQ(info.output_units(1), "m") << name;
  }
}

// validate_only compiles and answers as CreateModel would, stores nothing;
// a stored name lists its revisions.
TEST_F(ModelCatalogService, ACheckStoresNothingAndAStoredModelListsItsRevisions) {
  start();
  std::string renamed = shipped("two_tank");
  renamed.replace(renamed.find("two_tank_text"), 13, "my_tank");
  v1::ModelInfo info;
  ASSERT_TRUE(create_model(renamed, &info, true).ok());
  EXPECT_EQ(info.name(), "my_tank");
  EXPECT_EQ(info.text().revision(), 0u);
  EXPECT_EQ(info.param_names_size(), 4);
  {
    grpc::ClientContext ctx;
    v1::GetModelRequest request;
    request.set_name("my_tank");
    EXPECT_EQ(models_->GetModel(&ctx, request, &info).error_code(), grpc::StatusCode::NOT_FOUND);
  }
  const grpc::Status bad = create_model("model: m\nstates: [x]\nder:\n  x: (x +) * 2\noutputs: {y: x}\n", &info, true);
  EXPECT_EQ(bad.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(bad.error_message().rfind("model.yaml:4:10: ", 0), 0u) << bad.error_message();

  ASSERT_TRUE(create_model(renamed, &info).ok());
  ASSERT_TRUE(create_model(renamed, &info).ok());
  EXPECT_EQ(info.text().revision(), 1u) << "the same source again is the same revision (a retry)";
  ASSERT_TRUE(create_model(renamed + "# changed\n", &info).ok());
  EXPECT_EQ(info.text().revision(), 2u);
  grpc::ClientContext ctx;
  v1::ListModelsResponse list;
  ASSERT_TRUE(models_->ListModels(&ctx, {}, &list).ok());
  const auto mine = std::find_if(list.models().begin(), list.models().end(),
                                 [](const v1::ModelInfo& m) { return m.name() == "my_tank"; });
  ASSERT_NE(mine, list.models().end());
  ASSERT_EQ(mine->text().revisions_size(), 2);
  EXPECT_EQ(mine->text().revisions(0), 1u);
  EXPECT_EQ(mine->text().revisions(1), 2u);
  EXPECT_EQ(get("my_tank@1").text().revisions_size(), 2);
}

// The quota counts the stored revisions not deleted and their bytes.
TEST_F(ModelCatalogService, ATenantsStoredModelsAreHeldToTheirQuota) {
  std::string source = shipped("two_tank");  // under a name the directory's tank.yaml does not take
  source.replace(source.find("two_tank_text"), 13, "quota_tank");
  start({"--max-tenant-models", "2", "--max-tenant-model-bytes", std::to_string(3 * source.size())});
  v1::ModelInfo info;
  ASSERT_TRUE(create_model(source, &info).ok());
  ASSERT_TRUE(create_model(source + "#2\n", &info).ok());
  grpc::Status s = create_model(source + "#3\n", &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_EQ(s.error_message().rfind("limit max_tenant_models = 2 reached", 0), 0u) << s.error_message();
  // A check uses no room.
  EXPECT_TRUE(create_model(source, &info, true).ok());
  {
    grpc::ClientContext ctx;
    v1::DeleteModelRequest remove;
    remove.set_name("quota_tank");
    v1::DeleteModelResponse removed;
    ASSERT_TRUE(models_->DeleteModel(&ctx, remove, &removed).ok());
  }
  s = create_model(source, &info);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(info.text().revision(), 3u);
  // Bytes: a model as large as the two others together would pass 3 x its size.
  std::string large = source;
  large.replace(large.find("quota_tank"), 10, "large_tank");
  large += "\n# " + std::string(source.size() + 10, '-') + "\n";
  s = create_model(large, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_EQ(s.error_message().rfind("limit max_tenant_model_bytes = " + std::to_string(3 * source.size()) + " reached",
                                    0),
            0u)
      << s.error_message();
}

}  // namespace
}  // namespace riccati
