// The HTTP API's JSON writer against protobuf's own printer: every message
// of the API, filled at random (every field kind, NaN, infinities, -0,
// 64-bit extremes, strings needing escapes, bytes, timestamps, maps, unset
// and empty fields), written both ways and compared as parsed JSON.
#include <gtest/gtest.h>
#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>
#include <google/protobuf/util/json_util.h>

#include <cmath>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "riccati/v1/datasets.pb.h"
#include "riccati/v1/jobs.pb.h"
#include "riccati/v1/models.pb.h"
#include "riccati/v1/sessions.pb.h"
#include "service/http/json_writer.hpp"

namespace riccati::service {
namespace {

using google::protobuf::Descriptor;
using google::protobuf::FieldDescriptor;
using google::protobuf::Message;
using google::protobuf::Reflection;

class Filler {
 public:
  explicit Filler(unsigned seed) : rng_(seed) {}

  void fill(Message& m, int depth) {
    const Descriptor* d = m.GetDescriptor();
    if (d->full_name() == "google.protobuf.Timestamp") {
      const Reflection* r = m.GetReflection();
      r->SetInt64(&m, d->FindFieldByName("seconds"), pick<std::int64_t>({0, 1, 1'700'000'000, 4'102'444'800}));
      r->SetInt32(&m, d->FindFieldByName("nanos"), pick<std::int32_t>({0, 5'000'000, 123'000, 7}));
      return;
    }
    const Reflection* r = m.GetReflection();
    for (int i = 0; i < d->field_count(); ++i) {
      const FieldDescriptor* f = d->field(i);
      if (chance(0.25)) continue;  // left unset: zero, empty, or absent
      if (f->cpp_type() == FieldDescriptor::CPPTYPE_MESSAGE && depth >= 3) continue;
      if (f->is_repeated()) {
        const int n = static_cast<int>(rng_() % 4);
        for (int k = 0; k < n; ++k) add(m, r, f, depth);
      } else {
        set(m, r, f, depth);
      }
    }
  }

 private:
  template <typename T>
  T pick(std::initializer_list<T> values) {
    return *(values.begin() + rng_() % values.size());
  }
  bool chance(double p) { return std::uniform_real_distribution<double>(0, 1)(rng_) < p; }
  double real() {
    return pick<double>({0.0, -0.0, 1.0, -2.5, 0.1, 1e-310, 1e300, 123456789.123456789, 2.0 / 3.0,
                         std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(),
                         -std::numeric_limits<double>::infinity(),
                         std::uniform_real_distribution<double>(-1e6, 1e6)(rng_)});
  }
  std::string text() {
    return pick<std::string>({"", "two_tank", "h1", "quote \" and backslash \\", "line\nbreak\ttab",
                              "<script>alert(1)</script>", "\x01\x1f control", "utf-8: \xc3\xa9 \xe2\x82\xac"});
  }
  int enum_number(const FieldDescriptor* f) {
    const auto* e = f->enum_type();
    return e->value(static_cast<int>(rng_() % static_cast<unsigned>(e->value_count())))->number();
  }

  void set(Message& m, const Reflection* r, const FieldDescriptor* f, int depth) {
    switch (f->cpp_type()) {
      case FieldDescriptor::CPPTYPE_INT32: r->SetInt32(&m, f, pick<std::int32_t>({0, -7, 42, INT32_MAX, INT32_MIN})); break;
      case FieldDescriptor::CPPTYPE_UINT32: r->SetUInt32(&m, f, pick<std::uint32_t>({0, 7, UINT32_MAX})); break;
      case FieldDescriptor::CPPTYPE_INT64: r->SetInt64(&m, f, pick<std::int64_t>({0, -3, INT64_MAX, INT64_MIN})); break;
      case FieldDescriptor::CPPTYPE_UINT64: r->SetUInt64(&m, f, pick<std::uint64_t>({0, 3, UINT64_MAX})); break;
      case FieldDescriptor::CPPTYPE_DOUBLE: r->SetDouble(&m, f, real()); break;
      case FieldDescriptor::CPPTYPE_FLOAT: r->SetFloat(&m, f, static_cast<float>(real())); break;
      case FieldDescriptor::CPPTYPE_BOOL: r->SetBool(&m, f, chance(0.5)); break;
      case FieldDescriptor::CPPTYPE_ENUM: r->SetEnumValue(&m, f, enum_number(f)); break;
      case FieldDescriptor::CPPTYPE_STRING:
        r->SetString(&m, f, f->type() == FieldDescriptor::TYPE_BYTES ? std::string("\x00\xff\x10 b", 5) : text());
        break;
      case FieldDescriptor::CPPTYPE_MESSAGE: fill(*r->MutableMessage(&m, f), depth + 1); break;
    }
  }
  void add(Message& m, const Reflection* r, const FieldDescriptor* f, int depth) {
    switch (f->cpp_type()) {
      case FieldDescriptor::CPPTYPE_INT32: r->AddInt32(&m, f, pick<std::int32_t>({0, -7, 42})); break;
      case FieldDescriptor::CPPTYPE_UINT32: r->AddUInt32(&m, f, pick<std::uint32_t>({0, 7, UINT32_MAX})); break;
      case FieldDescriptor::CPPTYPE_INT64: r->AddInt64(&m, f, pick<std::int64_t>({0, INT64_MIN})); break;
      case FieldDescriptor::CPPTYPE_UINT64: r->AddUInt64(&m, f, pick<std::uint64_t>({1, UINT64_MAX})); break;
      case FieldDescriptor::CPPTYPE_DOUBLE: r->AddDouble(&m, f, real()); break;
      case FieldDescriptor::CPPTYPE_FLOAT: r->AddFloat(&m, f, static_cast<float>(real())); break;
      case FieldDescriptor::CPPTYPE_BOOL: r->AddBool(&m, f, chance(0.5)); break;
      case FieldDescriptor::CPPTYPE_ENUM: r->AddEnumValue(&m, f, enum_number(f)); break;
      case FieldDescriptor::CPPTYPE_STRING: r->AddString(&m, f, text()); break;
      case FieldDescriptor::CPPTYPE_MESSAGE: fill(*r->AddMessage(&m, f), depth + 1); break;
    }
  }

  std::mt19937 rng_;
};

// Every message type declared in the API's files.
std::vector<const Descriptor*> api_messages() {
  std::vector<const Descriptor*> out;
  for (const auto* file : {v1::Job::descriptor()->file(), v1::DatasetInfo::descriptor()->file(),
                           v1::ModelInfo::descriptor()->file(), v1::SessionInfo::descriptor()->file()}) {
    std::vector<const google::protobuf::FileDescriptor*> files{file};
    for (int i = 0; i < file->dependency_count(); ++i) {
      if (file->dependency(i)->package() == "riccati.v1") files.push_back(file->dependency(i));
    }
    for (const auto* f : files) {
      for (int i = 0; i < f->message_type_count(); ++i) {
        const Descriptor* d = f->message_type(i);
        if (std::find(out.begin(), out.end(), d) == out.end()) out.push_back(d);
      }
    }
  }
  return out;
}

TEST(JsonWriter, EveryApiMessageIsWrittenAsProtobufsPrinterWritesIt) {
  const std::vector<const Descriptor*> types = api_messages();
  ASSERT_GT(types.size(), 30u);
  int compared = 0;
  for (const Descriptor* d : types) {
    const Message* prototype = google::protobuf::MessageFactory::generated_factory()->GetPrototype(d);
    ASSERT_NE(prototype, nullptr) << d->full_name();
    for (unsigned seed = 0; seed < 20; ++seed) {
      std::unique_ptr<Message> m(prototype->New());
      if (seed > 0) Filler(seed * 7919 + static_cast<unsigned>(compared)).fill(*m, 0);  // seed 0: all unset
      google::protobuf::util::JsonPrintOptions options;
      options.always_print_primitive_fields = true;
      std::string reference;
      ASSERT_TRUE(google::protobuf::util::MessageToJsonString(*m, &reference, options).ok()) << d->full_name();
      const std::string ours = message_to_json(*m);
      const auto parsed = nlohmann::json::parse(ours, nullptr, /*allow_exceptions=*/false);
      ASSERT_FALSE(parsed.is_discarded()) << d->full_name() << ": not JSON: " << ours;
      EXPECT_EQ(parsed, nlohmann::json::parse(reference)) << d->full_name() << "\nours:     " << ours
                                                           << "\nprotobuf: " << reference;
      ++compared;
    }
  }
  RecordProperty("messages_compared", compared);
}

}  // namespace
}  // namespace riccati::service
