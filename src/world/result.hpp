#pragma once

#include <string>

#include "base/result.hpp"

namespace pnp::world {

// Why loading a cell description failed. The code is for programs (and tests), the message
// ("FILE:LINE: problem") for people.
enum class ErrorCode {
    kUnreadable,     // file missing, not a regular file, or not readable
    kTooLarge,       // file (or text) above the size limit
    kSyntax,         // not YAML, or more than one YAML document
    kVersion,        // `pnp-cell` is not a version this loader reads
    kUnknownKey,     // a key the format does not have (typo protection), or a repeated key
    kMissingKey,     // a required key is absent
    kWrongType,      // e.g. a string where a number or a list is expected
    kOutOfRange,     // non-finite, non-positive size, joint outside its limits ...
    kDuplicateName,  // two things (of any kind) with the same name
    kUnknownName,    // a reference to a thing that does not exist (or of the wrong kind)
    kConflict,       // a tool in two places at start, two tools with one changer id
    kTooMany,        // a list above its bound
};

struct Error {
    ErrorCode code;
    std::string message;  // "FILE:LINE: problem" (no line for whole-file problems)
    int line = 0;         // 1-based; 0 when the problem is not at one line
};

// A value or an Error: nothing in this module throws past its API.
template <class T>
using Result = base::Result<T, Error>;

}  // namespace pnp::world
