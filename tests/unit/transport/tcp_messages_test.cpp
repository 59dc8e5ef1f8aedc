// Connection protocol messages (HEL / ACK / ERR / RHE), message header, negotiation, URLs.
#include "ua/transport/tcp_messages.hpp"

#include <gtest/gtest.h>

#include "transport_test_util.hpp"
#include "ua/transport/client_connection.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {
namespace {

using test_util::statusOf;

Byte b(char c) { return static_cast<Byte>(c); }

TEST(TcpMessages, HeaderRoundTrip) {
    Byte h[8];
    encodeMessageHeader(h, MessageType::Message, ChunkType::Intermediate, 1234);
    EXPECT_EQ(0, std::memcmp(h, "MSGC", 4));
    auto d = decodeMessageHeader(h);
    EXPECT_EQ(d.type, MessageType::Message);
    EXPECT_EQ(d.chunkType, ChunkType::Intermediate);
    EXPECT_EQ(d.size, 1234u);
    for (auto t : {MessageType::Hello, MessageType::Acknowledge, MessageType::Error,
                   MessageType::ReverseHello, MessageType::OpenSecureChannel, MessageType::Message,
                   MessageType::CloseSecureChannel}) {
        encodeMessageHeader(h, t, ChunkType::Final, 4096);
        EXPECT_EQ(decodeMessageHeader(h).type, t) << toString(t);
    }
}

TEST(TcpMessages, HeaderRejectsInvalidTypes) {
    Byte garbage[8] = {b('G'), b('E'), b('T'), b(' '), 0, 0, 1, 0};
    EXPECT_EQ(statusOf([&] { decodeMessageHeader(garbage); }), status::BadTcpMessageTypeInvalid);
    Byte badChunk[8];
    encodeMessageHeader(badChunk, MessageType::Message, ChunkType::Final, 100);
    badChunk[3] = b('X');
    EXPECT_EQ(statusOf([&] { decodeMessageHeader(badChunk); }), status::BadTcpMessageTypeInvalid);
    Byte chunkedHello[8];
    encodeMessageHeader(chunkedHello, MessageType::Hello, ChunkType::Intermediate, 100);
    EXPECT_EQ(statusOf([&] { decodeMessageHeader(chunkedHello); }),
              status::BadTcpMessageTypeInvalid);
    Byte tiny[8];
    encodeMessageHeader(tiny, MessageType::Message, ChunkType::Final, 12);
    EXPECT_EQ(statusOf([&] { decodeMessageHeader(tiny); }), status::BadDecodingError);
}

TEST(TcpMessages, HelloRoundTrip) {
    Hello h{0, 65536, 32768, 1 << 24, 300, "opc.tcp://localhost:4840/x"};
    Buffer m = encodeMessage(h);
    ASSERT_EQ(m.size(), 8u + 20 + 4 + h.endpointUrl.size());
    auto hdr = decodeMessageHeader(m.data());
    EXPECT_EQ(hdr.type, MessageType::Hello);
    EXPECT_EQ(hdr.size, m.size());
    EXPECT_EQ(decodeHello(m.data() + 8, m.size() - 8), h);
}

TEST(TcpMessages, AcknowledgeErrorReverseHelloRoundTrip) {
    Acknowledge a{0, 8192, 16384, 1000000, 12};
    Buffer m = encodeMessage(a);
    EXPECT_EQ(m.size(), 28u);
    EXPECT_EQ(decodeAcknowledge(m.data() + 8, m.size() - 8), a);

    ErrorMessage e{status::BadTcpMessageTooLarge, "too big"};
    m = encodeMessage(e);
    EXPECT_EQ(decodeMessageHeader(m.data()).type, MessageType::Error);
    EXPECT_EQ(decodeError(m.data() + 8, m.size() - 8), e);

    ErrorMessage longReason{status::BadTimeout, std::string(10000, 'r')};
    m = encodeMessage(longReason);
    EXPECT_EQ(decodeError(m.data() + 8, m.size() - 8).reason.size(), kMaxReasonLength);

    ReverseHello r{"urn:server", "opc.tcp://h:1"};
    m = encodeMessage(r);
    EXPECT_EQ(decodeReverseHello(m.data() + 8, m.size() - 8), r);
}

TEST(TcpMessages, HelloWithOversizedUrl) {
    Hello h{0, 65536, 65536, 0, 0, std::string(kMaxUrlLength + 1, 'u')};
    EXPECT_EQ(statusOf([&] { encodeMessage(h); }), status::BadTcpEndpointUrlInvalid);
    // Hand-made: the length field says 5000 (more than 4096) - rejected before reading.
    Buffer body(20, 0);
    Int32 len = 5000;
    body.insert(body.end(), reinterpret_cast<Byte*>(&len), reinterpret_cast<Byte*>(&len) + 4);
    body.resize(body.size() + 5000);
    std::fill(body.end() - 5000, body.end(), Byte{'u'});
    EXPECT_EQ(statusOf([&] { decodeHello(body.data(), body.size()); }),
              status::BadTcpEndpointUrlInvalid);
}

TEST(TcpMessages, TruncatedMessages) {
    Hello h{0, 65536, 65536, 0, 0, "opc.tcp://x:1"};
    Buffer m = encodeMessage(h);
    for (std::size_t n = 0; n < m.size() - 8; ++n) {
        EXPECT_EQ(statusOf([&] { decodeHello(m.data() + 8, n); }), status::BadDecodingError) << n;
    }
    // Length field larger than what is there (and below 4096).
    Buffer body(20, 0);
    Int32 len = 4000;
    body.insert(body.end(), reinterpret_cast<Byte*>(&len), reinterpret_cast<Byte*>(&len) + 4);
    body.resize(body.size() + 10, 'u');
    EXPECT_EQ(statusOf([&] { decodeHello(body.data(), body.size()); }), status::BadDecodingError);
    EXPECT_EQ(statusOf([&] { decodeAcknowledge(body.data(), 19); }), status::BadDecodingError);
    EXPECT_EQ(statusOf([&] { decodeError(body.data(), 3); }), status::BadDecodingError);
}

TEST(TcpMessages, NegotiationAsServer) {
    TransportLimits own;
    own.receiveBufferSize = 65536;
    own.sendBufferSize = 65536;
    own.maxMessageSize = 1 << 20;
    own.maxChunkCount = 0;
    Hello h{0, 16384, 32768, 100000, 20, "opc.tcp://x:1"};
    Acknowledge ack;
    NegotiatedLimits n = negotiateAsServer(h, own, ack);
    EXPECT_EQ(n.receiveBufferSize, 32768u);  // min(our receive, client send)
    EXPECT_EQ(n.sendBufferSize, 16384u);     // min(our send, client receive)
    EXPECT_EQ(n.maxSendMessageSize, 100000u);
    EXPECT_EQ(n.maxSendChunkCount, 20u);
    EXPECT_EQ(n.maxReceiveMessageSize, 1u << 20);
    // Derived chunk count: a full message in full chunks (+1).
    EXPECT_EQ(n.maxReceiveChunkCount, (1u << 20) / (32768 - 24) + 2);
    EXPECT_EQ(ack.receiveBufferSize, 32768u);
    EXPECT_EQ(ack.sendBufferSize, 16384u);
    EXPECT_EQ(ack.maxMessageSize, 1u << 20);
    EXPECT_EQ(ack.maxChunkCount, n.maxReceiveChunkCount);
    EXPECT_EQ(ack.protocolVersion, 0u);

    // Any client version is accepted and answered with ours.
    Hello future = h;
    future.protocolVersion = 7;
    EXPECT_EQ(negotiateAsServer(future, own, ack).protocolVersion, 0u);

    Hello small = h;
    small.receiveBufferSize = 1024;
    EXPECT_EQ(statusOf([&] { negotiateAsServer(small, own, ack); }), status::BadConnectionRejected);
}

TEST(TcpMessages, NegotiationAsClient) {
    TransportLimits own;
    own.receiveBufferSize = 8192;
    own.sendBufferSize = 65536;
    own.maxMessageSize = 0;  // default
    Hello h = makeHello(own, "opc.tcp://x:1");
    EXPECT_EQ(h.maxMessageSize, kDefaultMaxMessageSize);
    EXPECT_GT(h.maxChunkCount, 0u);
    Acknowledge ack{0, 16384, 8192, 50000, 10};
    NegotiatedLimits n = negotiateAsClient(h, ack, own);
    EXPECT_EQ(n.sendBufferSize, 16384u);
    EXPECT_EQ(n.receiveBufferSize, 8192u);
    EXPECT_EQ(n.maxSendMessageSize, 50000u);
    EXPECT_EQ(n.maxSendChunkCount, 10u);
    ack.protocolVersion = 1;
    EXPECT_EQ(statusOf([&] { negotiateAsClient(h, ack, own); }),
              status::BadProtocolVersionUnsupported);
}

TEST(EndpointUrl, Parse) {
    auto u = parseEndpointUrl("opc.tcp://localhost:4841/UA/Server");
    EXPECT_EQ(u.host, "localhost");
    EXPECT_EQ(u.port, 4841);
    EXPECT_EQ(u.path, "/UA/Server");
    u = parseEndpointUrl("OPC.TCP://10.0.0.1");
    EXPECT_EQ(u.host, "10.0.0.1");
    EXPECT_EQ(u.port, 4840);
    EXPECT_EQ(u.path, "");
    u = parseEndpointUrl("opc.tcp://[::1]:48010");
    EXPECT_EQ(u.host, "::1");
    EXPECT_EQ(u.port, 48010);
    u = parseEndpointUrl("opc.tcp://host/");
    EXPECT_EQ(u.path, "/");
    for (const char* bad :
         {"http://x:1", "opc.tcp://", "opc.tcp://:4840", "opc.tcp://h:0", "opc.tcp://h:65536",
          "opc.tcp://h:12a", "opc.tcp://[::1", "opc.tcp://h:", "opc.tcp://[::1]x", "opc.tcp:/h"}) {
        EXPECT_EQ(statusOf([&] { parseEndpointUrl(bad); }), status::BadTcpEndpointUrlInvalid)
            << bad;
    }
    EXPECT_EQ(statusOf([&] { parseEndpointUrl("opc.tcp://" + std::string(5000, 'h')); }),
              status::BadTcpEndpointUrlInvalid);
}

}  // namespace
}  // namespace pnp::ua::transport
