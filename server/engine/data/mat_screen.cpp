#include "engine/data/mat_screen.hpp"

#include <zlib.h>

#include <algorithm>
#include <array>
#include <cstddef>

namespace riccati {
namespace {

// Level 5 layout (MathWorks, "MAT-File Format"): a 128-byte header, then
// data elements, each an 8-byte tag (type, byte count) and its data, or a
// "small element" of 8 bytes whose count sits in the upper half of the
// tag's first word. A variable is an miMATRIX element, or an miCOMPRESSED
// one holding a zlib stream of an miMATRIX element.
constexpr std::size_t kFileHeaderSize = 128;
constexpr std::size_t kTagSize = 8;
constexpr std::uint32_t kMiInt8 = 1, kMiInt32 = 5, kMiUInt32 = 6, kMiMatrix = 14, kMiCompressed = 15;
constexpr std::uint32_t kDoubleClass = 6;
constexpr std::uint32_t kLogicalFlag = 0x0200, kComplexFlag = 0x0800;  // in the array flags
constexpr std::size_t kMaxRank = 32;
constexpr std::size_t kMaxNameRead = 64;  // a longer name is not one we want
// The start of a matrix element's data that holds all we check: array flags
// (16 bytes), dimensions (8 + up to 4 per dimension), name (8 + its bytes).
constexpr std::size_t kMatrixHeadSize = 16 + 8 + 4 * kMaxRank + 8 + kMaxNameRead;
// Deflate shrinks data at most about 1032:1.
constexpr std::uint64_t kMaxCompressionRatio = 1032;

// The 32-bit word at `at` (at + 4 <= bytes.size()), in the file's byte order.
std::uint32_t read_u32(std::string_view bytes, std::size_t at, bool little_endian) {
  const auto byte = [&](std::size_t k) { return static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[at + k])); };
  return little_endian ? byte(0) | byte(1) << 8 | byte(2) << 16 | byte(3) << 24
                       : byte(3) | byte(2) << 8 | byte(1) << 16 | byte(0) << 24;
}

std::size_t padded_to_8(std::size_t n) { return (n + 7) / 8 * 8; }

// The first `want` bytes that `compressed` inflates to; fewer if the stream
// ends or turns out corrupt before.
std::string inflate_prefix(std::string_view compressed, std::size_t want) {
  std::string out(want, '\0');
  z_stream z{};
  if (inflateInit(&z) != Z_OK) return "";
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(compressed.data()));
  z.avail_in = static_cast<uInt>(compressed.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data());
  z.avail_out = static_cast<uInt>(want);
  while (z.avail_out > 0 && inflate(&z, Z_SYNC_FLUSH) == Z_OK) {
  }
  out.resize(want - z.avail_out);
  inflateEnd(&z);
  return out;
}

struct MatrixHead {
  std::uint32_t flags = 0;  // the array flags' first word: the class in its low byte, then flag bits
  std::vector<std::uint32_t> dims;
  std::string name;  // empty unless an miINT8 name of at most kMaxNameRead bytes

  std::uint32_t class_code() const { return flags & 0xff; }
};

const char* class_name(const MatrixHead& head) {
  if ((head.flags & kLogicalFlag) != 0) return "logical";
  static constexpr std::array<const char*, 18> kNames = {
      "unknown class", "cell",  "struct", "object", "char",   "sparse", "double", "single",          "int8",
      "uint8",         "int16", "uint16", "int32",  "uint32", "int64",  "uint64", "function handle", "opaque object"};
  return head.class_code() < kNames.size() ? kNames[head.class_code()] : "unknown class";
}

std::string dims_text(const std::vector<std::uint32_t>& dims) {
  std::string text;
  for (std::size_t k = 0; k < dims.size(); ++k) text += (k > 0 ? " x " : "") + std::to_string(dims[k]);
  return text;
}

// Reads the head of a matrix element's data into `out`. `head` holds the
// first min(size, kMatrixHeadSize) bytes, `size` being the byte count the
// element's tag claims. Returns what is wrong with it, or nothing.
std::string read_matrix_head(std::string_view head, std::uint64_t size, bool little_endian, MatrixHead& out) {
  const auto u32 = [&](std::size_t at) { return read_u32(head, at, little_endian); };
  if (head.size() < 24) return "its header is cut short";
  if (u32(0) != kMiUInt32 || u32(4) != 8) return "its array flags are malformed";
  out.flags = u32(8);
  const std::uint32_t dims_type = u32(16), dims_size = u32(20);
  if (dims_type != kMiInt32 || dims_size % 4 != 0 || dims_size < 8 || dims_size > 4 * kMaxRank) {
    return "its dimensions are malformed";
  }
  // head.size() < kMatrixHeadSize means that head is the whole element.
  if (24 + dims_size > head.size()) return "its dimensions run past its end";
  for (std::size_t k = 0; k < dims_size / 4; ++k) {
    const std::uint32_t dim = u32(24 + 4 * k);
    if (dim > static_cast<std::uint32_t>(std::numeric_limits<std::int32_t>::max())) return "it has a negative dimension";
    out.dims.push_back(dim);
  }

  const std::size_t name_at = 24 + padded_to_8(dims_size);
  if (name_at + kTagSize > head.size()) return "its name runs past its end";
  const std::uint32_t name_tag = u32(name_at);
  std::uint32_t name_type = name_tag & 0xffff, name_size = name_tag >> 16;
  std::size_t name_data_at = name_at + 4;
  if (name_size == 0) {  // a full tag, not a small element
    name_type = name_tag;
    name_size = u32(name_at + 4);
    name_data_at = name_at + kTagSize;
  } else if (name_size > 4) {
    return "its name is malformed";
  }
  if (name_data_at + name_size > size) return "its name runs past its end";
  if (name_type == kMiInt8 && name_size <= kMaxNameRead && name_data_at + name_size <= head.size()) {
    out.name.assign(head.substr(name_data_at, name_size));
  }
  return "";
}

// A variable riccati reads must be a real 2-D double matrix whose values fit
// in the `capacity` bytes that its element holds or may inflate to.
Status check_wanted(const MatrixHead& head, std::uint64_t capacity, const std::string& what) {
  if (head.class_code() != kDoubleClass || (head.flags & (kComplexFlag | kLogicalFlag)) != 0) {
    return invalid_argument(what + " must be a real double matrix, found " +
                            ((head.flags & kComplexFlag) != 0 ? "complex " : "") + class_name(head));
  }
  if (head.dims.size() != 2) return invalid_argument(what + " must be a 2-D matrix, found " + dims_text(head.dims));
  const std::uint64_t count = std::uint64_t{head.dims[0]} * head.dims[1];  // < 2^62
  if (count > capacity / sizeof(double)) {
    return invalid_argument(what + " claims to be " + dims_text(head.dims) +
                            ", more than the file can hold (is it corrupt?)");
  }
  return Status::ok();
}

}  // namespace

Result<ScreenedMatFile> screen_mat_file(std::string_view bytes, const std::vector<std::string>& wanted,
                                        const std::string& source, std::uint64_t max_value_bytes) {
  if (bytes.empty()) return invalid_argument(source + ": the file is empty");
  const std::string not_read = "; riccati reads level 5 MAT files, which MATLAB writes with -v7 and -v6";
  if (bytes.size() < kFileHeaderSize) return invalid_argument(source + ": not a MAT file (shorter than its header)" + not_read);
  const std::string_view byte_order = bytes.substr(126, 2);
  const bool little_endian = byte_order == "IM";
  if (!little_endian && byte_order != "MI") {
    return invalid_argument(source + ": not a MAT file of level 5 (no byte-order mark at byte 126)" + not_read);
  }
  const auto version_byte = [&](std::size_t k) { return static_cast<unsigned>(static_cast<unsigned char>(bytes[124 + k])); };
  const unsigned version = little_endian ? version_byte(0) | version_byte(1) << 8 : version_byte(1) | version_byte(0) << 8;
  if (version == 0x0200) {
    return invalid_argument(source + ": a MAT file of version 7.3 (HDF5), which riccati does not read: save it with -v7 " +
                            "(save(file, 'T', 'U', 'Y', '-v7')) or upload CSV");
  }
  if (version != 0x0100) return invalid_argument(source + ": a MAT file of unknown version " + std::to_string(version) + not_read);

  ScreenedMatFile screened;
  screened.bytes.assign(bytes.substr(0, kFileHeaderSize));
  std::uint64_t value_bytes = 0;
  // Fewer than 8 bytes after the last element are padding; matio ignores them too.
  for (std::size_t offset = kFileHeaderSize; bytes.size() - offset >= kTagSize;) {
    const std::string_view rest = bytes.substr(offset);
    const std::uint32_t type = read_u32(rest, 0, little_endian);
    const bool small_element = (type >> 16) != 0;
    const std::uint64_t element_size = small_element ? kTagSize : kTagSize + std::uint64_t{read_u32(rest, 4, little_endian)};
    const std::string at_offset = "the variable at byte " + std::to_string(offset);
    if (element_size > rest.size()) {
      return invalid_argument(source + ": the file is truncated or corrupt (" + at_offset + " needs " +
                              std::to_string(element_size) + " bytes, only " + std::to_string(rest.size()) + " remain)");
    }
    const std::string_view element = rest.substr(0, element_size);
    offset += element_size;
    if (small_element || (type != kMiMatrix && type != kMiCompressed)) continue;  // not a variable

    const auto corrupt = [&](const std::string& problem) {
      return invalid_argument(source + ": the file is corrupt (" + at_offset + ": " + problem + ")");
    };
    std::string inflated;    // of a compressed variable: the start of its miMATRIX element
    std::string_view head;   // the start of the matrix element's data
    std::uint64_t size = 0;  // the byte count of the matrix element's data
    if (type == kMiMatrix) {
      size = element_size - kTagSize;
      head = element.substr(kTagSize, std::min<std::uint64_t>(size, kMatrixHeadSize));
    } else {
      const std::string_view compressed = element.substr(kTagSize);
      inflated = inflate_prefix(compressed, kTagSize + kMatrixHeadSize);
      if (inflated.size() < kTagSize) return corrupt("its compressed data is corrupt");
      if (read_u32(inflated, 0, little_endian) != kMiMatrix) return corrupt("its compressed data is not a variable");
      size = read_u32(inflated, 4, little_endian);
      if (size > compressed.size() * kMaxCompressionRatio) {
        return corrupt("it claims " + std::to_string(size) + " bytes, more than " + std::to_string(compressed.size()) +
                       " compressed bytes can hold");
      }
      const std::size_t head_size = std::min<std::uint64_t>(size, kMatrixHeadSize);
      if (inflated.size() < kTagSize + head_size) return corrupt("its compressed data is corrupt or cut short");
      head = std::string_view(inflated).substr(kTagSize, head_size);
    }
    MatrixHead matrix;
    if (const std::string problem = read_matrix_head(head, size, little_endian, matrix); !problem.empty()) {
      return corrupt(problem);
    }
    const bool is_wanted = std::find(wanted.begin(), wanted.end(), matrix.name) != wanted.end();
    const bool is_first = std::find(screened.found.begin(), screened.found.end(), matrix.name) == screened.found.end();
    if (!is_wanted || !is_first) continue;

    RICCATI_RETURN_IF_ERROR(check_wanted(matrix, size, source + ": variable \"" + matrix.name + "\""));
    value_bytes += std::uint64_t{matrix.dims[0]} * matrix.dims[1] * sizeof(double);  // each <= size < 2^43
    if (value_bytes > max_value_bytes) {
      return Status(StatusCode::kResourceExhausted,
                    source + ": its variables claim " + std::to_string(value_bytes) + " bytes of values (\"" +
                        matrix.name + "\" is " + dims_text(matrix.dims) + "), more than the " +
                        std::to_string(max_value_bytes) + " allowed");
    }
    screened.bytes.append(element);
    screened.found.push_back(matrix.name);
  }
  return screened;
}

}  // namespace riccati
