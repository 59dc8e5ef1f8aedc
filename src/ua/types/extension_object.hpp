// Typed access to ExtensionObjects. Generated structures specialise DataTypeInfo<T>:
//   static constexpr UInt32 dataTypeId;        // ns=0 DataType node
//   static constexpr UInt32 binaryEncodingId;  // ns=0 "Default Binary" encoding node
//   static constexpr std::string_view name;
#pragma once

#include <optional>
#include <string_view>

#include "ua/types/binary.hpp"

namespace pnp::ua {

template <class T>
struct DataTypeInfo;

template <class T>
ExtensionObject toExtensionObject(const T& v) {
    ExtensionObject x;
    x.typeId = NodeId(0, DataTypeInfo<T>::binaryEncodingId);
    x.encoding = ExtensionObject::Encoding::Binary;
    Buffer b;
    b.reserve(256);  // most bodies fit: one allocation instead of a doubling series
    BinaryEncoder e(b);
    encode(e, v);
    x.body.assign(reinterpret_cast<const char*>(b.data()), b.size());
    return x;
}

// nullopt when the object holds another type; throws DecodeError when the body is malformed.
template <class T>
std::optional<T> fromExtensionObject(const ExtensionObject& x, const DecodeLimits& limits = {}) {
    if (x.encoding != ExtensionObject::Encoding::Binary ||
        x.typeId != NodeId(0, DataTypeInfo<T>::binaryEncodingId))
        return std::nullopt;
    return decodeFromBuffer<T>(reinterpret_cast<const Byte*>(x.body.data()), x.body.size(), false,
                               limits);
}

}  // namespace pnp::ua
