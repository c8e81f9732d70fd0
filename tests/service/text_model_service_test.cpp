// Text models through a real riccatid: CreateModel, GetModel, ListModels,
// DeleteModel; an identification job and a session on an uploaded model,
// compared with the same on the C++ plugin; revisions that keep a stored
// job's model; refusals; and tenants that never see each other's models.
#include <openssl/evp.h>

#include <array>
#include <cmath>

#include "service/daemon_fixture.hpp"

namespace riccati {
namespace {

using testing::DaemonProcess;
using testing::DaemonTest;
using testing::read_file;
using testing::TempDir;

std::string shipped(const std::string& name) {
  return read_file(std::string(RICCATI_TEST_TEXT_MODEL_DIR) + "/" + name + ".yaml");
}

grpc::Status create_model(v1::ModelService::Stub& models, grpc::ClientContext* ctx, const std::string& source,
                          v1::ModelInfo* info) {
  v1::CreateModelRequest request;
  request.set_source(source);
  request.set_file_name("model.yaml");
  return models.CreateModel(ctx, request, info);
}

class TextModelService : public DaemonTest {
 protected:
  grpc::Status create(const std::string& source, v1::ModelInfo* info) {
    grpc::ClientContext ctx;
    return create_model(*models_, &ctx, source, info);
  }
  grpc::Status get(const std::string& name, v1::ModelInfo* info) {
    grpc::ClientContext ctx;
    v1::GetModelRequest request;
    request.set_name(name);
    return models_->GetModel(&ctx, request, info);
  }
  int count_models() {
    grpc::ClientContext ctx;
    v1::ListModelsResponse list;
    EXPECT_TRUE(models_->ListModels(&ctx, {}, &list).ok());
    return list.models_size();
  }
};

TEST_F(TextModelService, AnUploadedModelIsListedShownAndDescribedAsText) {
  v1::ModelInfo info;
  const grpc::Status s = create(shipped("two_tank"), &info);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(info.name(), "two_tank_text");
  EXPECT_EQ(info.text().revision(), 1u);
  EXPECT_EQ(info.text().sha256().size(), 64u);
  EXPECT_EQ(info.text().source(), shipped("two_tank"));
  EXPECT_TRUE(info.exact_f_jacobian());
  EXPECT_TRUE(info.jacobian_check().checked());
  EXPECT_TRUE(info.jacobian_check().agrees());
  ASSERT_EQ(info.text().f_sparsity_size(), 2);
  EXPECT_EQ(info.text().f_sparsity(0), "x.x.x.");
  EXPECT_EQ(count_models(), 5);
  v1::ModelInfo again;
  ASSERT_TRUE(get("two_tank_text", &again).ok());
  EXPECT_EQ(again.text().equations(0), "h1' = (F1 - q1) / A1");
  // The plugins are not text models.
  v1::ModelInfo plugin;
  ASSERT_TRUE(get("two_tank", &plugin).ok());
  EXPECT_FALSE(plugin.has_text());
}

TEST_F(TextModelService, IdentificationOnTheTextModelEqualsThePlugins) {
  v1::ModelInfo info;
  ASSERT_TRUE(create(shipped("two_tank"), &info).ok());
  const std::string dataset = upload_two_tank();
  v1::IdentificationSpec spec = hensen(dataset, 2);
  const v1::Job plugin_job = submit(spec);
  spec.set_model("two_tank_text");
  const v1::Job text_job = submit(spec);
  // Stored with the revision it was checked against.
  EXPECT_EQ(get_job(text_job.id()).identification().model(), "two_tank_text@1");
  ASSERT_EQ(wait_for(plugin_job.id()).state(), v1::JOB_STATE_SUCCEEDED);
  ASSERT_EQ(wait_for(text_job.id()).state(), v1::JOB_STATE_SUCCEEDED);
  const v1::IdentificationResult a = result_of(text_job.id()).identification();
  const v1::IdentificationResult b = result_of(plugin_job.id()).identification();
  ASSERT_EQ(a.theta_size(), 4);
  ASSERT_EQ(b.theta_size(), 4);
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(a.theta(i), b.theta(i), 1e-9 * std::abs(b.theta(i))) << i;
    EXPECT_NEAR(a.theta_std(i), b.theta_std(i), 1e-9 * std::abs(b.theta_std(i))) << i;
  }
}

TEST_F(TextModelService, ANewRevisionOrADeleteLeavesAStoredJobsModelAsItWas) {
  v1::ModelInfo info;
  ASSERT_TRUE(create(shipped("two_tank"), &info).ok());
  std::string changed = shipped("two_tank");
  const auto at = changed.find("value: 10,");
  ASSERT_NE(at, std::string::npos);
  changed.replace(at, 10, "value: 12,");
  ASSERT_TRUE(create(changed, &info).ok());
  EXPECT_EQ(info.text().revision(), 2u);
  EXPECT_EQ(info.theta_default(0), 12.0);
  v1::ModelInfo first;
  ASSERT_TRUE(get("two_tank_text@1", &first).ok());
  EXPECT_EQ(first.theta_default(0), 10.0);
  EXPECT_EQ(count_models(), 5);  // one name, its latest revision

  grpc::ClientContext ctx;
  v1::DeleteModelRequest remove;
  remove.set_name("two_tank_text");
  v1::DeleteModelResponse removed;
  ASSERT_TRUE(models_->DeleteModel(&ctx, remove, &removed).ok());
  EXPECT_EQ(get("two_tank_text", &info).error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(count_models(), 4);
  // No job that may run names its revisions: they are purged (a queued
  // job's revision stays until the job ends: BoundedRequests.
  // RemovedModelsArePurgedUnlessAQueuedJobNamesThem).
  EXPECT_EQ(get("two_tank_text@2", &info).error_code(), grpc::StatusCode::NOT_FOUND);
  // Uploaded again, the name goes on counting: two_tank_text@2 is never another source.
  ASSERT_TRUE(create(shipped("two_tank"), &info).ok());
  EXPECT_EQ(info.text().revision(), 3u);
  grpc::ClientContext again;
  remove.set_name("no_such_model");
  EXPECT_EQ(models_->DeleteModel(&again, remove, &removed).error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_F(TextModelService, BadModelsAreRefusedWithTheirPlaceAndNothingIsStored) {
  v1::ModelInfo info;
  grpc::Status s = create("model: m\nstates: [x]\nder:\n  x: (x +) * 2\noutputs: {y: x}\n", &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  // The line and a caret under the spot, on lines of their own.
  EXPECT_EQ(s.error_message(),
            "model.yaml:4:10: unexpected ')': a number, a name or '(' is expected\n    x: (x +) * 2\n           ^");
  s = create("model: m\nstates: [x]\ndefine: {a: b, b: a}\nder: {x: a}\noutputs: {y: x}\n", &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("cycle"), std::string::npos) << s.error_message();
  s = create(std::string(300 * 1024, '#'), &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("limit"), std::string::npos) << s.error_message();
  // A built-in model's name is taken.
  std::string same = shipped("two_tank");
  same.replace(same.find("two_tank_text"), 13, "two_tank");
  s = create(same, &info);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::ALREADY_EXISTS) << s.error_message();
  EXPECT_EQ(count_models(), 4);
  EXPECT_EQ(get("m", &info).error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_F(TextModelService, ASessionRunsOnAnUploadedModel) {
  v1::ModelInfo info;
  ASSERT_TRUE(create(shipped("two_tank"), &info).ok());
  v1::CreateSessionRequest request = testing::two_tank_session();
  request.set_model("two_tank_text");
  grpc::ClientContext ctx;
  v1::SessionInfo session;
  const grpc::Status s = sessions_->CreateSession(&ctx, request, &session);
  EXPECT_TRUE(s.ok()) << s.error_message();
}

// The optimal filter needs the mechanical form: the manipulator written as
// text has it.
TEST_F(TextModelService, AnOptimalFilterSessionRunsOnAMechanicalTextModel) {
  v1::ModelInfo info;
  ASSERT_TRUE(create(shipped("flexible_manipulator"), &info).ok());
  EXPECT_EQ(info.ndof(), 2u);
  v1::CreateSessionRequest request = testing::manipulator_case_c_session();
  request.set_model("flexible_manipulator_text");
  grpc::ClientContext ctx;
  v1::SessionInfo session;
  const grpc::Status s = sessions_->CreateSession(&ctx, request, &session);
  EXPECT_TRUE(s.ok()) << s.error_message();
}

// ---------------------------------------------------------------------------
// Tenants

const std::string kAlpha = "alpha-7f3c9e2b4d1a";
const std::string kBeta = "beta-0c5e8a6f2b9d";

std::string digest(const std::string& token) {
  std::array<unsigned char, EVP_MAX_MD_SIZE> md;
  unsigned int n = 0;
  EVP_Digest(token.data(), token.size(), md.data(), &n, EVP_sha256(), nullptr);
  std::string out = "sha256:";
  char hex[3];
  for (unsigned int i = 0; i < n; ++i) {
    std::snprintf(hex, sizeof hex, "%02x", md[i]);
    out += hex;
  }
  return out;
}

std::unique_ptr<grpc::ClientContext> as(const std::string& token) {
  auto ctx = std::make_unique<grpc::ClientContext>();
  ctx->AddMetadata("authorization", "Bearer " + token);
  ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  return ctx;
}

TEST(TextModelTenants, AnotherTenantCannotSeeOrUseAModel) {
  TempDir dir;
  const auto tokens = dir.path() / "tokens";
  std::ofstream(tokens) << "alpha " << digest(kAlpha) << "\nbeta " << digest(kBeta) << "\n";
  DaemonProcess daemon(dir.path() / "data", {"--tokens-file", tokens.string()});
  daemon.start();
  auto models = v1::ModelService::NewStub(daemon.channel());
  auto datasets = v1::DatasetService::NewStub(daemon.channel());
  auto jobs = v1::JobService::NewStub(daemon.channel());
  v1::ModelInfo info;
  {
    auto ctx = as(kAlpha);
    ASSERT_TRUE(create_model(*models, ctx.get(), shipped("two_tank"), &info).ok());
  }
  {
    auto ctx = as(kBeta);
    v1::ListModelsResponse list;
    ASSERT_TRUE(models->ListModels(ctx.get(), {}, &list).ok());
    EXPECT_EQ(list.models_size(), 4);
  }
  for (const std::string name : {"two_tank_text", "two_tank_text@1"}) {
    auto ctx = as(kBeta);
    v1::GetModelRequest get;
    get.set_name(name);
    const grpc::Status s = models->GetModel(ctx.get(), get, &info);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << name;
    EXPECT_EQ(s.error_message(), "no model \"" + name + "\" is loaded");  // as if it did not exist
  }
  {
    auto ctx = as(kBeta);
    v1::DatasetInfo dataset;
    ASSERT_TRUE(testing::upload_dataset(*datasets, ctx.get(), "two_tank.csv",
                                        read_file(std::string(RICCATI_TEST_DATA_DIR) + "/two_tank.csv"), {"F1", "F2"},
                                        {"h1", "h2"}, &dataset)
                    .ok());
    v1::IdentificationSpec spec = testing::hensen_spec(dataset.id(), 1);
    spec.set_model("two_tank_text");
    auto submit = as(kBeta);
    v1::Job job;
    EXPECT_EQ(jobs->SubmitIdentification(submit.get(), spec, &job).error_code(), grpc::StatusCode::NOT_FOUND);
    auto remove = as(kBeta);
    v1::DeleteModelRequest request;
    request.set_name("two_tank_text");
    v1::DeleteModelResponse removed;
    EXPECT_EQ(models->DeleteModel(remove.get(), request, &removed).error_code(), grpc::StatusCode::NOT_FOUND);
    // Beta's own model of the same name is another model.
    auto own = as(kBeta);
    ASSERT_TRUE(create_model(*models, own.get(), shipped("two_tank"), &info).ok());
    EXPECT_EQ(info.text().revision(), 1u);
  }
  auto ctx = as(kAlpha);
  v1::GetModelRequest get;
  get.set_name("two_tank_text");
  ASSERT_TRUE(models->GetModel(ctx.get(), get, &info).ok());
  EXPECT_EQ(info.text().revision(), 1u);
}

}  // namespace
}  // namespace riccati
