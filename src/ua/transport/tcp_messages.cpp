#include "ua/transport/tcp_messages.hpp"

#include <algorithm>
#include <cstring>

#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {

TransportError::TransportError(StatusCode status, const std::string& message)
    : std::runtime_error(message.empty() ? status.toString() : message + ": " + status.toString()),
      status_(status),
      message_(message) {}

namespace {

struct TypeName {
    char name[3];
    MessageType type;
};
constexpr TypeName kTypeNames[] = {
    {{'H', 'E', 'L'}, MessageType::Hello},
    {{'A', 'C', 'K'}, MessageType::Acknowledge},
    {{'E', 'R', 'R'}, MessageType::Error},
    {{'R', 'H', 'E'}, MessageType::ReverseHello},
    {{'O', 'P', 'N'}, MessageType::OpenSecureChannel},
    {{'M', 'S', 'G'}, MessageType::Message},
    {{'C', 'L', 'O'}, MessageType::CloseSecureChannel},
};

bool isSecureType(MessageType t) {
    return t == MessageType::OpenSecureChannel || t == MessageType::Message ||
           t == MessageType::CloseSecureChannel;
}

// Strings of the connection protocol messages: Int32 length (-1: null) + bytes, at most
// `max` bytes; `tooLong` is the status of a longer one. Checked before allocating.
std::string readString(BinaryDecoder& d, std::size_t max, StatusCode tooLong, const char* what) {
    Int32 n = d.number<Int32>();
    if (n < 0) return {};
    auto len = static_cast<std::size_t>(n);
    if (len > max) {
        throw TransportError(tooLong,
                             std::string(what) + " longer than " + std::to_string(max) + " bytes");
    }
    if (len > d.remaining()) throw TransportError(status::BadDecodingError, "message truncated");
    std::string s(reinterpret_cast<const char*>(d.position()), len);
    d.skip(len);
    return s;
}

template <class F>
auto decodeChecked(const Byte* body, std::size_t size, F&& f) {
    BinaryDecoder d(body, size);
    try {
        return f(d);
    } catch (const DecodeError& e) {
        throw TransportError(status::BadDecodingError, e.what());
    }
}

Buffer startMessage(MessageType type) {
    Buffer b(kMessageHeaderSize);
    encodeMessageHeader(b.data(), type, ChunkType::Final, 0);
    return b;
}
void finishMessage(Buffer& b) {
    auto size = static_cast<UInt32>(b.size());
    std::memcpy(b.data() + 4, &size, 4);
}

}  // namespace

std::string_view toString(MessageType t) {
    for (const auto& n : kTypeNames)
        if (n.type == t) return {n.name, 3};
    return "???";
}

std::size_t minimumChunkSize(MessageType type) {
    switch (type) {
        case MessageType::Hello:
            return kMessageHeaderSize + 20 + 4;
        case MessageType::Acknowledge:
            return kMessageHeaderSize + 20;
        case MessageType::Error:
            return kMessageHeaderSize + 4 + 4;
        case MessageType::ReverseHello:
            return kMessageHeaderSize + 4 + 4;
        // channel id + policy uri + certificate + thumbprint + sequence header
        case MessageType::OpenSecureChannel:
            return kMessageHeaderSize + 4 + 12 + 8;
        case MessageType::Message:
        case MessageType::CloseSecureChannel:
            return kSymmetricHeaderSize;
    }
    return kMessageHeaderSize;
}

MessageHeader decodeMessageHeader(const Byte* p) {
    MessageHeader h;
    bool found = false;
    for (const auto& n : kTypeNames) {
        if (std::memcmp(p, n.name, 3) == 0) {
            h.type = n.type;
            found = true;
            break;
        }
    }
    if (!found) throw TransportError(status::BadTcpMessageTypeInvalid, "unknown message type");
    char ct = static_cast<char>(p[3]);
    if (ct != 'F' && ct != 'C' && ct != 'A')
        throw TransportError(status::BadTcpMessageTypeInvalid, "invalid chunk type");
    h.chunkType = static_cast<ChunkType>(ct);
    if (h.chunkType != ChunkType::Final && !isSecureType(h.type)) {
        throw TransportError(status::BadTcpMessageTypeInvalid,
                             std::string(toString(h.type)) + " cannot be chunked");
    }
    std::memcpy(&h.size, p + 4, 4);
    if (h.size < minimumChunkSize(h.type)) {
        throw TransportError(status::BadDecodingError, std::string(toString(h.type)) +
                                                           " message size " +
                                                           std::to_string(h.size) + " too small");
    }
    return h;
}

void encodeMessageHeader(Byte* p, MessageType type, ChunkType chunkType, UInt32 size) {
    for (const auto& n : kTypeNames) {
        if (n.type == type) {
            std::memcpy(p, n.name, 3);
            break;
        }
    }
    p[3] = static_cast<Byte>(chunkType);
    std::memcpy(p + 4, &size, 4);
}

// ---- encode ----------------------------------------------------------------------------
namespace {
// The fields Hello and Acknowledge share, in their order (Part 6 §7.1.2.3 / §7.1.2.4).
template <class M>
void encodeBufferLimits(BinaryEncoder& e, const M& m) {
    e.number(m.protocolVersion);
    e.number(m.receiveBufferSize);
    e.number(m.sendBufferSize);
    e.number(m.maxMessageSize);
    e.number(m.maxChunkCount);
}
}  // namespace

Buffer encodeMessage(const Hello& m) {
    if (m.endpointUrl.size() > kMaxUrlLength)
        throw TransportError(status::BadTcpEndpointUrlInvalid, "EndpointUrl too long");
    Buffer b = startMessage(MessageType::Hello);
    BinaryEncoder e(b);
    encodeBufferLimits(e, m);
    e.lengthPrefixed(m.endpointUrl);
    finishMessage(b);
    return b;
}

Buffer encodeMessage(const Acknowledge& m) {
    Buffer b = startMessage(MessageType::Acknowledge);
    BinaryEncoder e(b);
    encodeBufferLimits(e, m);
    finishMessage(b);
    return b;
}

Buffer encodeMessage(const ErrorMessage& m) {
    Buffer b = startMessage(MessageType::Error);
    BinaryEncoder e(b);
    e.number(m.error.value);
    std::string reason = m.reason.substr(0, kMaxReasonLength);
    // Do not cut a UTF-8 sequence in half.
    if (m.reason.size() > kMaxReasonLength) {
        while (!reason.empty() && (static_cast<Byte>(reason.back()) & 0xC0) == 0x80)
            reason.pop_back();
        if (!reason.empty() && (static_cast<Byte>(reason.back()) & 0x80)) reason.pop_back();
    }
    e.lengthPrefixed(reason);
    finishMessage(b);
    return b;
}

Buffer encodeMessage(const ReverseHello& m) {
    if (m.serverUri.size() > kMaxUrlLength || m.endpointUrl.size() > kMaxUrlLength)
        throw TransportError(status::BadTcpEndpointUrlInvalid, "ReverseHello URI too long");
    Buffer b = startMessage(MessageType::ReverseHello);
    BinaryEncoder e(b);
    e.lengthPrefixed(m.serverUri);
    e.lengthPrefixed(m.endpointUrl);
    finishMessage(b);
    return b;
}

// ---- decode ----------------------------------------------------------------------------
Hello decodeHello(const Byte* body, std::size_t size) {
    return decodeChecked(body, size, [](BinaryDecoder& d) {
        Hello m;
        m.protocolVersion = d.number<UInt32>();
        m.receiveBufferSize = d.number<UInt32>();
        m.sendBufferSize = d.number<UInt32>();
        m.maxMessageSize = d.number<UInt32>();
        m.maxChunkCount = d.number<UInt32>();
        m.endpointUrl =
            readString(d, kMaxUrlLength, status::BadTcpEndpointUrlInvalid, "EndpointUrl");
        return m;
    });
}

Acknowledge decodeAcknowledge(const Byte* body, std::size_t size) {
    return decodeChecked(body, size, [](BinaryDecoder& d) {
        Acknowledge m;
        m.protocolVersion = d.number<UInt32>();
        m.receiveBufferSize = d.number<UInt32>();
        m.sendBufferSize = d.number<UInt32>();
        m.maxMessageSize = d.number<UInt32>();
        m.maxChunkCount = d.number<UInt32>();
        return m;
    });
}

ErrorMessage decodeError(const Byte* body, std::size_t size) {
    return decodeChecked(body, size, [](BinaryDecoder& d) {
        ErrorMessage m;
        m.error = StatusCode(d.number<UInt32>());
        m.reason = readString(d, kMaxReasonLength, status::BadDecodingError, "Reason");
        return m;
    });
}

ReverseHello decodeReverseHello(const Byte* body, std::size_t size) {
    return decodeChecked(body, size, [](BinaryDecoder& d) {
        ReverseHello m;
        m.serverUri = readString(d, kMaxUrlLength, status::BadTcpEndpointUrlInvalid, "ServerUri");
        m.endpointUrl =
            readString(d, kMaxUrlLength, status::BadTcpEndpointUrlInvalid, "EndpointUrl");
        return m;
    });
}

// ---- negotiation -----------------------------------------------------------------------
UInt32 effectiveMaxMessageSize(const TransportLimits& limits) {
    return limits.maxMessageSize ? limits.maxMessageSize : kDefaultMaxMessageSize;
}

UInt32 effectiveMaxChunkCount(const TransportLimits& limits, UInt32 receiveBufferSize) {
    if (limits.maxChunkCount) return limits.maxChunkCount;
    UInt64 body =
        receiveBufferSize > kSymmetricHeaderSize ? receiveBufferSize - kSymmetricHeaderSize : 1;
    UInt64 n = (UInt64{effectiveMaxMessageSize(limits)} + body - 1) / body + 1;
    return static_cast<UInt32>(std::min<UInt64>(n, 0xFFFFFFFFu));
}

Hello makeHello(const TransportLimits& own, std::string endpointUrl) {
    Hello h;
    h.protocolVersion = kProtocolVersion;
    h.receiveBufferSize = std::max(own.receiveBufferSize, kMinBufferSize);
    h.sendBufferSize = std::max(own.sendBufferSize, kMinBufferSize);
    h.maxMessageSize = effectiveMaxMessageSize(own);
    h.maxChunkCount = effectiveMaxChunkCount(own, h.receiveBufferSize);
    h.endpointUrl = std::move(endpointUrl);
    return h;
}

NegotiatedLimits negotiateAsServer(const Hello& hello, const TransportLimits& own,
                                   Acknowledge& ack) {
    if (hello.receiveBufferSize < kMinBufferSize || hello.sendBufferSize < kMinBufferSize) {
        throw TransportError(status::BadConnectionRejected,
                             "Hello buffer sizes below " + std::to_string(kMinBufferSize));
    }
    NegotiatedLimits n;
    n.protocolVersion = kProtocolVersion;
    n.receiveBufferSize =
        std::min(std::max(own.receiveBufferSize, kMinBufferSize), hello.sendBufferSize);
    n.sendBufferSize =
        std::min(std::max(own.sendBufferSize, kMinBufferSize), hello.receiveBufferSize);
    n.maxReceiveMessageSize = effectiveMaxMessageSize(own);
    n.maxReceiveChunkCount = effectiveMaxChunkCount(own, n.receiveBufferSize);
    n.maxSendMessageSize = hello.maxMessageSize;
    n.maxSendChunkCount = hello.maxChunkCount;

    ack.protocolVersion = n.protocolVersion;
    ack.receiveBufferSize = n.receiveBufferSize;
    ack.sendBufferSize = n.sendBufferSize;
    ack.maxMessageSize = n.maxReceiveMessageSize;
    ack.maxChunkCount = n.maxReceiveChunkCount;
    return n;
}

NegotiatedLimits negotiateAsClient(const Hello& sent, const Acknowledge& ack,
                                   const TransportLimits& own) {
    if (ack.protocolVersion > sent.protocolVersion) {
        throw TransportError(status::BadProtocolVersionUnsupported,
                             "server protocol version " + std::to_string(ack.protocolVersion));
    }
    if (ack.receiveBufferSize < kMinBufferSize || ack.sendBufferSize < kMinBufferSize) {
        throw TransportError(status::BadConnectionRejected,
                             "Acknowledge buffer sizes below " + std::to_string(kMinBufferSize));
    }
    NegotiatedLimits n;
    n.protocolVersion = ack.protocolVersion;
    // We accept what our buffer holds, even if the server announced a larger send buffer.
    n.receiveBufferSize = sent.receiveBufferSize;
    n.sendBufferSize = std::min(sent.sendBufferSize, ack.receiveBufferSize);
    n.maxReceiveMessageSize = effectiveMaxMessageSize(own);
    n.maxReceiveChunkCount = sent.maxChunkCount;
    n.maxSendMessageSize = ack.maxMessageSize;
    n.maxSendChunkCount = ack.maxChunkCount;
    return n;
}

}  // namespace pnp::ua::transport
