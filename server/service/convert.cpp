#include "service/convert.hpp"

#include <cmath>

namespace riccati::service {

grpc::Status to_grpc(const Status& status) {
  if (status.is_ok()) return grpc::Status::OK;
  return {static_cast<grpc::StatusCode>(status.code()), status.message()};
}

v1::Error to_error(const Status& status) {
  v1::Error e;
  e.set_code(static_cast<int>(status.code()));
  e.set_message(status.message());
  return e;
}

Status from_error(const v1::Error& error, StatusCode otherwise) {
  return {error.code() != 0 ? static_cast<StatusCode>(error.code()) : otherwise, error.message()};
}

void set_timestamp(std::int64_t unix_ms, google::protobuf::Timestamp* out) {
  out->set_seconds(unix_ms / 1000);
  out->set_nanos(static_cast<int>((unix_ms % 1000) * 1000000));
}

v1::Matrix to_matrix(const Eigen::MatrixXd& m) {
  v1::Matrix out;
  out.set_rows(static_cast<uint32_t>(m.rows()));
  out.set_cols(static_cast<uint32_t>(m.cols()));
  out.mutable_values()->Add(m.data(), m.data() + m.size());
  return out;
}

Result<Eigen::MatrixXd> from_matrix(const v1::Matrix& m, const std::string& field) {
  const std::int64_t expected = static_cast<std::int64_t>(m.rows()) * m.cols();
  if (expected != m.values_size()) {
    return invalid_argument(field + ": a " + std::to_string(m.rows()) + " x " + std::to_string(m.cols()) +
                            " matrix needs " + std::to_string(expected) + " values, got " +
                            std::to_string(m.values_size()));
  }
  Eigen::MatrixXd out = Eigen::Map<const Eigen::MatrixXd>(m.values().data(), m.rows(), m.cols());
  if (!out.allFinite()) return invalid_argument(field + " has a NaN or infinite value");
  return out;
}

Result<Eigen::VectorXd> from_values(const google::protobuf::RepeatedField<double>& v, Eigen::Index expected,
                                    const std::string& field) {
  if (v.size() != expected) {
    return invalid_argument(field + " needs " + std::to_string(expected) + " values, got " +
                            std::to_string(v.size()));
  }
  Eigen::VectorXd out = Eigen::Map<const Eigen::VectorXd>(v.data(), v.size());
  for (Eigen::Index i = 0; i < out.size(); ++i) {
    if (!std::isfinite(out[i])) return invalid_argument(field + "[" + std::to_string(i) + "] is not finite");
  }
  return out;
}

Result<Eigen::MatrixXd> from_covariance(const v1::Covariance& c, Eigen::Index n, bool required,
                                        const std::string& field) {
  switch (c.form_case()) {
    case v1::Covariance::kScalar: {
      if (!std::isfinite(c.scalar())) return invalid_argument(field + ".scalar is not finite");
      return Eigen::MatrixXd(Eigen::MatrixXd::Identity(n, n) * c.scalar());
    }
    case v1::Covariance::kDiagonal: {
      RICCATI_ASSIGN_OR_RETURN(const Eigen::VectorXd d, from_values(c.diagonal().values(), n, field + ".diagonal"));
      return Eigen::MatrixXd(d.asDiagonal());
    }
    case v1::Covariance::kFull: {
      RICCATI_ASSIGN_OR_RETURN(Eigen::MatrixXd m, from_matrix(c.full(), field + ".full"));
      if (m.rows() != n || m.cols() != n) {
        return invalid_argument(field + ".full must be " + std::to_string(n) + " x " + std::to_string(n));
      }
      return m;
    }
    case v1::Covariance::FORM_NOT_SET:
      break;
  }
  if (required) {
    return invalid_argument(field + " is required (one value for the whole diagonal, " + std::to_string(n) +
                            " values on the diagonal, or the full matrix)");
  }
  return Eigen::MatrixXd(Eigen::MatrixXd::Zero(n, n));
}

int enum_to_proto(const google::protobuf::EnumDescriptor& descriptor, std::string_view name) {
  const google::protobuf::EnumValueDescriptor* value = api::find_enum_value(descriptor, name);
  return value != nullptr ? value->number() : 0;
}

}  // namespace riccati::service
