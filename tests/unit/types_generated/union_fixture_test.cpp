// Generated code paths that namespace 0 does not use (unions, optional structure and array
// fields, keyword field names), on the test-only DataTypes of
// tools/codegen/fixtures/pnp_codegen_test.NodeSet2.xml.
#include <gtest/gtest.h>

#include <type_traits>

#include "bytes.hpp"
#include "ns0_test_fixture.hpp"
#include "roundtrip_check.hpp"

namespace pnp::ua {
namespace {

using testgen::bytes;
using testgen::decodeAll;

TEST(GeneratedUnion, SwitchFieldIsTheVariantIndex) {
    static_assert(PnpTestUnion::kNumber == 1 && PnpTestUnion::kText == 2 &&
                  PnpTestUnion::kOther == 6);
    PnpTestUnion u;
    EXPECT_EQ(u.value.index(), 0u);
    EXPECT_EQ(encodeToBuffer(u), bytes({0, 0, 0, 0}));
    EXPECT_EQ(decodeAll<PnpTestUnion>(bytes({0, 0, 0, 0})), u);

    u.value.emplace<PnpTestUnion::kText>("ab");
    Buffer text = bytes({2, 0, 0, 0, 2, 0, 0, 0, 'a', 'b'});
    EXPECT_EQ(encodeToBuffer(u), text);
    EXPECT_EQ(decodeAll<PnpTestUnion>(text), u);
    EXPECT_EQ(toJson(u), "{\"SwitchField\":2,\"Text\":\"ab\"}");

    // Two fields of the same type stay distinct.
    u.value.emplace<PnpTestUnion::kOther>(5);
    Buffer other = bytes({6, 0, 0, 0, 5, 0, 0, 0});
    EXPECT_EQ(encodeToBuffer(u), other);
    PnpTestUnion back = decodeAll<PnpTestUnion>(other);
    EXPECT_EQ(back.value.index(), PnpTestUnion::kOther);
    EXPECT_EQ(std::get<PnpTestUnion::kOther>(back.value), 5);

    u.value.emplace<PnpTestUnion::kFlag>(true);
    EXPECT_EQ(encodeToBuffer(u), bytes({5, 0, 0, 0, 1}));

    EXPECT_THROW(decodeAll<PnpTestUnion>(bytes({7, 0, 0, 0})), DecodeError);
    EXPECT_THROW(decodeAll<PnpTestUnion>(bytes({2, 0, 0, 0, 2, 0, 0, 0, 'a'})), DecodeError);
}

TEST(GeneratedUnion, EveryAlternativeRoundTrips) {
    for (std::size_t i = 0; i <= 6; ++i) {
        PnpTestUnion u;
        switch (i) {
            case 1:
                u.value.emplace<1>(-7);
                break;
            case 2:
                u.value.emplace<2>("text");
                break;
            case 3:
                u.value.emplace<3>(2);
                std::get<3>(u.value)[1].attributeId = 13;
                break;
            case 4:
                u.value.emplace<4>().high = 3;
                break;
            case 5:
                u.value.emplace<5>(true);
                break;
            case 6:
                u.value.emplace<6>(42);
                break;
            default:
                break;
        }
        Buffer b = encodeToBuffer(u);
        EXPECT_EQ(decodeAll<PnpTestUnion>(b), u) << i;
        EXPECT_EQ(b[0], i);
        if (i != 0) {
            EXPECT_THROW(decodeAll<PnpTestUnion>(Buffer(b.begin(), b.end() - 1)), DecodeError);
        }
    }
}

TEST(GeneratedOptionalFields, MaskAndKeywordMember) {
    PnpTestOptionalFields v;
    v.head = 1;
    v.choice.emplace().value.emplace<PnpTestUnion::kText>("x");
    v.class_ = NodeClass::Object;  // field "Class": keywords get a trailing '_'
    v.tail = "t";
    Buffer b = bytes({
        0x05, 0, 0, 0,                     // EncodingMask: Choice (bit 0), Class (bit 2)
        1,    0, 0, 0,                     // Head
        2,    0, 0, 0, 1,   0, 0, 0, 'x',  // Choice: Text "x"
        1,    0, 0, 0,                     // Class: Object
        1,    0, 0, 0, 't',                // Tail
    });
    EXPECT_EQ(encodeToBuffer(v), b);
    EXPECT_EQ(decodeAll<PnpTestOptionalFields>(b), v);
    static_assert(std::is_same_v<decltype(v.flags), std::optional<std::vector<Boolean>>>);
}

TEST(GeneratedFixture, RoundTrips) {
    testgen::checkStructRoundTrip<PnpTestUnion, false>(true);
    testgen::checkStructRoundTrip<PnpTestOptionalFields, false>(true);
    testgen::checkStructRoundTrip<PnpTestUnionHolder, false>(true);
}

}  // namespace
}  // namespace pnp::ua
