// Client pieces that need no network: deadlines, errors and results, request encoding,
// response decoding / error mapping, browse path parsing.
#include <gtest/gtest.h>

#include <chrono>

#include "ua/client/browse_path.hpp"
#include "ua/client/client.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::client {
namespace {

using namespace std::chrono_literals;

TEST(Deadline, Resolves) {
    Clock::time_point now = Clock::now();
    EXPECT_EQ(Deadline().resolve(now, 10s), now + 10s);
    EXPECT_TRUE(Deadline().isDefault());
    EXPECT_EQ(Deadline(250ms).resolve(now, 10s), now + 250ms);
    EXPECT_EQ(Deadline(std::chrono::microseconds(5)).resolve(now, 10s), now + 5us);
    EXPECT_EQ(Deadline(now + 3s).resolve(Clock::now(), 10s), now + 3s);
    EXPECT_EQ(Deadline::never().resolve(now, 10s), Clock::time_point::max());
    EXPECT_EQ(Deadline(-5s).resolve(now, 10s), now);
    EXPECT_EQ(Deadline(std::chrono::hours::max()).resolve(now, 10s), Clock::time_point::max());
}

TEST(Error, CarriesStatusAndMessage) {
    Error e(status::BadTimeout, "Read timed out");
    EXPECT_EQ(e.status(), status::BadTimeout);
    std::string what = e.what();
    EXPECT_NE(what.find("Read timed out"), std::string::npos);
    EXPECT_NE(what.find("BadTimeout"), std::string::npos);
}

TEST(Result, ValueAndError) {
    Result<int> ok(42);
    EXPECT_TRUE(ok.ok());
    EXPECT_TRUE(static_cast<bool>(ok));
    EXPECT_EQ(ok.value(), 42);
    EXPECT_EQ(*ok, 42);
    EXPECT_EQ(ok.error(), nullptr);
    EXPECT_TRUE(ok.status().isGood());

    Result<int> bad(Error(status::BadNodeIdUnknown, "x"));
    EXPECT_FALSE(bad.ok());
    EXPECT_EQ(bad.status(), status::BadNodeIdUnknown);
    ASSERT_NE(bad.error(), nullptr);
    try {
        (void)bad.value();
        FAIL() << "value() of an error must throw";
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadNodeIdUnknown);
    }
}

TEST(Services, TraitsAndNames) {
    static_assert(std::is_same_v<ResponseOf<ReadRequest>, ReadResponse>);
    static_assert(std::is_same_v<ResponseOf<CallRequest>, CallResponse>);
    static_assert(ServiceTraits<ReadRequest>::idempotent);
    static_assert(ServiceTraits<BrowseRequest>::idempotent);
    static_assert(!ServiceTraits<WriteRequest>::idempotent);
    static_assert(!ServiceTraits<CallRequest>::idempotent);
    static_assert(!ServiceTraits<BrowseNextRequest>::idempotent);
    static_assert(!ServiceTraits<ServerStatusDataType>::idempotent);  // primary template
    EXPECT_EQ(detail::serviceName<ReadRequest>(), "Read");
    EXPECT_EQ(detail::serviceName<TranslateBrowsePathsToNodeIdsRequest>(),
              "TranslateBrowsePathsToNodeIds");
}

TEST(RequestCodec, EncodesTypeIdThenBody) {
    ReadRequest req{};
    req.requestHeader.requestHandle = 77;
    req.requestHeader.authenticationToken = NodeId(1, ByteString("tok"));
    req.requestHeader.timeoutHint = 1500;
    req.maxAge = 0;
    req.timestampsToReturn = TimestampsToReturn::Neither;
    ReadValueId id{};
    id.nodeId = NodeId(2, "Scalar.Int32");
    id.attributeId = static_cast<UInt32>(AttributeId::Value);
    req.nodesToRead.push_back(id);

    Buffer b;
    detail::encodeRequest(b, req);
    BinaryDecoder d(b.data(), b.size());
    NodeId typeId;
    decode(d, typeId);
    EXPECT_EQ(typeId, NodeId(0, 631));  // ReadRequest_Encoding_DefaultBinary
    ReadRequest back{};
    decode(d, back);
    EXPECT_EQ(d.remaining(), 0u);
    EXPECT_EQ(back, req);
}

// Requests without a hand-written body: the client's header in front, then the generated
// encodeAfterRequestHeader() - byte for byte what the generated encoder writes.
TEST(ClientCodec, GenericRequestWithTheClientsHeader) {
    CallRequest req{};
    CallMethodRequest m{};
    m.objectId = NodeId(2, "Demo");
    m.methodId = NodeId(2, "Demo.Echo");
    m.inputArguments.emplace_back(ByteString("abc"));
    req.methodsToCall.push_back(m);
    RequestHeader h{};
    h.authenticationToken = NodeId(0, ByteString("token-bytes-1234567890"));
    h.requestHandle = 42;
    h.timeoutHint = 1500;
    Buffer ours;
    detail::encodeRequest(ours, req, h);
    CallRequest expected = req;
    expected.requestHeader = h;
    Buffer generated = encodeToBuffer(NodeId(0, DataTypeInfo<CallRequest>::binaryEncodingId));
    Buffer body = encodeToBuffer(expected);
    generated.insert(generated.end(), body.begin(), body.end());
    EXPECT_EQ(ours, generated);
}

// Encodes with the client's request codec and checks: the type id, a round trip through the
// generated decoder, and the bytes against the generated encoder once every empty IndexRange
// is filled in (both then agree byte for byte).
template <class Req, class Fill>
void checkIndexRangeEncoding(Req req, std::size_t ranges, Fill fillRanges) {
    Buffer ours;
    detail::encodeRequest(ours, req);
    BinaryDecoder d(ours.data(), ours.size());
    NodeId typeId;
    decode(d, typeId);
    EXPECT_EQ(typeId, NodeId(0, DataTypeInfo<Req>::binaryEncodingId));
    Req back{};
    decode(d, back);
    EXPECT_EQ(d.remaining(), 0u);
    EXPECT_EQ(back, req);
    // Null (-1) instead of empty (0): 0 extra bytes, but the length fields differ.
    Buffer generated = encodeToBuffer(NodeId(0, DataTypeInfo<Req>::binaryEncodingId));
    Buffer body = encodeToBuffer(req);
    generated.insert(generated.end(), body.begin(), body.end());
    ASSERT_EQ(ours.size(), generated.size());
    std::size_t diffs = 0;
    for (std::size_t i = 0; i < ours.size(); ++i) diffs += ours[i] != generated[i];
    EXPECT_EQ(diffs, 4 * ranges);  // each empty field: 0x00000000 -> 0xFFFFFFFF
    fillRanges(req);
    Buffer filled;
    detail::encodeRequest(filled, req);
    Buffer gen2 = encodeToBuffer(NodeId(0, DataTypeInfo<Req>::binaryEncodingId));
    Buffer body2 = encodeToBuffer(req);
    gen2.insert(gen2.end(), body2.begin(), body2.end());
    EXPECT_EQ(filled, gen2);
}

TEST(RequestCodec, EmptyIndexRangeAndDataEncodingAreSentAsNull) {
    ReadRequest read{};
    read.timestampsToReturn = TimestampsToReturn::Both;
    ReadValueId id{};
    id.nodeId = NodeId(1, "x");
    id.attributeId = 13;
    read.nodesToRead = {id, id};
    checkIndexRangeEncoding(read, 4, [](ReadRequest& r) {
        for (auto& n : r.nodesToRead) {
            n.indexRange = "1:2";
            n.dataEncoding = QualifiedName{0, "Default Binary"};
        }
    });

    WriteRequest write{};
    WriteValue w{};
    w.nodeId = NodeId(1, "x");
    w.attributeId = 13;
    w.value = DataValue(Variant(std::vector<Int32>{1, 2}));
    write.nodesToWrite = {w};
    checkIndexRangeEncoding(write, 1, [](WriteRequest& r) { r.nodesToWrite[0].indexRange = "0"; });

    HistoryReadRequest hist{};
    HistoryReadValueId h{};
    h.nodeId = NodeId(1, "x");
    h.continuationPoint = ByteString("cp");
    hist.nodesToRead = {h};
    hist.releaseContinuationPoints = true;
    checkIndexRangeEncoding(hist, 2, [](HistoryReadRequest& r) {
        r.nodesToRead[0].indexRange = "3";
        r.nodesToRead[0].dataEncoding.name = "Default Binary";
    });

    CreateMonitoredItemsRequest mon{};
    mon.subscriptionId = 7;
    MonitoredItemCreateRequest m{};
    m.itemToMonitor = id;
    m.monitoringMode = MonitoringMode::Reporting;
    m.requestedParameters.clientHandle = 3;
    m.requestedParameters.samplingInterval = 100;
    m.requestedParameters.queueSize = 1;
    mon.itemsToCreate = {m, m, m};
    checkIndexRangeEncoding(mon, 6, [](CreateMonitoredItemsRequest& r) {
        for (auto& i : r.itemsToCreate) {
            i.itemToMonitor.indexRange = "5";
            i.itemToMonitor.dataEncoding.name = "Default Binary";
        }
    });
}

template <class T>
Buffer bodyOf(const T& v) {
    return encodeToBuffer(v);
}

TEST(ResponseCodec, DecodesTheExpectedType) {
    ReadResponse resp{};
    resp.responseHeader.requestHandle = 5;
    resp.results.push_back(DataValue(Variant(Int32{9})));
    Buffer b = bodyOf(resp);
    auto got = detail::decodeResponse<ReadResponse>(NodeId(0, 634), b.data(), b.size(), "Read", {});
    EXPECT_EQ(got, resp);
}

TEST(ResponseCodec, ServiceFaultBecomesError) {
    ServiceFault f{};
    f.responseHeader.serviceResult = status::BadTooManyOperations;
    Buffer b = bodyOf(f);
    try {
        detail::decodeResponse<ReadResponse>(NodeId(0, 397), b.data(), b.size(), "Read", {});
        FAIL();
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadTooManyOperations);
        EXPECT_NE(std::string(e.what()).find("Read"), std::string::npos);
    }
}

TEST(ResponseCodec, GoodServiceFaultIsStillAnError) {
    ServiceFault f{};
    Buffer b = bodyOf(f);
    try {
        detail::decodeResponse<ReadResponse>(NodeId(0, 397), b.data(), b.size(), "Read", {});
        FAIL();
    } catch (const Error& e) {
        EXPECT_TRUE(e.status().isBad());
    }
}

TEST(ResponseCodec, BadServiceResultBecomesError) {
    WriteResponse resp{};
    resp.responseHeader.serviceResult = status::BadNothingToDo;
    Buffer b = bodyOf(resp);
    try {
        detail::decodeResponse<WriteResponse>(NodeId(0, 676), b.data(), b.size(), "Write", {});
        FAIL();
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadNothingToDo);
    }
}

TEST(ResponseCodec, UncertainServiceResultIsNotAnError) {
    WriteResponse resp{};
    resp.responseHeader.serviceResult = StatusCode(0x40000000u);
    Buffer b = bodyOf(resp);
    EXPECT_NO_THROW(
        detail::decodeResponse<WriteResponse>(NodeId(0, 676), b.data(), b.size(), "Write", {}));
}

TEST(ResponseCodec, WrongTypeIsBadUnknownResponse) {
    WriteResponse resp{};
    Buffer b = bodyOf(resp);
    try {
        detail::decodeResponse<ReadResponse>(NodeId(0, 676), b.data(), b.size(), "Read", {});
        FAIL();
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadUnknownResponse);
    }
}

TEST(ResponseCodec, TruncatedBodyIsDecodingError) {
    ReadResponse resp{};
    resp.results.push_back(DataValue(Variant(String("hello world"))));
    Buffer b = bodyOf(resp);
    try {
        detail::decodeResponse<ReadResponse>(NodeId(0, 634), b.data(), b.size() - 3, "Read", {});
        FAIL();
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadDecodingError);
    }
}

TEST(ResponseCodec, DecodeLimitsApply) {
    ReadResponse resp{};
    for (int i = 0; i < 10; ++i) resp.results.push_back(DataValue(Variant(Int32{i})));
    Buffer b = bodyOf(resp);
    DecodeLimits limits;
    limits.maxArrayLength = 4;
    try {
        detail::decodeResponse<ReadResponse>(NodeId(0, 634), b.data(), b.size(), "Read", limits);
        FAIL();
    } catch (const Error& e) {
        EXPECT_TRUE(e.status().isBad());
    }
}

// ---- browse paths --------------------------------------------------------------------------

TEST(BrowsePath, SlashPath) {
    RelativePath p = parseRelativePath("/Objects/Server/ServerStatus");
    ASSERT_EQ(p.elements.size(), 3u);
    for (const auto& e : p.elements) {
        EXPECT_EQ(e.referenceTypeId, NodeId(0, 33));
        EXPECT_TRUE(e.includeSubtypes);
        EXPECT_FALSE(e.isInverse);
        EXPECT_EQ(e.targetName.namespaceIndex, 0);
    }
    EXPECT_EQ(p.elements[0].targetName.name, "Objects");
    EXPECT_EQ(p.elements[2].targetName.name, "ServerStatus");
}

TEST(BrowsePath, LeadingNameReadsAsSlash) {
    RelativePath p = parseRelativePath("Server/2:Demo");
    ASSERT_EQ(p.elements.size(), 2u);
    EXPECT_EQ(p.elements[0].referenceTypeId, NodeId(0, 33));
    EXPECT_EQ(p.elements[0].targetName, (QualifiedName{0, "Server"}));
    EXPECT_EQ(p.elements[1].targetName, (QualifiedName{2, "Demo"}));
}

TEST(BrowsePath, AggregatesAndReferenceTypes) {
    RelativePath p = parseRelativePath(".3:Prop<HasComponent>1:X<#!Organizes>Y<i=46>Z");
    ASSERT_EQ(p.elements.size(), 4u);
    EXPECT_EQ(p.elements[0].referenceTypeId, NodeId(0, 44));
    EXPECT_EQ(p.elements[0].targetName, (QualifiedName{3, "Prop"}));
    EXPECT_EQ(p.elements[1].referenceTypeId, NodeId(0, 47));
    EXPECT_TRUE(p.elements[1].includeSubtypes);
    EXPECT_EQ(p.elements[2].referenceTypeId, NodeId(0, 35));
    EXPECT_FALSE(p.elements[2].includeSubtypes);
    EXPECT_TRUE(p.elements[2].isInverse);
    EXPECT_EQ(p.elements[3].referenceTypeId, NodeId(0, 46));
    EXPECT_EQ(p.elements[3].targetName.name, "Z");
}

TEST(BrowsePath, Escapes) {
    RelativePath p = parseRelativePath("/2:Scalar&.Int32/a&/b&:c&&d");
    ASSERT_EQ(p.elements.size(), 2u);
    EXPECT_EQ(p.elements[0].targetName, (QualifiedName{2, "Scalar.Int32"}));
    EXPECT_EQ(p.elements[1].targetName, (QualifiedName{0, "a/b:c&d"}));
}

TEST(BrowsePath, UriPrefixUsesResolver) {
    auto resolver = [](std::string_view uri) -> UInt16 {
        if (uri == "urn:pnp:demo") return 4;
        throw Error(status::BadNotFound, "unknown");
    };
    RelativePath p = parseRelativePath("/Objects/urn:pnp:demo:Demo", resolver);
    ASSERT_EQ(p.elements.size(), 2u);
    EXPECT_EQ(p.elements[1].targetName, (QualifiedName{4, "Demo"}));
    try {
        parseRelativePath("/urn:other:X", resolver);
        FAIL();
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadNotFound);
    }
    try {
        parseRelativePath("/urn:pnp:demo:Demo");
        FAIL();
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadNotSupported);
    }
}

TEST(BrowsePath, EmptyLastNameAllowed) {
    RelativePath p = parseRelativePath("/Objects<HasComponent>");
    ASSERT_EQ(p.elements.size(), 2u);
    EXPECT_TRUE(p.elements[1].targetName.name.empty());
}

TEST(BrowsePath, SyntaxErrors) {
    for (std::string_view bad : {"", "<HasComponent", "/a//b", "<>X", "/a&", ":X", "<i=x>Y"}) {
        try {
            parseRelativePath(bad);
            ADD_FAILURE() << "accepted \"" << bad << "\"";
        } catch (const Error& e) {
            EXPECT_EQ(e.status(), status::BadSyntaxError) << bad;
        }
    }
    try {
        parseRelativePath("<NoSuchReference>X");
        FAIL();
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadNoMatch);
    }
}

TEST(BrowsePath, ReferenceTypeByName) {
    EXPECT_EQ(referenceTypeByName("HasProperty"), NodeId(0, 46));
    EXPECT_EQ(referenceTypeByName("HasSubtype"), NodeId(0, 45));
    EXPECT_TRUE(referenceTypeByName("Nope").isNull());
}

}  // namespace
}  // namespace pnp::ua::client
