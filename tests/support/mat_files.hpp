// Crafted level 5 MAT files (little-endian) for the cases the fixtures do not
// cover: wrong classes, corrupt headers, cells and structs beside the data,
// compressed variables. Written byte by byte from MathWorks' "MAT-File
// Format", so that what riccati reads is not checked by matio against itself.
#pragma once

#include <zlib.h>

#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

namespace riccati::testing {

struct MatVariable {
  std::string name;
  std::vector<std::int32_t> dims;
  std::vector<double> values;  // column-major
  enum class Type { kDouble, kInt32, kComplexDouble } type = Type::kDouble;
};

namespace mat5 {

constexpr std::uint32_t miINT8 = 1, miINT32 = 5, miUINT32 = 6, miDOUBLE = 9, miMATRIX = 14, miCOMPRESSED = 15;
constexpr std::uint32_t mxCELL_CLASS = 1, mxSTRUCT_CLASS = 2, mxDOUBLE_CLASS = 6, mxINT32_CLASS = 12;
constexpr std::uint32_t kComplexFlag = 0x0800;

inline void append_u32(std::string& out, std::uint32_t v) {
  for (int k = 0; k < 4; ++k) out.push_back(static_cast<char>(v >> (8 * k) & 0xff));
}

// A data element: its tag, its data, padding to 8 bytes.
inline std::string element(std::uint32_t type, const std::string& data) {
  std::string out;
  append_u32(out, type);
  append_u32(out, static_cast<std::uint32_t>(data.size()));
  out += data;
  out.append((8 - data.size() % 8) % 8, '\0');
  return out;
}

template <typename T>
std::string raw(const std::vector<T>& values) {
  std::string bytes(values.size() * sizeof(T), '\0');
  if (!values.empty()) std::memcpy(bytes.data(), values.data(), bytes.size());
  return bytes;
}

// The array flags, dimensions and name that every matrix element starts with.
inline std::string matrix_head(std::uint32_t flags, const std::vector<std::int32_t>& dims, const std::string& name) {
  std::string flag_words;
  append_u32(flag_words, flags);
  append_u32(flag_words, 0);
  return element(miUINT32, flag_words) + element(miINT32, raw(dims)) + element(miINT8, name);
}

inline std::string numeric_matrix(const MatVariable& var) {
  const bool is_int = var.type == MatVariable::Type::kInt32;
  const bool is_complex = var.type == MatVariable::Type::kComplexDouble;
  std::string body =
      matrix_head((is_int ? mxINT32_CLASS : mxDOUBLE_CLASS) | (is_complex ? kComplexFlag : 0), var.dims, var.name);
  if (is_int) {
    body += element(miINT32, raw(std::vector<std::int32_t>(var.values.begin(), var.values.end())));
  } else {
    body += element(miDOUBLE, raw(var.values));
  }
  if (is_complex) body += element(miDOUBLE, raw(std::vector<double>(var.values.size(), 0.0)));
  return element(miMATRIX, body);
}

// A cell array of the given dimensions; `contents` are its elements' bytes,
// which a well-formed cell has one of for each element.
inline std::string cell(const std::string& name, const std::vector<std::int32_t>& dims, const std::string& contents = "") {
  return element(miMATRIX, matrix_head(mxCELL_CLASS, dims, name) + contents);
}

// A 1 x 1 struct with one field, `field`, holding an empty double matrix.
inline std::string struct_with_empty_field(const std::string& name, const std::string& field) {
  std::string body = matrix_head(mxSTRUCT_CLASS, {1, 1}, name);
  constexpr std::uint32_t kFieldNameLength = 32;
  append_u32(body, 4u << 16 | miINT32);  // a small element: the field name length
  append_u32(body, kFieldNameLength);
  std::string names(kFieldNameLength, '\0');
  names.replace(0, field.size(), field);
  body += element(miINT8, names);
  body += element(miMATRIX, matrix_head(mxDOUBLE_CLASS, {0, 0}, "") + element(miDOUBLE, ""));
  return element(miMATRIX, body);
}

// An element as MATLAB's -v7 writes it: miCOMPRESSED around a zlib stream.
inline std::string compressed(const std::string& matrix_element) {
  uLongf size = compressBound(static_cast<uLong>(matrix_element.size()));
  std::string deflated(size, '\0');
  if (compress2(reinterpret_cast<Bytef*>(deflated.data()), &size, reinterpret_cast<const Bytef*>(matrix_element.data()),
                static_cast<uLong>(matrix_element.size()), Z_BEST_COMPRESSION) != Z_OK) {
    throw std::runtime_error("zlib compress2 failed");
  }
  deflated.resize(size);
  // Unlike other elements, a compressed one is not padded to 8 bytes.
  std::string out;
  append_u32(out, miCOMPRESSED);
  append_u32(out, static_cast<std::uint32_t>(deflated.size()));
  return out + deflated;
}

inline std::string file_header() {
  std::string header = "MATLAB 5.0 MAT-file, written by riccati's tests";
  header.resize(116, ' ');
  header.append(8, '\0');                 // no subsystem data
  header.append("\x00\x01" "IM", 4);      // version 0x0100, little-endian
  return header;
}

}  // namespace mat5

// A whole file: the header, then `before` (raw elements), then the variables.
inline std::string mat5_file(const std::vector<MatVariable>& variables, bool compress = false,
                             const std::string& before = "") {
  std::string file = mat5::file_header() + before;
  for (const MatVariable& var : variables) {
    file += compress ? mat5::compressed(mat5::numeric_matrix(var)) : mat5::numeric_matrix(var);
  }
  return file;
}

}  // namespace riccati::testing
