// Conversions between the API (riccati.v1 protobuf) and the engine that every
// service uses: statuses, vectors, matrices, covariances, timestamps and
// enums. What is particular to a service is converted beside it
// (run_settings.hpp for the filter settings of sessions and jobs,
// jobs/job_convert.hpp for job specs and results, the rpc/ handlers for the
// rest). Errors name the request field ("filter.r: ...") so a client knows
// what to fix.
#pragma once

#include <google/protobuf/timestamp.pb.h>
#include <grpcpp/grpcpp.h>

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <string_view>

#include "engine/status.hpp"
#include "riccati/enum_names.hpp"
#include "riccati/v1/common.pb.h"

namespace riccati::service {

// Status <-> gRPC (the codes are the same numbers).
// The gRPC status of a Status, its message printable().
grpc::Status to_grpc(const Status& status);
// A message as a client may be shown it: valid UTF-8 kept, control
// characters and invalid bytes as \xNN, at most 2 KiB.
std::string printable(const std::string& text);
v1::Error to_error(const Status& status);
// The inverse of to_error (a stored divergence); a code of 0 reads as `otherwise`.
Status from_error(const v1::Error& error, StatusCode otherwise);

void set_timestamp(std::int64_t unix_ms, google::protobuf::Timestamp* out);

// Vectors and matrices.
v1::Matrix to_matrix(const Eigen::MatrixXd& m);
Result<Eigen::MatrixXd> from_matrix(const v1::Matrix& m, const std::string& field);
Result<Eigen::VectorXd> from_values(const google::protobuf::RepeatedField<double>& v, Eigen::Index expected,
                                    const std::string& field);
template <typename Vector>
void copy_values(const Vector& v, google::protobuf::RepeatedField<double>* out) {
  out->Reserve(static_cast<int>(v.size()));
  for (Eigen::Index i = 0; i < v.size(); ++i) out->Add(v[i]);
}

// A covariance of size n x n from its scalar, diagonal or full form;
// `required` false makes an absent one zero.
Result<Eigen::MatrixXd> from_covariance(const v1::Covariance& c, Eigen::Index n, bool required,
                                        const std::string& field);

// The inverse, as a client would give it back: diagonal when the matrix is
// diagonal, else full.
v1::Covariance to_covariance(const Eigen::MatrixXd& m);

// An engine enum from the API's: by name (the API's short name is the
// engine's, enum_names.hpp), with `parse` the engine's parser for it. The
// API's UNSPECIFIED (0) leaves `*out` as it is: the engine's default.
template <typename T>
Status enum_from_proto(int number, const google::protobuf::EnumDescriptor& descriptor,
                       Result<T> (*parse)(std::string_view), const std::string& field, T* out) {
  if (number == 0) return Status::ok();
  const google::protobuf::EnumValueDescriptor* value = descriptor.FindValueByNumber(number);
  if (value == nullptr) {
    return invalid_argument(field + " " + std::to_string(number) + " is unknown (expected " +
                            api::enum_choice_list(descriptor) + ")");
  }
  Result<T> parsed = parse(api::enum_value_name(*value));
  if (!parsed.is_ok()) return parsed.status().with_context(field);
  *out = parsed.value();
  return Status::ok();
}

// The API's enum value of the engine's `name` (0 if the API has none).
int enum_to_proto(const google::protobuf::EnumDescriptor& descriptor, std::string_view name);

}  // namespace riccati::service
