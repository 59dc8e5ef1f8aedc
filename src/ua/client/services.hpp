// Service traits and the request/response codec of the client.
//
// ServiceTraits<XxxRequest> names the response type and says whether the service may be
// sent twice (idempotent) when its response was lost with the connection. Adding a service
// to the client is one PNP_UA_CLIENT_SERVICE line; Client::request() does the rest.
#pragma once

#include <cstddef>
#include <string_view>
#include <vector>

#include "ua/client/error.hpp"
#include "ua/types/attribute_id.hpp"
#include "ua/types/binary.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::client {

using ua::AttributeId;  // ua/types/attribute_id.hpp

// Primary template: services without a specialisation can still be sent with
// request<Req, Resp>() and are never retried.
template <class Req>
struct ServiceTraits {
    static constexpr bool idempotent = false;
};

#define PNP_UA_CLIENT_SERVICE(Service, Idempotent)     \
    template <>                                        \
    struct ServiceTraits<Service##Request> {           \
        using Response = Service##Response;            \
        static constexpr bool idempotent = Idempotent; \
    }

// Discovery
PNP_UA_CLIENT_SERVICE(FindServers, true);
PNP_UA_CLIENT_SERVICE(FindServersOnNetwork, true);
PNP_UA_CLIENT_SERVICE(GetEndpoints, true);
PNP_UA_CLIENT_SERVICE(RegisterServer, false);
PNP_UA_CLIENT_SERVICE(RegisterServer2, false);
// Session
PNP_UA_CLIENT_SERVICE(CreateSession, false);
PNP_UA_CLIENT_SERVICE(ActivateSession, false);
PNP_UA_CLIENT_SERVICE(CloseSession, false);
PNP_UA_CLIENT_SERVICE(Cancel, false);
// NodeManagement
PNP_UA_CLIENT_SERVICE(AddNodes, false);
PNP_UA_CLIENT_SERVICE(AddReferences, false);
PNP_UA_CLIENT_SERVICE(DeleteNodes, false);
PNP_UA_CLIENT_SERVICE(DeleteReferences, false);
// View. BrowseNext is not idempotent: the server may have advanced the continuation point.
PNP_UA_CLIENT_SERVICE(Browse, true);
PNP_UA_CLIENT_SERVICE(BrowseNext, false);
PNP_UA_CLIENT_SERVICE(TranslateBrowsePathsToNodeIds, true);
PNP_UA_CLIENT_SERVICE(RegisterNodes, false);
PNP_UA_CLIENT_SERVICE(UnregisterNodes, false);
// Attribute
PNP_UA_CLIENT_SERVICE(Read, true);
PNP_UA_CLIENT_SERVICE(HistoryRead, true);
PNP_UA_CLIENT_SERVICE(Write, false);
PNP_UA_CLIENT_SERVICE(HistoryUpdate, false);
// Method
PNP_UA_CLIENT_SERVICE(Call, false);
// MonitoredItem / Subscription
PNP_UA_CLIENT_SERVICE(CreateMonitoredItems, false);
PNP_UA_CLIENT_SERVICE(ModifyMonitoredItems, false);
PNP_UA_CLIENT_SERVICE(SetMonitoringMode, false);
PNP_UA_CLIENT_SERVICE(SetTriggering, false);
PNP_UA_CLIENT_SERVICE(DeleteMonitoredItems, false);
PNP_UA_CLIENT_SERVICE(CreateSubscription, false);
PNP_UA_CLIENT_SERVICE(ModifySubscription, false);
PNP_UA_CLIENT_SERVICE(SetPublishingMode, false);
PNP_UA_CLIENT_SERVICE(Publish, false);
PNP_UA_CLIENT_SERVICE(Republish, false);
PNP_UA_CLIENT_SERVICE(TransferSubscriptions, false);
PNP_UA_CLIENT_SERVICE(DeleteSubscriptions, false);

template <class Req>
using ResponseOf = typename ServiceTraits<Req>::Response;

namespace detail {

// IndexRange and DataEncoding fields. The codec encodes every empty String with length 0,
// but node-opcua (2.x) parses an empty, non-null NumericRange as an *invalid* range (arrays
// read back empty, other attributes fail with BadIndexRangeNoData) and an empty, non-null
// DataEncoding name as a requested encoding (BadDataEncodingInvalid). "Not specified" is
// therefore sent as a null String (length -1), which every server reads as "not specified".
// The requests that carry these fields are encoded here field by field; all others use the
// generated codec.
inline void encodeIndexRange(BinaryEncoder& e, const String& s) {
    if (s.empty())
        e.number<Int32>(-1);
    else
        encode(e, s);
}
inline void encodeDataEncoding(BinaryEncoder& e, const QualifiedName& q) {
    encode(e, q.namespaceIndex);
    encodeIndexRange(e, q.name);
}
inline void encodeBody(BinaryEncoder& e, const ReadValueId& v) {
    encode(e, v.nodeId);
    encode(e, v.attributeId);
    encodeIndexRange(e, v.indexRange);
    encodeDataEncoding(e, v.dataEncoding);
}
inline void encodeBody(BinaryEncoder& e, const WriteValue& v) {
    encode(e, v.nodeId);
    encode(e, v.attributeId);
    encodeIndexRange(e, v.indexRange);
    encode(e, v.value);
}
inline void encodeBody(BinaryEncoder& e, const HistoryReadValueId& v) {
    encode(e, v.nodeId);
    encodeIndexRange(e, v.indexRange);
    encodeDataEncoding(e, v.dataEncoding);
    encode(e, v.continuationPoint);
}
inline void encodeBody(BinaryEncoder& e, const MonitoredItemCreateRequest& v) {
    encodeBody(e, v.itemToMonitor);
    encode(e, v.monitoringMode);
    encode(e, v.requestedParameters);
}
template <class T>
void encodeBodies(BinaryEncoder& e, const std::vector<T>& v) {
    e.number<Int32>(static_cast<Int32>(v.size()));
    for (const auto& x : v) encodeBody(e, x);
}
inline void encodeBody(BinaryEncoder& e, const ReadRequest& r, const RequestHeader& h) {
    encode(e, h);
    encode(e, r.maxAge);
    encode(e, r.timestampsToReturn);
    encodeBodies(e, r.nodesToRead);
}
inline void encodeBody(BinaryEncoder& e, const WriteRequest& r, const RequestHeader& h) {
    encode(e, h);
    encodeBodies(e, r.nodesToWrite);
}
inline void encodeBody(BinaryEncoder& e, const HistoryReadRequest& r, const RequestHeader& h) {
    encode(e, h);
    encode(e, r.historyReadDetails);
    encode(e, r.timestampsToReturn);
    encode(e, r.releaseContinuationPoints);
    encodeBodies(e, r.nodesToRead);
}
inline void encodeBody(BinaryEncoder& e, const CreateMonitoredItemsRequest& r,
                       const RequestHeader& h) {
    encode(e, h);
    encode(e, r.subscriptionId);
    encode(e, r.timestampsToReturn);
    encodeBodies(e, r.itemsToCreate);
}
template <class Req>
void encodeBody(BinaryEncoder& e, const Req& r, const RequestHeader& h) {
    encode(e, h);
    encodeAfterRequestHeader(e, r);
}

// Appends "encoding NodeId + body" of a request to a message buffer. With `splices`, large
// byte runs are referenced in the request instead of copied (see BinaryEncoder).
template <class Req>
void encodeRequest(Buffer& out, const Req& req, const RequestHeader& header,
                   Splices* splices = nullptr) {
    BinaryEncoder e(out, splices);
    encode(e, NodeId(0, DataTypeInfo<Req>::binaryEncodingId));
    encodeBody(e, req, header);
}
// The same with the request's own RequestHeader.
template <class Req>
void encodeRequest(Buffer& out, const Req& req) {
    encodeRequest(out, req, req.requestHeader);
}

// Throws the Error that a response of the wrong type stands for: the serviceResult of a
// ServiceFault, or BadUnknownResponse.
[[noreturn]] void throwUnexpectedResponse(const NodeId& typeId, const Byte* body, std::size_t size,
                                          std::string_view service, const DecodeLimits& limits);
// Throws Error(header.serviceResult) when it is Bad.
void checkServiceResult(const ResponseHeader& header, std::string_view service);
[[noreturn]] void throwDecodeError(const DecodeError& e, std::string_view service);

inline bool isNs0Numeric(const NodeId& id, UInt32 value) {
    return id.namespaceIndex() == 0 && id.isNumeric() && id.numeric() == value;
}

// Decodes the body of a response whose encoding NodeId is typeId; a ServiceFault or a Bad
// serviceResult throws Error. block: where the body lies, when large ByteStrings may keep
// references to it (BinaryDecoder::shareFrom).
template <class Resp>
Resp decodeResponse(const NodeId& typeId, const Byte* body, std::size_t size,
                    std::string_view service, const DecodeLimits& limits,
                    ByteBlock* block = nullptr) {
    if (!isNs0Numeric(typeId, DataTypeInfo<Resp>::binaryEncodingId))
        throwUnexpectedResponse(typeId, body, size, service, limits);
    Resp resp{};
    try {
        BinaryDecoder d(body, size, limits);
        if (block != nullptr) d.shareFrom(block);
        decode(d, resp);
    } catch (const DecodeError& e) {
        throwDecodeError(e, service);
    }
    checkServiceResult(resp.responseHeader, service);
    return resp;
}

template <class Req>
constexpr std::string_view serviceName() {
    constexpr std::string_view n = DataTypeInfo<Req>::name;
    constexpr std::string_view suffix = "Request";
    if constexpr (n.size() > suffix.size() && n.substr(n.size() - suffix.size()) == suffix)
        return n.substr(0, n.size() - suffix.size());
    else
        return n;
}

}  // namespace detail
}  // namespace pnp::ua::client
