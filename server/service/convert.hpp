// Conversions between the API (riccati.v1 protobuf) and the engine.
//
// The one place where request fields are checked and turned into engine
// settings: sizes against the model, finiteness, enums. Errors name the
// field ("filter.r: ...") so a client knows what to fix.
#pragma once

#include <grpcpp/grpcpp.h>

#include <cstdint>
#include <string>
#include <string_view>

#include "engine/estimation/identification.hpp"
#include "engine/models/model.hpp"
#include "engine/estimation/validation.hpp"
#include "riccati/v1/common.pb.h"
#include "riccati/v1/datasets.pb.h"
#include "riccati/v1/jobs.pb.h"
#include "riccati/v1/models.pb.h"
#include "store/store.hpp"

namespace riccati::service {

// Status <-> gRPC (the codes are the same numbers).
grpc::Status to_grpc(const Status& status);
v1::Error to_error(const Status& status);

std::int64_t now_ms();
// A new random id such as "job-3f9a0c1d5e7b2a64" (64 random bits).
std::string new_id(std::string_view prefix);
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

// A covariance of size n x n from its diagonal or full form; `required`
// false makes an absent one zero.
Result<Eigen::MatrixXd> from_covariance(const v1::Covariance& c, Eigen::Index n, bool required,
                                        const std::string& field);

Result<IntegratorSettings> from_proto(const v1::IntegratorSettings& s);
HoldOrder from_proto(v1::HoldOrder hold);
Result<FilterSettings> from_proto(const v1::FilterSettings& s, const Model& model);
Result<IdentificationSettings> from_proto(const v1::IdentificationSpec& spec, const Model& model);
// Everything of a validation spec except where the parameters come from.
Result<ValidationSettings> from_proto(const v1::ValidationSpec& spec, const Model& model);
void initial_state_from_proto(const v1::InitialState& s, InitialState* mode, Eigen::VectorXd* x0);
// The initial covariance of a run: p0, or for the optimal filter R0^-1 from
// filter.optimal.r0 (one of the two).
Result<Eigen::MatrixXd> initial_covariance(const v1::Covariance& p0, const v1::FilterSettings& filter,
                                           const Model& model);

v1::ModelInfo to_proto(const Model& model);
v1::DatasetInfo to_proto(const DatasetRecord& record);
v1::IdentificationResult to_proto(const IdentificationResult& r);
// The inverse of to_proto (a stored result or checkpoint).
Result<IdentificationResult> from_proto(const v1::IdentificationResult& r);
v1::ValidationResult to_proto(const ValidationResult& r, const Eigen::VectorXd& theta);
v1::FilterKind to_proto(FilterKind kind);
v1::JobState to_proto(JobState state);

}  // namespace riccati::service
