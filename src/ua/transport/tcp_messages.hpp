// OPC UA Connection Protocol messages (OPC 10000-6 §7.1.2): the 8-byte message header and
// the Hello, Acknowledge, Error and ReverseHello messages, plus the buffer negotiation.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

#include "ua/transport/common.hpp"

namespace pnp::ua::transport {

enum class MessageType : Byte {
    Hello,               // "HEL"
    Acknowledge,         // "ACK"
    Error,               // "ERR"
    ReverseHello,        // "RHE"
    OpenSecureChannel,   // "OPN"
    Message,             // "MSG"
    CloseSecureChannel,  // "CLO"
};
std::string_view toString(MessageType t);  // "HEL", ...

enum class ChunkType : char { Final = 'F', Intermediate = 'C', Abort = 'A' };

inline constexpr std::size_t kMessageHeaderSize = 8;
// Message header + SecureChannelId + TokenId + SequenceNumber + RequestId: everything in
// front of the body of a MSG / CLO chunk (SecurityPolicy None: no padding, no signature).
inline constexpr std::size_t kSymmetricHeaderSize = 24;
// Part 6 §7.1.2.3 / §7.1.2.5: EndpointUrl and Reason are at most 4096 bytes.
inline constexpr std::size_t kMaxUrlLength = 4096;
inline constexpr std::size_t kMaxReasonLength = 4096;

struct MessageHeader {
    MessageType type = MessageType::Message;
    ChunkType chunkType = ChunkType::Final;
    UInt32 size = 0;  // whole chunk including these 8 bytes
};

// Reads the 8 bytes at p. Throws TransportError(BadTcpMessageTypeInvalid) for an unknown
// message type or chunk type, or a chunk type other than 'F' on HEL/ACK/ERR/RHE, and
// TransportError(BadDecodingError) for a size smaller than the smallest valid message of
// that type. The upper bound of the size is checked by the caller (ChunkReader).
MessageHeader decodeMessageHeader(const Byte* p);
void encodeMessageHeader(Byte* p, MessageType type, ChunkType chunkType, UInt32 size);
// Smallest chunk size (header included) of a message type.
std::size_t minimumChunkSize(MessageType type);

struct Hello {
    UInt32 protocolVersion = kProtocolVersion;
    UInt32 receiveBufferSize = 0;
    UInt32 sendBufferSize = 0;
    UInt32 maxMessageSize = 0;  // 0: no limit
    UInt32 maxChunkCount = 0;   // 0: no limit
    std::string endpointUrl;
    bool operator==(const Hello&) const = default;
};

struct Acknowledge {
    UInt32 protocolVersion = kProtocolVersion;
    UInt32 receiveBufferSize = 0;
    UInt32 sendBufferSize = 0;
    UInt32 maxMessageSize = 0;
    UInt32 maxChunkCount = 0;
    bool operator==(const Acknowledge&) const = default;
};

struct ErrorMessage {
    StatusCode error;
    std::string reason;
    bool operator==(const ErrorMessage&) const = default;
};

struct ReverseHello {
    std::string serverUri;
    std::string endpointUrl;
    bool operator==(const ReverseHello&) const = default;
};

// Complete messages, header included. Strings longer than 4096 bytes are truncated
// (Reason) or rejected with TransportError(BadTcpEndpointUrlInvalid) (URLs).
Buffer encodeMessage(const Hello& m);
Buffer encodeMessage(const Acknowledge& m);
Buffer encodeMessage(const ErrorMessage& m);
Buffer encodeMessage(const ReverseHello& m);

// Decode the bytes after the 8-byte header. Throw TransportError: BadDecodingError when
// truncated, BadTcpEndpointUrlInvalid for an EndpointUrl longer than 4096 bytes (checked
// before anything is allocated). Trailing bytes are ignored (newer protocol versions may
// append fields).
Hello decodeHello(const Byte* body, std::size_t size);
Acknowledge decodeAcknowledge(const Byte* body, std::size_t size);
ErrorMessage decodeError(const Byte* body, std::size_t size);
ReverseHello decodeReverseHello(const Byte* body, std::size_t size);

// The chunk count limit actually enforced for `limits` with a given receive buffer size:
// limits.maxChunkCount, or when 0 enough full chunks for a message of maxMessageSize.
UInt32 effectiveMaxChunkCount(const TransportLimits& limits, UInt32 receiveBufferSize);
UInt32 effectiveMaxMessageSize(const TransportLimits& limits);

// The Hello a client with `own` limits sends.
Hello makeHello(const TransportLimits& own, std::string endpointUrl);

// Server side (§7.1.2.4): fills `ack` and returns the connection's limits. The receive /
// send buffers are the minimum of both sides. Throws TransportError(BadConnectionRejected)
// when the client's buffers are smaller than 8192 bytes. Any client protocol version is
// accepted ("receivers always accept numbers greater than the latest version that they
// support"); we answer with ours (0).
NegotiatedLimits negotiateAsServer(const Hello& hello, const TransportLimits& own,
                                   Acknowledge& ack);

// Client side: the limits after the server's Acknowledge to our Hello. Throws
// TransportError(BadProtocolVersionUnsupported) when the server answers with a version newer
// than ours, BadConnectionRejected when its buffers are below 8192 bytes.
NegotiatedLimits negotiateAsClient(const Hello& sent, const Acknowledge& ack,
                                   const TransportLimits& own);

}  // namespace pnp::ua::transport
