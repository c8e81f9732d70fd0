// Status and Result<T>: how the engine reports expected failures.
//
// The engine never throws across its public API and never aborts on user
// input. A function that can fail returns Status (or Result<T> when it also
// produces a value); the service layer maps StatusCode to a gRPC status code
// one to one, so the codes below mirror gRPC's.
#pragma once

#include <string>
#include <vector>
#include <utility>
#include <variant>

namespace riccati {

enum class StatusCode {
  kOk = 0,
  kCancelled = 1,
  kInvalidArgument = 3,
  kDeadlineExceeded = 4,
  kNotFound = 5,
  kAlreadyExists = 6,
  kPermissionDenied = 7,    // e.g. an operator's call by a tenant
  kResourceExhausted = 8,
  kFailedPrecondition = 9,  // e.g. a filter that diverged
  kAborted = 10,            // e.g. a job whose lease another instance took
  kOutOfRange = 11,
  kInternal = 13,
  kUnavailable = 14,
  kUnauthenticated = 16,
};

const char* status_code_name(StatusCode code);

class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  static Status ok() { return {}; }

  bool is_ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }

  // Returns a copy whose message is "context: message", to say where an error
  // happened as it travels up (e.g. "sample 17 (t = 17 s): model f returned NaN").
  Status with_context(const std::string& context) const;

  std::string to_string() const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

// For messages: names joined with ", ", and a matrix's size ("2 x 3").
std::string join_names(const std::vector<std::string>& names);
template <typename Matrix>
std::string size_text(const Matrix& m) {
  return std::to_string(m.rows()) + " x " + std::to_string(m.cols());
}

inline Status invalid_argument(std::string m) { return {StatusCode::kInvalidArgument, std::move(m)}; }
inline Status not_found(std::string m) { return {StatusCode::kNotFound, std::move(m)}; }
inline Status failed_precondition(std::string m) { return {StatusCode::kFailedPrecondition, std::move(m)}; }
inline Status internal_error(std::string m) { return {StatusCode::kInternal, std::move(m)}; }
inline Status cancelled(std::string m) { return {StatusCode::kCancelled, std::move(m)}; }
inline Status deadline_exceeded(std::string m) { return {StatusCode::kDeadlineExceeded, std::move(m)}; }

// A number as messages show it: %g with `significant` digits.
std::string message_number(double v, int significant = 6);

// A value or the Status that explains why there is none.
template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::move(value)) {}         // NOLINT(google-explicit-constructor)
  Result(Status status) : v_(std::move(status)) {}  // NOLINT(google-explicit-constructor)

  bool is_ok() const { return std::holds_alternative<T>(v_); }
  const Status& status() const {
    static const Status kOk;
    return is_ok() ? kOk : std::get<Status>(v_);
  }
  T& value() & { return std::get<T>(v_); }
  const T& value() const& { return std::get<T>(v_); }
  T&& value() && { return std::get<T>(std::move(v_)); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

 private:
  std::variant<T, Status> v_;
};

}  // namespace riccati

#define RICCATI_CONCAT_INNER_(a, b) a##b
#define RICCATI_CONCAT_(a, b) RICCATI_CONCAT_INNER_(a, b)

// Returns from the enclosing function if `expr` (a Status) is not ok.
#define RICCATI_RETURN_IF_ERROR(expr)                   \
  do {                                                  \
    ::riccati::Status riccati_status_ = (expr);         \
    if (!riccati_status_.is_ok()) return riccati_status_; \
  } while (false)

// `RICCATI_ASSIGN_OR_RETURN(auto x, make_x());` binds the value or returns the error.
#define RICCATI_ASSIGN_OR_RETURN(lhs, expr) \
  RICCATI_ASSIGN_OR_RETURN_IMPL_(RICCATI_CONCAT_(riccati_result_, __LINE__), lhs, expr)
#define RICCATI_ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                                   \
  if (!tmp.is_ok()) return tmp.status();               \
  lhs = std::move(tmp).value()
