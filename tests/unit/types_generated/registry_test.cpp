#include <gtest/gtest.h>

#include <algorithm>
#include <string>

#include "ua/types/ns0_types.hpp"

namespace pnp::ua {
namespace {

TEST(Ns0Registry, Lookups) {
    const DataTypeCodec* c = findCodecByEncodingId(631);
    ASSERT_NE(c, nullptr);
    EXPECT_EQ(c->name, "ReadRequest");
    EXPECT_EQ(c->dataTypeId, 629u);
    EXPECT_EQ(findCodecByDataTypeId(629), c);

    const DataTypeCodec* range = findCodecByDataTypeId(884);
    ASSERT_NE(range, nullptr);
    EXPECT_EQ(range->name, "Range");
    EXPECT_EQ(range->binaryEncodingId, 886u);

    EXPECT_EQ(findCodecByEncodingId(0), nullptr);
    EXPECT_EQ(findCodecByEncodingId(629), nullptr);  // a DataType id, not an encoding
    EXPECT_EQ(findCodecByEncodingId(632), nullptr);  // ReadResponse's DataType id
    EXPECT_EQ(findCodecByDataTypeId(631), nullptr);
    EXPECT_EQ(findCodecByDataTypeId(22), nullptr);   // Structure is abstract
    EXPECT_EQ(findCodecByDataTypeId(316), nullptr);  // UserIdentityToken is abstract

    // JSON-only DataTypes have a codec but no binary encoding.
    const DataTypeCodec* json = findCodecByDataTypeId(19312);
    ASSERT_NE(json, nullptr);
    EXPECT_EQ(json->name, "JsonDataSetMessage");
    EXPECT_EQ(json->binaryEncodingId, 0u);
}

TEST(Ns0Registry, Table) {
    auto all = allDataTypeCodecs();
    ASSERT_EQ(all.size(), kDataTypeCodecCount);
    EXPECT_GT(all.size(), 300u);
    EXPECT_TRUE(std::is_sorted(all.begin(), all.end(), [](const auto& a, const auto& b) {
        return a.dataTypeId < b.dataTypeId;
    }));
    for (const auto& c : all) {
        EXPECT_EQ(findCodecByDataTypeId(c.dataTypeId), &c) << c.name;
        if (c.binaryEncodingId != 0) {
            EXPECT_EQ(findCodecByEncodingId(c.binaryEncodingId), &c);
        }
        // Every type decodes from a body of zeros or reports a DecodeError: never crashes.
        Buffer zeros(64, 0);
        BinaryDecoder in(zeros.data(), zeros.size());
        Buffer out;
        BinaryEncoder enc(out);
        try {
            c.reencode(in, enc);
        } catch (const DecodeError&) {
        }
    }
}

TEST(Ns0Registry, ReencodeAndJson) {
    Range r;
    r.low = -1.5;
    r.high = 99;
    ExtensionObject x = toExtensionObject(r);
    auto again = reencodeExtensionObject(x);
    ASSERT_TRUE(again.has_value());
    EXPECT_EQ(*again, x);

    std::string json = toJson(x);
    EXPECT_NE(json.find("\"Type\":\"Range\""), std::string::npos) << json;
    EXPECT_NE(json.find("\"Body\":{\"Low\":-1.5,\"High\":99}"), std::string::npos) << json;
    EXPECT_EQ(toJson(r), "{\"Low\":-1.5,\"High\":99}");

    ReadValueId id;
    id.nodeId = NodeId(0, 2258);
    id.attributeId = 13;
    std::string j = toJson(id);
    EXPECT_NE(j.find("\"AttributeId\":13"), std::string::npos) << j;

    // Unknown types keep their body.
    ExtensionObject unknown;
    unknown.typeId = NodeId(2, 5001);
    unknown.encoding = ExtensionObject::Encoding::Binary;
    unknown.body = "\x01\x02";
    EXPECT_EQ(reencodeExtensionObject(unknown), std::nullopt);
    std::string uj = toJson(unknown);
    EXPECT_NE(uj.find("\"Body\":\"AQI=\""), std::string::npos) << uj;

    // A malformed body throws when re-encoded and prints raw.
    ExtensionObject bad = x;
    bad.body.resize(5);
    EXPECT_THROW(reencodeExtensionObject(bad), DecodeError);
    EXPECT_NE(toJson(bad).find("\"Encoding\":\"Binary\""), std::string::npos);
}

TEST(Ns0Registry, NestedExtensionObjectsAreBounded) {
    // MonitoringParameters holds its filter as an ExtensionObject: nest it deeply.
    MonitoringParameters p;
    p.clientHandle = 1;
    for (int i = 0; i < 200; ++i) {
        MonitoringParameters outer;
        outer.clientHandle = static_cast<UInt32>(i + 2);
        outer.filter = toExtensionObject(p);
        p = std::move(outer);
    }
    std::string json = toJson(p);
    EXPECT_NE(json.find("\"ClientHandle\":201"), std::string::npos);
    EXPECT_NE(json.find("\"Encoding\":\"Binary\""), std::string::npos);  // depth limit reached
}

}  // namespace
}  // namespace pnp::ua
