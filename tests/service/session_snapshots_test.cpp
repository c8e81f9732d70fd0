// The session manager's snapshot writer against a real SQLite store: the
// snapshots that fall due close together are stored in one transaction, so
// that the commits (each a sync to disk) do not grow with the sessions.
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "engine/models/plugin_loader.hpp"
#include "service/models/model_catalog.hpp"
#include "service/sessions/session_manager.hpp"
#include "store/store.hpp"
#include "support/manual_clock.hpp"
#include "support/requests.hpp"
#include "support/wait.hpp"

namespace riccati::service {
namespace {

// The stored time of each snapshot stored after `since_ms`, read through a
// connection of its own (as another process would see the file).
std::vector<std::int64_t> stored_after(const std::string& path, std::int64_t since_ms) {
  sqlite3* db = nullptr;
  std::vector<std::int64_t> out;
  if (sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) == SQLITE_OK) {
    sqlite3_stmt* q = nullptr;
    if (sqlite3_prepare_v2(db, "SELECT updated_ms FROM session_snapshots WHERE updated_ms > ?", -1, &q, nullptr) ==
        SQLITE_OK) {
      sqlite3_bind_int64(q, 1, since_ms);
      while (sqlite3_step(q) == SQLITE_ROW) out.push_back(sqlite3_column_int64(q, 0));
    }
    sqlite3_finalize(q);
  }
  sqlite3_close(db);
  return out;
}

TEST(SessionSnapshots, ThoseDueTogetherAreStoredInOneTransaction) {
  const auto dir = std::filesystem::temp_directory_path() / ("riccati-snapshots-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "riccati.db").string();
  // Every read of the store's clock a millisecond on: each transaction
  // stamps its snapshots with a time of its own, so the distinct stored
  // times count the transactions.
  auto clock = std::make_shared<testing::ManualClock>(1);
  auto store = open_sqlite_store(path, clock).value();
  ModelCatalog models(ModelRegistry::load_directory(RICCATI_TEST_PLUGIN_DIR).value(), *store);
  SessionStoreOptions options;
  options.instance_id = "inst-1";
  options.snapshot_interval = std::chrono::milliseconds(2000);  // gathers for 500 ms
  {
    SessionManager sessions(models, std::chrono::seconds(600), Limits{}, store.get(), options);
    ASSERT_TRUE(sessions.start().is_ok());
    constexpr int kSessions = 10;
    std::vector<std::shared_ptr<Session>> made;
    for (int i = 0; i < kSessions; ++i) {
      auto created = sessions.create("t", testing::two_tank_session());
      ASSERT_TRUE(created.is_ok()) << created.status().to_string();
      made.push_back(created.value());
    }
    const std::int64_t since = clock->peek() - 1;  // what the creations stored is before
    // One after another, 20 ms apart (as streams detach, or fall due), all
    // within the 500 ms the writer gathers for.
    for (const auto& session : made) {
      sessions.save(*session);
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    ASSERT_TRUE(testing::wait_until([&] { return stored_after(path, since).size() == kSessions; },
                                    std::chrono::seconds(10), "every session's snapshot is stored"));
    // A stored time a transaction: the first snapshot is stored at once (the
    // writer had not written for a while), the others gathered behind it.
    const std::vector<std::int64_t> times = stored_after(path, since);
    const std::set<std::int64_t> transactions(times.begin(), times.end());
    RecordProperty("transactions", static_cast<int>(transactions.size()));
    EXPECT_LE(transactions.size(), 3u) << kSessions << " snapshots saved 20 ms apart";
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace riccati::service
