// Screening of MAT files before matio reads them.
//
// matio believes what a file's headers say: it allocates for a variable's
// dimensions, a cell's elements or a struct's fields before it reads a value,
// and it reads a truncated file without complaint. An upload can say
// anything, so riccati gives matio only a file it has walked first:
// screen_mat_file checks the top-level structure of a level 5 MAT file (what
// MATLAB writes with -v6 and -v7, compressed or not) and keeps only the
// variables asked for, each checked to be a real 2-D double matrix whose
// values fit in the file. Everything else (a struct of notes, a cell of
// labels) is dropped unread.
//
// Level 4 and v7.3 (HDF5) files are refused: level 4 cannot be told apart
// from arbitrary bytes, and HDF5 is a large parser that was never meant for
// untrusted input.
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "engine/status.hpp"

namespace riccati {

struct ScreenedMatFile {
  std::string bytes;               // the file's 128-byte header and the kept variables, byte for byte
  std::vector<std::string> found;  // the names of the kept variables, in file order
};

// `bytes` is the whole file and `source` names it in messages. Of each
// wanted name the first variable is kept. `max_value_bytes` bounds the
// values the kept variables claim (8 bytes each, as matio will allocate
// them): past it, RESOURCE_EXHAUSTED. Anything malformed is INVALID_ARGUMENT
// with the byte offset of the variable at fault.
Result<ScreenedMatFile> screen_mat_file(std::string_view bytes, const std::vector<std::string>& wanted,
                                        const std::string& source,
                                        std::uint64_t max_value_bytes = std::numeric_limits<std::uint64_t>::max());

}  // namespace riccati
