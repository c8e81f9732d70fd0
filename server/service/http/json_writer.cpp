#include "service/http/json_writer.hpp"

#include <google/protobuf/descriptor.h>
#include <google/protobuf/reflection.h>
#include <google/protobuf/util/json_util.h>
#include <spdlog/spdlog.h>

#include <charconv>
#include <cmath>
#include <cstdint>
#include <ctime>
#include <string_view>

namespace riccati::service {
namespace {

using google::protobuf::Descriptor;
using google::protobuf::FieldDescriptor;
using google::protobuf::Message;
using google::protobuf::Reflection;

void write_escaped(std::string_view s, std::string& out) {
  out += '"';
  for (const char c : s) {
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\r': out += "\\r"; break;
      case '\t': out += "\\t"; break;
      case '\b': out += "\\b"; break;
      case '\f': out += "\\f"; break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          static constexpr char kHex[] = "0123456789abcdef";
          out += "\\u00";
          out += kHex[(c >> 4) & 0xf];
          out += kHex[c & 0xf];
        } else {
          out += c;
        }
    }
  }
  out += '"';
}

void write_base64(std::string_view bytes, std::string& out) {
  static constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  out += '"';
  std::size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const unsigned v = (static_cast<unsigned char>(bytes[i]) << 16) | (static_cast<unsigned char>(bytes[i + 1]) << 8) |
                       static_cast<unsigned char>(bytes[i + 2]);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += kAlphabet[v & 63];
  }
  if (i + 1 == bytes.size()) {
    const unsigned v = static_cast<unsigned char>(bytes[i]) << 16;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == bytes.size()) {
    const unsigned v = (static_cast<unsigned char>(bytes[i]) << 16) | (static_cast<unsigned char>(bytes[i + 1]) << 8);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += '=';
  }
  out += '"';
}

template <typename T>
void write_number(T v, std::string& out) {
  char buffer[64];
  const auto [end, ec] = std::to_chars(buffer, buffer + sizeof buffer, v);
  out.append(buffer, ec == std::errc() ? end : buffer);
}

// Doubles and floats: the shortest text that reads back to the same value;
// NaN and the infinities as the strings the JSON mapping names.
template <typename T>
void write_real(T v, std::string& out) {
  if (std::isnan(v)) {
    out += "\"NaN\"";
  } else if (std::isinf(v)) {
    out += v > 0 ? "\"Infinity\"" : "\"-Infinity\"";
  } else {
    write_number(v, out);
  }
}

// google.protobuf.Timestamp: RFC 3339 in UTC, with 0, 3, 6 or 9 digits of
// fraction as protobuf writes them.
bool write_timestamp(const Message& m, std::string& out) {
  const Descriptor* d = m.GetDescriptor();
  const Reflection* r = m.GetReflection();
  const std::int64_t seconds = r->GetInt64(m, d->FindFieldByName("seconds"));
  const std::int32_t nanos = r->GetInt32(m, d->FindFieldByName("nanos"));
  // 0001-01-01 to 9999-12-31, and nanos in [0, 1e9): what the mapping allows.
  if (seconds < -62135596800 || seconds > 253402300799 || nanos < 0 || nanos > 999999999) return false;
  const auto t = static_cast<std::time_t>(seconds);
  std::tm tm{};
  if (gmtime_r(&t, &tm) == nullptr) return false;
  char buffer[64];
  std::size_t n = std::strftime(buffer, sizeof buffer, "%Y-%m-%dT%H:%M:%S", &tm);
  if (tm.tm_year + 1900 < 1000) {  // strftime's %Y does not pad years before 1000
    n = static_cast<std::size_t>(std::snprintf(buffer, sizeof buffer, "%04d-%02d-%02dT%02d:%02d:%02d",
                                               tm.tm_year + 1900, tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min,
                                               tm.tm_sec));
  }
  out += '"';
  out.append(buffer, n);
  if (nanos != 0) {
    char fraction[16];
    if (nanos % 1000000 == 0) {
      std::snprintf(fraction, sizeof fraction, ".%03d", nanos / 1000000);
    } else if (nanos % 1000 == 0) {
      std::snprintf(fraction, sizeof fraction, ".%06d", nanos / 1000);
    } else {
      std::snprintf(fraction, sizeof fraction, ".%09d", nanos);
    }
    out += fraction;
  }
  out += "Z\"";
  return true;
}

void write_message(const Message& m, std::string& out);

// Value `index` of a repeated field, or the value of a singular one (index < 0).
void write_value(const Message& m, const Reflection* r, const FieldDescriptor* f, int index, std::string& out) {
  const bool rep = index >= 0;
  switch (f->cpp_type()) {
    case FieldDescriptor::CPPTYPE_INT32:
      write_number(rep ? r->GetRepeatedInt32(m, f, index) : r->GetInt32(m, f), out);
      break;
    case FieldDescriptor::CPPTYPE_UINT32:
      write_number(rep ? r->GetRepeatedUInt32(m, f, index) : r->GetUInt32(m, f), out);
      break;
    case FieldDescriptor::CPPTYPE_INT64:  // as strings: JavaScript's numbers hold 53 bits
      out += '"';
      write_number(rep ? r->GetRepeatedInt64(m, f, index) : r->GetInt64(m, f), out);
      out += '"';
      break;
    case FieldDescriptor::CPPTYPE_UINT64:
      out += '"';
      write_number(rep ? r->GetRepeatedUInt64(m, f, index) : r->GetUInt64(m, f), out);
      out += '"';
      break;
    case FieldDescriptor::CPPTYPE_DOUBLE:
      write_real(rep ? r->GetRepeatedDouble(m, f, index) : r->GetDouble(m, f), out);
      break;
    case FieldDescriptor::CPPTYPE_FLOAT:
      write_real(rep ? r->GetRepeatedFloat(m, f, index) : r->GetFloat(m, f), out);
      break;
    case FieldDescriptor::CPPTYPE_BOOL:
      out += (rep ? r->GetRepeatedBool(m, f, index) : r->GetBool(m, f)) ? "true" : "false";
      break;
    case FieldDescriptor::CPPTYPE_ENUM: {
      const int number = rep ? r->GetRepeatedEnumValue(m, f, index) : r->GetEnumValue(m, f);
      if (const auto* value = f->enum_type()->FindValueByNumber(number)) {
        out += '"';
        out += value->name();
        out += '"';
      } else {
        write_number(number, out);  // a value this build does not know
      }
      break;
    }
    case FieldDescriptor::CPPTYPE_STRING: {
      std::string scratch;
      const std::string& s = rep ? r->GetRepeatedStringReference(m, f, index, &scratch)
                                 : r->GetStringReference(m, f, &scratch);
      if (f->type() == FieldDescriptor::TYPE_BYTES) {
        write_base64(s, out);
      } else {
        write_escaped(s, out);
      }
      break;
    }
    case FieldDescriptor::CPPTYPE_MESSAGE:
      write_message(rep ? r->GetRepeatedMessage(m, f, index) : r->GetMessage(m, f), out);
      break;
  }
}

// A map's key, always a JSON string.
void write_map_key(const Message& entry, const FieldDescriptor* key, std::string& out) {
  const Reflection* r = entry.GetReflection();
  std::string text;
  switch (key->cpp_type()) {
    case FieldDescriptor::CPPTYPE_STRING: text = r->GetString(entry, key); break;
    case FieldDescriptor::CPPTYPE_BOOL: text = r->GetBool(entry, key) ? "true" : "false"; break;
    case FieldDescriptor::CPPTYPE_INT32: text = std::to_string(r->GetInt32(entry, key)); break;
    case FieldDescriptor::CPPTYPE_UINT32: text = std::to_string(r->GetUInt32(entry, key)); break;
    case FieldDescriptor::CPPTYPE_INT64: text = std::to_string(r->GetInt64(entry, key)); break;
    case FieldDescriptor::CPPTYPE_UINT64: text = std::to_string(r->GetUInt64(entry, key)); break;
    default: break;  // no other key types exist
  }
  write_escaped(text, out);
}

// protobuf's own printer, for the well-known types this writer does not
// spell out (none of the API's messages use them today).
void write_with_protobuf(const Message& m, std::string& out) {
  std::string json;
  const auto status = google::protobuf::util::MessageToJsonString(m, &json);
  if (!status.ok()) {
    spdlog::error("cannot write {} as JSON: {}", m.GetTypeName(), status.ToString());
    json = "null";
  }
  out += json;
}

void write_message(const Message& m, std::string& out) {
  const Descriptor* d = m.GetDescriptor();
  if (d->file()->package() == "google.protobuf") {
    if (d->full_name() == "google.protobuf.Timestamp" && write_timestamp(m, out)) return;
    write_with_protobuf(m, out);
    return;
  }
  const Reflection* r = m.GetReflection();
  out += '{';
  bool first = true;
  for (int i = 0; i < d->field_count(); ++i) {
    const FieldDescriptor* f = d->field(i);
    // Fields with presence (messages, oneof members, `optional`) when set;
    // the others always, zeros and empty lists included.
    if (!f->is_repeated() && f->has_presence() && !r->HasField(m, f)) continue;
    if (!first) out += ',';
    first = false;
    write_escaped(f->json_name(), out);
    out += ':';
    if (f->is_map()) {
      const FieldDescriptor* key = f->message_type()->map_key();
      const FieldDescriptor* value = f->message_type()->map_value();
      out += '{';
      const int n = r->FieldSize(m, f);
      for (int k = 0; k < n; ++k) {
        if (k > 0) out += ',';
        const Message& entry = r->GetRepeatedMessage(m, f, k);
        write_map_key(entry, key, out);
        out += ':';
        write_value(entry, entry.GetReflection(), value, -1, out);
      }
      out += '}';
    } else if (f->is_repeated() && f->cpp_type() == FieldDescriptor::CPPTYPE_DOUBLE) {
      // Most of a result's bytes: its traces. Read through one reference to
      // the field, not a lookup of the field's place per value.
      out += '[';
      const google::protobuf::RepeatedFieldRef<double> values = r->GetRepeatedFieldRef<double>(m, f);
      for (int k = 0; k < values.size(); ++k) {
        if (k > 0) out += ',';
        write_real(values.Get(k), out);
      }
      out += ']';
    } else if (f->is_repeated()) {
      out += '[';
      const int n = r->FieldSize(m, f);
      for (int k = 0; k < n; ++k) {
        if (k > 0) out += ',';
        write_value(m, r, f, k, out);
      }
      out += ']';
    } else {
      write_value(m, r, f, -1, out);
    }
  }
  out += '}';
}

}  // namespace

std::string message_to_json(const Message& message) {
  std::string out;
  out.reserve(message.ByteSizeLong() * 2 + 64);  // about twice the wire size for numbers: one allocation
  write_message(message, out);
  return out;
}

}  // namespace riccati::service
