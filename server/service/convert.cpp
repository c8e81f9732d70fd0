#include "service/convert.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

#include "service/ids.hpp"

namespace riccati::service {

// What a message may show of the bytes it quotes (a CSV header, a cell, a
// file name): valid UTF-8 as it is, control characters and invalid bytes as
// \xNN, and at most kMaxMessage bytes of it, so that junk uploaded is not
// echoed raw into a client's terminal or log. Newlines are kept: a text
// model's error shows the line of the model with a caret under the spot.
std::string printable(const std::string& text) {
  constexpr std::size_t kMaxMessage = 2048;
  std::string out;
  out.reserve(std::min(text.size(), kMaxMessage) + 16);
  auto escape = [&out](unsigned char c) {
    static const char* hex = "0123456789abcdef";
    out += "\\x";
    out += hex[c >> 4];
    out += hex[c & 15];
  };
  std::size_t i = 0;
  while (i < text.size() && out.size() < kMaxMessage) {
    const auto c = static_cast<unsigned char>(text[i]);
    if ((c >= 0x20 && c < 0x7f) || c == '\n') {
      out += static_cast<char>(c);
      ++i;
      continue;
    }
    // A multi-byte UTF-8 sequence: its lead byte says how long it is.
    const std::size_t length = (c & 0xe0) == 0xc0 ? 2 : (c & 0xf0) == 0xe0 ? 3 : (c & 0xf8) == 0xf0 ? 4 : 0;
    bool valid = length > 0 && i + length <= text.size() && c != 0xc0 && c != 0xc1 && c < 0xf5;
    for (std::size_t k = 1; valid && k < length; ++k) valid = (static_cast<unsigned char>(text[i + k]) & 0xc0) == 0x80;
    if (valid) {
      out.append(text, i, length);
      i += length;
    } else {
      escape(c);
      ++i;
    }
  }
  if (i < text.size()) out += " ... (" + std::to_string(text.size() - i) + " more bytes)";
  return out;
}

namespace {

// What a client is told of an error. An INTERNAL one is a fault of the
// daemon or of a plugin, not of the request: it is logged whole, under an
// incident id that the client gets to quote to the operator, with the
// message (which names no server path: the store's and the loader's
// messages name none).
std::string client_message(const Status& status) {
  if (status.code() != StatusCode::kInternal) return printable(status.message());
  const std::string incident = new_id("incident");
  spdlog::error("internal error incident={} detail=\"{}\"", incident, printable(status.message()));
  return "internal error (" + incident + ": quote it to riccatid's operator, whose log has it): " +
         printable(status.message());
}

}  // namespace

grpc::Status to_grpc(const Status& status) {
  if (status.is_ok()) return grpc::Status::OK;
  return {static_cast<grpc::StatusCode>(status.code()), client_message(status)};
}

v1::Error to_error(const Status& status) {
  v1::Error e;
  e.set_code(static_cast<v1::Code>(status.code()));  // the same numbers
  e.set_message(client_message(status));
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

v1::Covariance to_covariance(const Eigen::MatrixXd& m) {
  v1::Covariance out;
  if (m.rows() == m.cols() && m.isDiagonal(0.0)) {
    copy_values(m.diagonal(), out.mutable_diagonal()->mutable_values());
  } else {
    *out.mutable_full() = to_matrix(m);
  }
  return out;
}

Result<Eigen::MatrixXd> from_matrix(const v1::Matrix& m, const std::string& field) {
  // Two 32-bit counts: their product fits 64 unsigned bits (it need not fit
  // 63: a 4e9 x 4e9 matrix needs 1.6e19 values).
  const std::uint64_t expected = static_cast<std::uint64_t>(m.rows()) * static_cast<std::uint64_t>(m.cols());
  if (expected != static_cast<std::uint64_t>(m.values_size())) {
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
