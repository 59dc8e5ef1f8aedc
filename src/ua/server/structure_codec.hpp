// Dynamic structure codec: encodes and decodes the OPC UA Binary body of a structure whose
// layout is only known at run time, from its StructureDefinition (OPC 10000-3 §8.48,
// OPC 10000-6 §5.2.6/5.2.7). This is how structures defined in a NodeSet2 file loaded at run
// time go on the wire without generated code.
//
// A decoded structure is a list of (field name, Variant): a field of a built-in type holds
// that type (scalar or array), an enumeration an Int32, a BaseDataType field its Variant, and
// a field whose type is itself a structure holds an ExtensionObject with the binary body of
// that structure (decode it with the nested layout); an absent optional field, or every
// field but the chosen one of a union, is an empty Variant.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "ua/types/binary.hpp"
#include "ua/types/builtin.hpp"

namespace pnp::ua::server {

struct StructureFieldLayout {
    enum class Kind : std::uint8_t {
        Builtin,          // `builtin` (enumerations: Int32)
        Structure,        // a concrete structure, encoded inline (its body only)
        ExtensionObject,  // an abstract structure type: a whole ExtensionObject
        Variant,          // BaseDataType: a Variant
    };
    std::string name;
    NodeId dataType;
    Int32 valueRank = -1;  // -1 scalar, >= 1 array (encoded as a one-dimensional array)
    bool isOptional = false;
    Kind kind = Kind::Builtin;
    BuiltinType builtin = BuiltinType::Null;
};

struct StructureLayout {
    enum class Form : std::uint8_t { Plain, WithOptionalFields, Union };
    NodeId dataType;
    NodeId binaryEncoding;  // the "Default Binary" DataTypeEncoding node
    Form form = Form::Plain;
    std::vector<StructureFieldLayout> fields;  // inherited fields first
};

// Layout of a nested structure DataType (nullptr: unknown).
using StructureLayoutLookup = std::function<std::shared_ptr<const StructureLayout>(const NodeId&)>;

struct StructureValue {
    std::vector<std::pair<std::string, Variant>> fields;
    const Variant* field(std::string_view name) const {
        for (const auto& f : fields)
            if (f.first == name) return &f.second;
        return nullptr;
    }
};

// The binary body of `value` (fields matched by name; a missing mandatory field is encoded
// with its default value). Throws std::invalid_argument naming the field when a value does
// not fit its field's type.
std::string encodeStructure(const StructureLayout& layout, const StructureValue& value,
                            const StructureLayoutLookup& lookup);
// Throws DecodeError on a malformed or truncated body (nesting bounded by limits.maxDepth).
StructureValue decodeStructure(const StructureLayout& layout, const Byte* body, std::size_t size,
                               const StructureLayoutLookup& lookup,
                               const DecodeLimits& limits = {});

// An array of built-in type `type` from scalars of that type (std::invalid_argument if one is
// of another type).
Variant arrayOf(BuiltinType type, std::vector<Variant> scalars);

// The default (zero) value of a built-in type, as held in a Variant.
Variant defaultValueOf(BuiltinType type);

}  // namespace pnp::ua::server
