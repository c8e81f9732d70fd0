// The PostgreSQL store: the Store interface (store.hpp) on a PostgreSQL
// server, for teams and for several riccatid sharing one database.
#pragma once

#include <memory>
#include <string>

#include "store/store.hpp"

namespace riccati {

// Connects to the database at `url` (a libpq connection URI,
// postgresql://user:password@host:port/dbname?param=value..., or a libpq
// key=value string) and brings its schema up to date: versioned migrations,
// applied at start in one transaction under an advisory lock, so instances
// starting at once do not race. The tables go to the first schema of the
// connection's search_path (`?options=-csearch_path%3Dname` selects one).
// UNAVAILABLE if the server cannot be reached; FAILED_PRECONDITION if the
// schema is newer than this binary. Leases are reckoned in the database
// server's clock, so that instances on hosts whose clocks disagree agree on
// when one has expired; a `clock` given (tests) stands in for it.
Result<std::unique_ptr<Store>> open_postgres_store(const std::string& url,
                                                   std::shared_ptr<StoreClock> clock = nullptr);

// `url` with its password replaced by "***" (in the user-info part of a URI
// and in any password=... parameter), for logs and error messages.
std::string redact_database_url(const std::string& url);

}  // namespace riccati
