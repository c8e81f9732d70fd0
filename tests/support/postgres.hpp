// PostgreSQL for tests: the server in RICCATI_TEST_POSTGRES_URL (which
// scripts/with-postgres.sh starts and sets), and a schema of each test's own
// in it, so tests stay independent and can run in parallel.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <pqxx/pqxx>
#include <random>
#include <string>

namespace riccati::testing {

// The test server's URL, or empty.
inline std::string postgres_test_url() {
  const char* url = std::getenv("RICCATI_TEST_POSTGRES_URL");
  return url != nullptr ? url : "";
}

// RICCATI_REQUIRE_POSTGRES=1 (CI): a missing server fails the tests instead of skipping them.
inline bool postgres_required() {
  const char* required = std::getenv("RICCATI_REQUIRE_POSTGRES");
  return required != nullptr && std::string(required) == "1";
}

// Skips the test (or fails it, if PostgreSQL is required) without a server.
#define RICCATI_SKIP_WITHOUT_POSTGRES()                                                                      \
  do {                                                                                                       \
    if (::riccati::testing::postgres_test_url().empty()) {                                                   \
      if (::riccati::testing::postgres_required()) {                                                         \
        GTEST_FAIL() << "RICCATI_REQUIRE_POSTGRES=1 but RICCATI_TEST_POSTGRES_URL is not set: run the tests " \
                        "under scripts/with-postgres.sh";                                                    \
      }                                                                                                      \
      GTEST_SKIP() << "RICCATI_TEST_POSTGRES_URL is not set (scripts/with-postgres.sh sets it)";             \
    }                                                                                                        \
  } while (false)

// A fresh schema in the test database, dropped at the end. url() connects
// with it first on the search path, so a store opened there creates its
// tables in it.
class PostgresSchema {
 public:
  PostgresSchema() {
    static std::atomic<int> counter{0};
    std::random_device random;
    name_ = "riccati_test_" + std::to_string(getpid()) + "_" + std::to_string(counter++) + "_" +
            std::to_string(random() % 1000000);
    exec("DROP SCHEMA IF EXISTS " + name_ + " CASCADE; CREATE SCHEMA " + name_);
  }
  ~PostgresSchema() {
    try {
      exec("DROP SCHEMA IF EXISTS " + name_ + " CASCADE");
    } catch (const std::exception&) {
      // The server may be gone already; the cluster is thrown away anyway.
    }
  }
  PostgresSchema(const PostgresSchema&) = delete;
  PostgresSchema& operator=(const PostgresSchema&) = delete;

  const std::string& name() const { return name_; }

  // The test URL with this schema on the search path and `params` (more
  // URI parameters, "a=b&c=d") added.
  std::string url(const std::string& params = "") const {
    const std::string base = postgres_test_url();
    std::string out = base + (base.find('?') == std::string::npos ? "?" : "&") + "options=-csearch_path%3D" + name_;
    if (!params.empty()) out += "&" + params;
    return out;
  }

  // Runs SQL in this schema, returning the result.
  pqxx::result exec(const std::string& sql) const {
    pqxx::connection c(postgres_test_url());
    pqxx::nontransaction tx(c);
    tx.exec("SET client_min_messages = warning; SET search_path = " + name_ + ", public");
    return tx.exec(sql);
  }

 private:
  std::string name_;
};

}  // namespace riccati::testing
