// libFuzzer target: validation of the requests that carry numbers into the
// engine. The first byte chooses the request:
//   even: [CreateSessionRequest][MeasurementBatch], the length of the first
//         in the next two bytes; the session is created as riccatid does
//         and every measurement of the batch is processed;
//   odd:  an IdentificationSpec, converted as a submission is and, when
//         accepted, run (two passes at most) on a short two-tank record.
// What validation accepts must run without crashing: errors are fine.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <stdlib.h>
#include <memory>
#include <string>
#include <spdlog/spdlog.h>

#include "engine/data/dataset.hpp"
#include "engine/estimation/identification.hpp"
#include "engine/models/plugin_loader.hpp"
#include "riccati/v1/jobs.pb.h"
#include "riccati/v1/sessions.pb.h"
#include "service/jobs/job_convert.hpp"
#include "service/models/model_catalog.hpp"
#include "service/sessions/session_manager.hpp"
#include "store/store.hpp"

namespace {

using namespace riccati;

const ModelRegistry& registry() {
  static const ModelRegistry models = [] {
    spdlog::set_level(spdlog::level::off);
    auto loaded = ModelRegistry::load_directory(RICCATI_FUZZ_PLUGIN_DIR);
    if (!loaded.is_ok()) std::abort();
    return std::move(loaded).value();
  }();
  return models;
}

// Sessions resolve their model through a catalog, which also knows the
// tenants' text models: those live in a store, here an empty SQLite one.
const service::ModelCatalog& catalog() {
  static const std::unique_ptr<Store> store = [] {
    char dir[] = "/tmp/riccati-fuzz-XXXXXX";
    if (::mkdtemp(dir) == nullptr) std::abort();
    auto opened = open_sqlite_store(std::string(dir) + "/riccati.db");
    if (!opened.is_ok()) std::abort();
    return std::move(opened).value();
  }();
  static const service::ModelCatalog models(registry(), *store);
  return models;
}

// Five samples of the two-tank record (t, F1, F2, h1, h2).
const Dataset& two_tank_record() {
  static const Dataset data = [] {
    auto parsed = parse_csv(
        "t,F1,F2,h1,h2\n0,1e-4,0,0.1,0.05\n1,1e-4,0,0.101,0.051\n2,1e-4,2e-5,0.102,0.052\n"
        "3,1e-4,2e-5,0.103,0.052\n4,0,2e-5,0.103,0.053\n",
        ColumnMapping{"t", {"F1", "F2"}, {"h1", "h2"}}, "fuzz");
    if (!parsed.is_ok()) std::abort();
    return std::move(parsed).value();
  }();
  return data;
}

void fuzz_session(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return;
  const std::size_t create_size = std::min<std::size_t>(size - 2, data[0] | (std::size_t{data[1]} << 8));
  v1::CreateSessionRequest create;
  if (!create.ParseFromArray(data + 2, static_cast<int>(create_size))) return;
  v1::MeasurementBatch batch;
  if (!batch.ParseFromArray(data + 2 + create_size, static_cast<int>(size - 2 - create_size))) return;
  // No reaper thread work matters here: the timeout is long.
  static service::SessionManager sessions(catalog(), std::chrono::hours(1));
  auto session = sessions.create("fuzz", create);
  if (!session.is_ok()) return;
  int processed = 0;
  for (const auto& m : batch.measurements()) {
    if (++processed > 32) break;
    v1::MeasurementResult out;
    if (!session.value()->process(m, /*full_covariance=*/true, &out).is_ok()) break;
  }
  (void)sessions.close("fuzz", session.value()->id());
}

void fuzz_identification(const std::uint8_t* data, std::size_t size) {
  v1::IdentificationSpec spec;
  if (!spec.ParseFromArray(data, static_cast<int>(size))) return;
  const ModelPtr model = registry().find("two_tank");
  auto settings = service::from_proto(spec, *model);
  if (!settings.is_ok()) return;
  settings.value().passes = std::min(settings.value().passes, 2);
  (void)identify(model, two_tank_record(), settings.value());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  if (data[0] % 2 == 0) {
    fuzz_session(data + 1, size - 1);
  } else {
    fuzz_identification(data + 1, size - 1);
  }
  return 0;
}
