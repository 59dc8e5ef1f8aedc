// Checks used by the generated round-trip tests (ns0_test_roundtrip_<k>.cpp).
#pragma once

#include <gtest/gtest.h>

#include <cstring>
#include <initializer_list>
#include <string>

#include "ua/types/binary.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types.hpp"

namespace pnp::ua::testgen {

// T filled by fill() must encode, decode to an equal value and encode to the same bytes;
// the encoding cut short by one byte must be rejected with DecodeError.
template <class T, bool kHasBinaryEncoding>
void checkStructRoundTrip(bool hasFields) {
    T value{};
    fill(value);
    if (hasFields) {
        EXPECT_FALSE(value == T{}) << "fill() left the value at its default";
    }

    Buffer bytes = encodeToBuffer(value);
    T decoded = decodeFromBuffer<T>(bytes.data(), bytes.size());
    EXPECT_EQ(decoded, value);
    EXPECT_EQ(encodeToBuffer(decoded), bytes);

    if (!bytes.empty()) {
        EXPECT_THROW(decodeFromBuffer<T>(bytes.data(), bytes.size() - 1), DecodeError);
    }

    if constexpr (kHasBinaryEncoding) {
        ExtensionObject x = toExtensionObject(value);
        EXPECT_EQ(x.typeId, NodeId(0, DataTypeInfo<T>::binaryEncodingId));
        auto back = fromExtensionObject<T>(x);
        ASSERT_TRUE(back.has_value());
        EXPECT_EQ(*back, value);

        const DataTypeCodec* codec = findCodecByEncodingId(DataTypeInfo<T>::binaryEncodingId);
        ASSERT_NE(codec, nullptr);
        EXPECT_EQ(codec->name, DataTypeInfo<T>::name);
        EXPECT_EQ(codec->dataTypeId, DataTypeInfo<T>::dataTypeId);
        EXPECT_EQ(findCodecByDataTypeId(DataTypeInfo<T>::dataTypeId), codec);

        auto again = reencodeExtensionObject(x);
        ASSERT_TRUE(again.has_value());
        EXPECT_EQ(*again, x);

        std::string json = toJson(x);
        EXPECT_NE(json.find(std::string("\"Type\":\"") + std::string(codec->name) + "\""),
                  std::string::npos)
            << json;
    }
    std::string json = toJson(value);
    ASSERT_FALSE(json.empty());
    EXPECT_EQ(json.front(), '{');
    EXPECT_EQ(json.back(), '}');
}

// Every enumerator encodes as its Int32 value and decodes back; names are known.
template <class E>
void checkEnumRoundTrip(std::initializer_list<E> values) {
    for (E v : values) {
        Buffer bytes = encodeToBuffer(v);
        ASSERT_EQ(bytes.size(), 4u);
        Int32 raw = 0;
        std::memcpy(&raw, bytes.data(), 4);
        EXPECT_EQ(raw, static_cast<Int32>(v));
        EXPECT_EQ(decodeFromBuffer<E>(bytes.data(), bytes.size()), v);
        EXPECT_THROW(decodeFromBuffer<E>(bytes.data(), bytes.size() - 1), DecodeError);
        EXPECT_FALSE(toString(v).empty());
    }
    E filled{};
    fill(filled);
    Buffer bytes = encodeToBuffer(filled);
    EXPECT_EQ(decodeFromBuffer<E>(bytes.data(), bytes.size()), filled);
}

}  // namespace pnp::ua::testgen
