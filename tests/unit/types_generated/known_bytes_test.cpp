// Generated codecs against encodings written out by hand from OPC 10000-6 §5.2.
#include <gtest/gtest.h>

#include <string>
#include <type_traits>

#include "bytes.hpp"
#include "ua/types/ns0_types.hpp"

namespace pnp::ua {
namespace {

using testgen::bytes;
using testgen::decodeAll;

void append(Buffer& b, const Buffer& more) { b.insert(b.end(), more.begin(), more.end()); }

// ReadValueId{ns=0;i=2258 (Server_ServerStatus_CurrentTime), Value attribute}.
const Buffer kReadValueId = bytes({
    0x01, 0x00, 0xD2, 0x08,  // NodeId, four-byte form: ns 0, id 2258
    0x0D, 0x00, 0x00, 0x00,  // AttributeId 13 (Value)
    0x00, 0x00, 0x00, 0x00,  // IndexRange ""
    0x00, 0x00,              // DataEncoding: namespace 0
    0x00, 0x00, 0x00, 0x00,  //               name ""
});

TEST(Ns0KnownBytes, ReadValueId) {
    ReadValueId v;
    v.nodeId = NodeId(0, 2258);
    v.attributeId = 13;
    EXPECT_EQ(encodeToBuffer(v), kReadValueId);
    EXPECT_EQ(decodeAll<ReadValueId>(kReadValueId), v);

    // Null strings (-1) decode like empty ones.
    Buffer nulls = bytes({0x01, 0x00, 0xD2, 0x08, 0x0D, 0x00, 0x00, 0x00, 0xFF, 0xFF, 0xFF, 0xFF,
                          0x00, 0x00, 0xFF, 0xFF, 0xFF, 0xFF});
    EXPECT_EQ(decodeAll<ReadValueId>(nulls), v);
}

// RequestHeader with a token, a timestamp, an audit entry id and no additional header.
const Buffer kRequestHeader = bytes({
    0x00, 0x05,                                      // AuthenticationToken i=5, two-byte form
    0x00, 0x00, 0x5A, 0xF6, 0x4C, 0xF5, 0xD4, 0x01,  // Timestamp 132000000000000000
    0x01, 0x00, 0x00, 0x00,                          // RequestHandle 1
    0x00, 0x00, 0x00, 0x00,                          // ReturnDiagnostics 0
    0x03, 0x00, 0x00, 0x00, 'a',  'b',  'c',         // AuditEntryId "abc"
    0x10, 0x27, 0x00, 0x00,                          // TimeoutHint 10000
    0x00, 0x00, 0x00,                                // AdditionalHeader: null NodeId, no body
});

RequestHeader requestHeader() {
    RequestHeader h;
    h.authenticationToken = NodeId(0, 5);
    h.timestamp = DateTime{132000000000000000LL};
    h.requestHandle = 1;
    h.auditEntryId = "abc";
    h.timeoutHint = 10000;
    return h;
}

TEST(Ns0KnownBytes, RequestHeader) {
    EXPECT_EQ(encodeToBuffer(requestHeader()), kRequestHeader);
    EXPECT_EQ(decodeAll<RequestHeader>(kRequestHeader), requestHeader());
}

TEST(Ns0KnownBytes, ReadRequest) {
    Buffer b = kRequestHeader;
    append(b, bytes({0, 0, 0, 0, 0, 0, 0, 0}));  // MaxAge 0.0
    append(b, bytes({0x02, 0, 0, 0}));           // TimestampsToReturn Both
    append(b, bytes({0x02, 0, 0, 0}));           // NodesToRead: 2 elements
    append(b, kReadValueId);
    append(b, kReadValueId);

    ReadRequest r;
    r.requestHeader = requestHeader();
    r.timestampsToReturn = TimestampsToReturn::Both;
    r.nodesToRead.resize(2);
    r.nodesToRead[0].nodeId = r.nodesToRead[1].nodeId = NodeId(0, 2258);
    r.nodesToRead[0].attributeId = r.nodesToRead[1].attributeId = 13;
    EXPECT_EQ(encodeToBuffer(r), b);
    EXPECT_EQ(decodeAll<ReadRequest>(b), r);

    // An array count the message cannot hold is rejected before anything is allocated.
    Buffer bad(b.begin(), b.begin() + static_cast<std::ptrdiff_t>(kRequestHeader.size()) + 12);
    append(bad, bytes({0xFF, 0xFF, 0xFF, 0x7F}));
    EXPECT_THROW(decodeAll<ReadRequest>(bad), DecodeError);
}

TEST(Ns0KnownBytes, Enumeration) {
    EXPECT_EQ(encodeToBuffer(NodeClass::Variable), bytes({0x02, 0x00, 0x00, 0x00}));
    EXPECT_EQ(decodeAll<NodeClass>(bytes({0x04, 0x00, 0x00, 0x00})), NodeClass::Method);
    EXPECT_EQ(toString(NodeClass::ObjectType), "ObjectType");
    EXPECT_EQ(toString(MessageSecurityMode::SignAndEncrypt), "SignAndEncrypt");
    // Values without a name are kept, and print as "".
    auto odd = decodeAll<NodeClass>(bytes({0x03, 0x00, 0x00, 0x00}));
    EXPECT_EQ(static_cast<Int32>(odd), 3);
    EXPECT_EQ(toString(odd), "");
    static_assert(std::is_same_v<std::underlying_type_t<IdTypeEnum>, Int32>);
    EXPECT_EQ(toString(IdTypeEnum::Opaque), "Opaque");
}

// LogRecord is a structure with optional fields: EventType (bit 0), SourceNode (1),
// SourceName (2), TraceContext (3), AdditionalData (4).
TEST(Ns0KnownBytes, OptionalFields) {
    LogRecord r;
    r.time = DateTime{1};
    r.severity = 100;
    r.sourceName = "src";
    r.message = LocalizedText("", "m");
    Buffer b = bytes({
        0x04, 0x00, 0x00, 0x00,                          // EncodingMask: SourceName only
        0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,  // Time
        0x64, 0x00,                                      // Severity 100
        0x03, 0x00, 0x00, 0x00, 's',  'r',  'c',         // SourceName
        0x02, 0x01, 0x00, 0x00, 0x00, 'm',               // Message: text only
    });
    EXPECT_EQ(encodeToBuffer(r), b);
    EXPECT_EQ(decodeAll<LogRecord>(b), r);

    r.sourceName.reset();
    r.additionalData.emplace();  // present but empty
    Buffer b2 = bytes({0x10, 0x00, 0x00, 0x00, 0x01, 0, 0, 0,   0, 0, 0, 0,
                       0x64, 0x00, 0x02, 0x01, 0,    0, 0, 'm', 0, 0, 0, 0});
    EXPECT_EQ(encodeToBuffer(r), b2);
    EXPECT_EQ(decodeAll<LogRecord>(b2), r);

    Buffer unknownBit = b;
    unknownBit[0] = 0x24;  // bit 5 is not an optional field
    EXPECT_THROW(decodeAll<LogRecord>(unknownBit), DecodeError);
}

// Subtypes whose NodeSet2 definition lists only their own fields get the inherited ones first.
TEST(Ns0KnownBytes, InheritedFieldsComeFirst) {
    UserNameIdentityToken t;
    t.policyId = "p";
    t.userName = "u";
    t.password = ByteString(std::string("pw"));
    Buffer b = bytes({1, 0, 0, 0, 'p', 1, 0, 0, 0, 'u', 2, 0, 0, 0, 'p', 'w', 0, 0, 0, 0});
    EXPECT_EQ(encodeToBuffer(t), b);

    EnumField f;
    f.value = 7;
    f.name = "Seven";
    Buffer fb = bytes({7, 0, 0, 0, 0, 0, 0, 0, 0x00, 0x00, 5, 0, 0, 0, 'S', 'e', 'v', 'e', 'n'});
    EXPECT_EQ(encodeToBuffer(f), fb);
    EXPECT_EQ(decodeAll<EnumField>(fb), f);
}

TEST(Ns0KnownBytes, ExtensionObjectField) {
    AnonymousIdentityToken anon;
    anon.policyId = "anonymous";
    ActivateSessionRequest req;
    req.userIdentityToken = toExtensionObject(anon);
    EXPECT_EQ(req.userIdentityToken.typeId, NodeId(0, 321));  // Default Binary of i=319
    ActivateSessionRequest back = decodeAll<ActivateSessionRequest>(encodeToBuffer(req));
    auto token = fromExtensionObject<AnonymousIdentityToken>(back.userIdentityToken);
    ASSERT_TRUE(token.has_value());
    EXPECT_EQ(token->policyId, "anonymous");
    EXPECT_FALSE(fromExtensionObject<UserNameIdentityToken>(back.userIdentityToken));
}

TEST(Ns0KnownBytes, SimpleTypesAndOptionSets) {
    static_assert(std::is_same_v<Duration, Double>);
    static_assert(std::is_same_v<UtcTime, DateTime>);
    static_assert(std::is_same_v<LocaleId, String>);
    static_assert(std::is_same_v<IntegerId, UInt32>);
    static_assert(std::is_same_v<Counter, UInt32>);
    static_assert(std::is_same_v<NumericRange, String>);
    static_assert(std::is_same_v<Index, UInt32>);
    static_assert(std::is_same_v<ApplicationInstanceCertificate, ByteString>);
    static_assert(std::is_same_v<AccessLevelType, Byte>);
    static_assert(std::is_same_v<EventNotifierType, Byte>);
    static_assert(std::is_same_v<AccessLevelExType, UInt32>);
    static_assert(AccessLevelTypeBits::CurrentRead == 0x01);
    static_assert(AccessLevelTypeBits::CurrentWrite == 0x02);
    static_assert(AccessLevelTypeBits::HistoryRead == 0x04);
    static_assert(EventNotifierTypeBits::SubscribeToEvents == 0x01);
    static_assert(EventNotifierTypeBits::HistoryRead == 0x04);
    static_assert(DataTypeInfo<ReadRequest>::dataTypeId == 629);
    static_assert(DataTypeInfo<ReadRequest>::binaryEncodingId == 631);
    static_assert(DataTypeInfo<ThreeDVector>::name == "3DVector");
    SUCCEED();
}

}  // namespace
}  // namespace pnp::ua
