// NumericRange / IndexRange (OPC 10000-4 §7.27, BNF in Annex A.3).
//
//   "6"          one element               "2:4"      elements 2..4 (first < second)
//   "1:2,0:3"    a block of a matrix       "1,1"      one element of a matrix
//
// Strings and ByteStrings are arrays of bytes for this purpose: a range applies to a scalar
// String/ByteString, and an array of them takes one more dimension that indexes the bytes
// of each element ("0:1,2:3" = elements 0..1, bytes 2..3 of each).
//
// Status codes: Bad_IndexRangeInvalid only for a string that does not follow the syntax;
// every other range that cannot be applied (lower bound out of bounds, wrong number of
// dimensions, a scalar that is not a String/ByteString, size mismatch on write) is
// Bad_IndexRangeNoData. An upper bound beyond the data yields the part that exists (read).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "ua/types/builtin.hpp"

namespace pnp::ua::server {

class NumericRange {
  public:
    struct Dimension {
        UInt32 min = 0;
        UInt32 max = 0;  // inclusive; == min for a single index
        UInt32 count() const { return max - min + 1; }
        bool operator==(const Dimension&) const = default;
    };

    NumericRange() = default;
    explicit NumericRange(std::vector<Dimension> dims) : dims_(std::move(dims)) {}

    // nullopt when the text is not a valid NumericRange. An empty string parses to an empty
    // range (= "not used").
    static std::optional<NumericRange> parse(std::string_view text);

    bool empty() const { return dims_.empty(); }
    const std::vector<Dimension>& dimensions() const { return dims_; }
    std::string toString() const;
    bool operator==(const NumericRange&) const = default;

  private:
    std::vector<Dimension> dims_;
};

// Selects the range of `value` into `out` (read). Good, or Bad_IndexRangeNoData.
StatusCode readRange(const Variant& value, const NumericRange& range, Variant& out);

// Replaces the range of `target` by `source` (write). `source` must hold exactly the selected
// number of elements of the same built-in type (a matrix source must have the range's
// shape). Good, Bad_TypeMismatch (element type differs) or Bad_IndexRangeNoData.
StatusCode writeRange(Variant& target, const NumericRange& range, const Variant& source);

}  // namespace pnp::ua::server
