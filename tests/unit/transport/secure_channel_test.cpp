// ServerChannel <-> ClientChannel in memory (no sockets, simulated time): handshake,
// requests, chunking, token renewal and expiry, limits, protocol violations.
#include "ua/transport/secure_channel.hpp"

#include <gtest/gtest.h>

#include <deque>
#include <functional>
#include <random>

#include "transport_test_util.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {
namespace {

using test_util::pattern;

using namespace std::chrono_literals;

const NodeId kEchoRequest(1, 1001);
const NodeId kEchoResponse(1, 1002);

Buffer request(const NodeId& type, const Buffer& body) {
    Buffer m = newMessageBuffer();
    BinaryEncoder e(m);
    encode(e, type);
    e.raw(body.data(), body.size());
    return m;
}

struct ServerSide : ServerChannel::Hooks {
    std::deque<Buffer>* out = nullptr;
    std::function<void(const IncomingRequest&)> onRequest;
    UInt32 nextChannel = 4711;
    void write(Buffer&& b) override { out->push_back(std::move(b)); }
    void request(const IncomingRequest& r) override {
        if (onRequest) onRequest(r);
    }
    UInt32 newChannelId() override { return nextChannel++; }
};

struct ClientSide : ClientChannel::Hooks {
    std::deque<Buffer>* out = nullptr;
    std::vector<IncomingResponse> responses;
    void write(Buffer&& b) override { out->push_back(std::move(b)); }
    void response(IncomingResponse&& r) override { responses.push_back(std::move(r)); }
};

// The chunks of one direction, split into messages of the connection protocol.
std::vector<Buffer> chunksOf(const std::deque<Buffer>& writes) {
    Buffer all;
    for (const auto& w : writes) all.insert(all.end(), w.begin(), w.end());
    std::vector<Buffer> out;
    std::size_t off = 0;
    while (off + 8 <= all.size()) {
        UInt32 size = getUInt32(all.data() + off + 4);
        out.emplace_back(all.begin() + off, all.begin() + off + size);
        off += size;
    }
    return out;
}

class ChannelPair : public ::testing::Test {
  protected:
    void SetUp() override {
        scfg.receiveBufferSize = 8192;
        scfg.sendBufferSize = 8192;
        scfg.maxMessageSize = 4 << 20;
        scfg.minTokenLifetime = 1000ms;
        scfg.maxTokenLifetime = 60000ms;
        ccfg.receiveBufferSize = 8192;
        ccfg.sendBufferSize = 8192;
        ccfg.maxMessageSize = 4 << 20;
        ccfg.requestedLifetime = 10000ms;
    }

    void create() {
        ss.out = &toClient;
        cs.out = &toServer;
        ss.onRequest = [this](const IncomingRequest& r) {
            requests.push_back(r.requestId);
            if (!echo) return;
            Buffer m = newMessageBuffer();
            BinaryEncoder e(m);
            encode(e, kEchoResponse);
            e.raw(r.body, r.size);
            server->send(r.requestId, std::move(m));
        };
        server = std::make_unique<ServerChannel>(scfg, ss, now);
        client = std::make_unique<ClientChannel>(ccfg, "opc.tcp://test:4840", cs);
    }

    void open() {
        create();
        client->start(now);
        pump();
        ASSERT_TRUE(client->isOpen());
        ASSERT_EQ(server->state(), ServerChannel::State::Open);
    }

    // Delivers the queued bytes both ways until nothing moves (optionally byte by byte).
    void pump(std::size_t slice = 0) {
        while (!toServer.empty() || !toClient.empty()) {
            if (!toServer.empty()) {
                Buffer b = std::move(toServer.front());
                toServer.pop_front();
                sentToServer.push_back(b);
                feed(b, slice, [&](const Byte* p, std::size_t n) { server->feed(p, n, now); });
            }
            if (!toClient.empty()) {
                Buffer b = std::move(toClient.front());
                toClient.pop_front();
                sentToClient.push_back(b);
                try {
                    feed(b, slice, [&](const Byte* p, std::size_t n) { client->feed(p, n, now); });
                } catch (const TransportError& e) {
                    clientError = e.status();
                }
            }
        }
    }
    template <class F>
    void feed(const Buffer& b, std::size_t slice, F&& f) {
        if (slice == 0) {
            f(b.data(), b.size());
            return;
        }
        for (std::size_t off = 0; off < b.size(); off += slice)
            f(b.data() + off, std::min(slice, b.size() - off));
    }

    // The ERR the server sent last (Good when none).
    StatusCode serverError() {
        for (auto& c : chunksOf(sentToClient)) {
            if (decodeMessageHeader(c.data()).type == MessageType::Error)
                return decodeError(c.data() + 8, c.size() - 8).error;
        }
        return StatusCode{};
    }

    // Hand-made MSG chunk on the open channel.
    Buffer rawMsg(UInt32 seq, UInt32 req, const Buffer& body, ChunkType ct = ChunkType::Final,
                  std::optional<UInt32> channel = {}, std::optional<UInt32> token = {},
                  MessageType t = MessageType::Message) {
        Buffer m = request(kEchoRequest, body);
        encodeMessageHeader(m.data(), t, ct, static_cast<UInt32>(m.size()));
        putUInt32(m.data() + 8, channel.value_or(client->channelId()));
        putUInt32(m.data() + 12, token.value_or(client->currentTokenId()));
        putUInt32(m.data() + 16, seq);
        putUInt32(m.data() + 20, req);
        return m;
    }
    void toServerRaw(const Buffer& b) { server->feed(b.data(), b.size(), now); }
    // A response message: the start of a ResponseHeader (Timestamp, RequestHandle) and
    // `extra` more bytes.
    static Buffer responseWithHandle(UInt32 requestHandle, std::size_t extra) {
        Buffer m = newMessageBuffer();
        BinaryEncoder e(m);
        encode(e, kEchoResponse);
        encode(e, DateTime::now());
        encode(e, requestHandle);
        m.resize(m.size() + extra);
        return m;
    }

    ServerTransportConfig scfg;
    ClientConfig ccfg;
    TimePoint now = Clock::now();
    ServerSide ss;
    ClientSide cs;
    std::unique_ptr<ServerChannel> server;
    std::unique_ptr<ClientChannel> client;
    std::deque<Buffer> toServer, toClient, sentToServer, sentToClient;
    std::vector<UInt32> requests;
    bool echo = true;
    StatusCode clientError;
};

TEST_F(ChannelPair, HandshakeAndEcho) {
    open();
    EXPECT_EQ(client->channelId(), 4711u);
    EXPECT_EQ(server->channelId(), 4711u);
    EXPECT_EQ(server->endpointUrl(), "opc.tcp://test:4840");
    EXPECT_EQ(client->revisedLifetime(), 10000ms);
    Buffer body = pattern(300);
    UInt32 id = client->send(request(kEchoRequest, body));
    pump();
    ASSERT_EQ(cs.responses.size(), 1u);
    EXPECT_EQ(cs.responses[0].requestId, id);
    EXPECT_EQ(cs.responses[0].typeId, kEchoResponse);
    EXPECT_EQ(cs.responses[0].body, body);
    EXPECT_TRUE(cs.responses[0].status.isGood());
}

// Large single-chunk responses one after the other and back to back: every body intact.
TEST_F(ChannelPair, LargeSingleChunkBodies) {
    open();
    for (int round = 0; round < 3; ++round) {
        Buffer small = pattern(100, static_cast<Byte>(round));
        Buffer large = pattern(6000, static_cast<Byte>(round + 7));
        client->send(request(kEchoRequest, large));
        pump();
        client->send(request(kEchoRequest, small));
        pump();
        ASSERT_EQ(cs.responses.size(), 2u * (round + 1));
        EXPECT_EQ(cs.responses[2 * round].body, large);
        EXPECT_EQ(cs.responses[2 * round + 1].body, small);
    }
    // Back-to-back requests: both responses intact.
    Buffer a = pattern(5000, 1), b = pattern(5000, 2);
    client->send(request(kEchoRequest, a));
    client->send(request(kEchoRequest, b));
    pump();
    ASSERT_EQ(cs.responses.size(), 8u);
    EXPECT_EQ(cs.responses[6].body, a);
    EXPECT_EQ(cs.responses[7].body, b);
}

TEST_F(ChannelPair, EverythingFedByteByByte) {
    create();
    client->start(now);
    pump(1);
    ASSERT_TRUE(client->isOpen());
    Buffer big = pattern(30000, 3);
    UInt32 a = client->send(request(kEchoRequest, pattern(10)));
    UInt32 b = client->send(request(kEchoRequest, big));
    pump(1);
    ASSERT_EQ(cs.responses.size(), 2u);
    EXPECT_EQ(cs.responses[0].requestId, a);
    EXPECT_EQ(cs.responses[1].requestId, b);
    EXPECT_EQ(cs.responses[1].body, big);
}

TEST_F(ChannelPair, MultiChunkOneMiB) {
    open();
    Buffer body = pattern(1 << 20, 7);
    client->send(request(kEchoRequest, body));
    EXPECT_GT(chunksOf(toServer).size(), 128u);  // 8192-byte chunks
    pump(5000);
    ASSERT_EQ(cs.responses.size(), 1u);
    EXPECT_EQ(cs.responses[0].body, body);
}

TEST_F(ChannelPair, RenewKeepsOldTokenUntilClientUsesNewOne) {
    open();
    const UInt32 first = client->currentTokenId();
    EXPECT_FALSE(client->renewIfDue(now));
    now += 7600ms;  // > 75 % of 10 s
    // Request A leaves with the old token before the renewal.
    UInt32 a = client->send(request(kEchoRequest, pattern(5)));
    echo = false;
    pump();  // server got A, does not answer yet
    ASSERT_TRUE(client->renewIfDue(now));
    EXPECT_TRUE(client->renewPending());
    pump();
    EXPECT_FALSE(client->renewPending());
    const UInt32 second = client->currentTokenId();
    EXPECT_NE(first, second);
    EXPECT_EQ(server->currentTokenId(), second);
    // The server answers A with the old token (the client has not used the new one yet).
    Buffer resp = newMessageBuffer();
    BinaryEncoder e(resp);
    encode(e, kEchoResponse);
    server->send(a, std::move(resp));
    auto chunks = chunksOf(toClient);
    ASSERT_EQ(chunks.size(), 1u);
    EXPECT_EQ(getUInt32(chunks[0].data() + 12), first);
    pump();
    ASSERT_EQ(cs.responses.size(), 1u);  // the client accepts the previous token
    // Request B with the new token: from now on the server uses the new token too.
    echo = true;
    client->send(request(kEchoRequest, pattern(5)));
    pump();
    ASSERT_EQ(cs.responses.size(), 2u);
    auto last = chunksOf(sentToClient).back();
    EXPECT_EQ(getUInt32(last.data() + 12), second);
    // The old token is no longer accepted by the server.
    toServerRaw(rawMsg(5, 99, pattern(3), ChunkType::Final, {}, first));
    EXPECT_TRUE(server->isClosed());
    EXPECT_EQ(server->closeStatus(), status::BadSecureChannelTokenUnknown);
}

TEST_F(ChannelPair, TokenExpiresWithoutRenewal) {
    open();
    now += 12000ms;  // lifetime 10 s, tolerance 25 %: still open
    server->tick(now);
    EXPECT_FALSE(server->isClosed());
    now += 1000ms;
    server->tick(now);
    EXPECT_TRUE(server->isClosed());
    EXPECT_EQ(server->closeStatus(), status::BadSecureChannelClosed);
    pump();
    EXPECT_EQ(clientError, status::BadSecureChannelClosed);
    EXPECT_EQ(client->state(), ClientChannel::State::Closed);
}

TEST_F(ChannelPair, LifetimeIsClamped) {
    ccfg.requestedLifetime = 10ms;
    open();
    EXPECT_EQ(client->revisedLifetime(), 1000ms);
    ccfg.requestedLifetime = std::chrono::hours(100);
    toServer.clear();
    toClient.clear();
    open();
    EXPECT_EQ(client->revisedLifetime(), 60000ms);
}

TEST_F(ChannelPair, HelloTimeout) {
    scfg.helloTimeout = 500ms;
    create();
    now += 400ms;
    server->tick(now);
    EXPECT_FALSE(server->isClosed());
    now += 200ms;
    server->tick(now);
    EXPECT_TRUE(server->isClosed());
    EXPECT_EQ(serverError(), StatusCode{});  // written, not yet pumped
    pump();
    EXPECT_EQ(serverError(), status::BadTimeout);
}

TEST_F(ChannelPair, IdleTimeout) {
    scfg.idleTimeout = 1000ms;
    open();
    now += 900ms;
    server->tick(now);
    EXPECT_FALSE(server->isClosed());
    client->send(request(kEchoRequest, pattern(1)));
    pump();
    now += 900ms;
    server->tick(now);
    EXPECT_FALSE(server->isClosed());
    now += 200ms;
    server->tick(now);
    EXPECT_EQ(server->closeStatus(), status::BadTimeout);
}

TEST_F(ChannelPair, ResponseTooLargeBecomesServiceFault) {
    ccfg.maxMessageSize = 50000;
    open();
    echo = false;
    client->send(request(kEchoRequest, pattern(1)));
    pump();
    ASSERT_EQ(requests.size(), 1u);
    // A "response" with a ResponseHeader (Timestamp, RequestHandle 777) and a big body.
    EXPECT_TRUE(server->send(requests[0], responseWithHandle(777, 60000)));
    pump();
    ASSERT_EQ(cs.responses.size(), 1u);
    EXPECT_EQ(cs.responses[0].typeId, NodeId(0, DataTypeInfo<ServiceFault>::binaryEncodingId));
    auto fault =
        decodeFromBuffer<ServiceFault>(cs.responses[0].body.data(), cs.responses[0].body.size());
    EXPECT_EQ(fault.responseHeader.serviceResult, status::BadResponseTooLarge);
    EXPECT_EQ(fault.responseHeader.requestHandle, 777u);
    EXPECT_TRUE(client->isOpen());
}

TEST_F(ChannelPair, RequestTooLargeIsRejectedByTheClient) {
    scfg.maxMessageSize = 20000;
    open();
    try {
        client->send(request(kEchoRequest, pattern(30000)));
        FAIL() << "no exception";
    } catch (const TransportError& e) {
        EXPECT_EQ(e.status(), status::BadRequestTooLarge);
    }
    EXPECT_TRUE(toServer.empty());
    client->send(request(kEchoRequest, pattern(100)));
    pump();
    EXPECT_EQ(cs.responses.size(), 1u);
}

TEST_F(ChannelPair, ServerEnforcesMessageSizeAgainstLyingClient) {
    scfg.maxMessageSize = 20000;
    open();
    // Chunks of a client that ignores the Acknowledge: 3 x 8000 bytes > 20000.
    toServerRaw(rawMsg(2, 50, pattern(8000), ChunkType::Intermediate));
    toServerRaw(rawMsg(3, 50, pattern(8000), ChunkType::Intermediate));
    EXPECT_FALSE(server->isClosed());
    toServerRaw(rawMsg(4, 50, pattern(8000), ChunkType::Final));
    EXPECT_EQ(server->closeStatus(), status::BadTcpMessageTooLarge);
    EXPECT_TRUE(requests.empty());
}

TEST_F(ChannelPair, ServerEnforcesChunkCount) {
    scfg.maxChunkCount = 3;
    open();
    for (UInt32 i = 0; i < 3; ++i)
        toServerRaw(rawMsg(2 + i, 50, pattern(10), ChunkType::Intermediate));
    EXPECT_FALSE(server->isClosed());
    toServerRaw(rawMsg(5, 50, pattern(10), ChunkType::Final));
    EXPECT_EQ(server->closeStatus(), status::BadTcpMessageTooLarge);
}

TEST_F(ChannelPair, AbortChunkDiscardsPartialRequest) {
    open();
    toServerRaw(rawMsg(2, 50, pattern(100), ChunkType::Intermediate));
    Buffer abortBody(8);
    putUInt32(abortBody.data(), status::BadRequestCancelledByClient.value);
    Buffer ab = rawMsg(3, 50, {}, ChunkType::Abort);
    ab.resize(kSymmetricHeaderSize);
    ab.insert(ab.end(), abortBody.begin(), abortBody.end());
    encodeMessageHeader(ab.data(), MessageType::Message, ChunkType::Abort,
                        static_cast<UInt32>(ab.size()));
    toServerRaw(ab);
    EXPECT_FALSE(server->isClosed());
    EXPECT_TRUE(requests.empty());
    toServerRaw(rawMsg(4, 51, pattern(10)));
    EXPECT_FALSE(server->isClosed());
    ASSERT_EQ(requests.size(), 1u);
    EXPECT_EQ(requests[0], 51u);
}

TEST_F(ChannelPair, WrongSequenceNumber) {
    open();
    toServerRaw(rawMsg(2, 1, pattern(1)));
    toServerRaw(rawMsg(4, 2, pattern(1)));
    EXPECT_EQ(server->closeStatus(), status::BadSequenceNumberInvalid);
    EXPECT_EQ(requests.size(), 1u);
}

TEST_F(ChannelPair, WrongChannelId) {
    open();
    toServerRaw(rawMsg(2, 1, pattern(1), ChunkType::Final, client->channelId() + 1));
    EXPECT_EQ(server->closeStatus(), status::BadSecureChannelIdInvalid);
}

TEST_F(ChannelPair, WrongTokenId) {
    open();
    toServerRaw(rawMsg(2, 1, pattern(1), ChunkType::Final, {}, 12345));
    EXPECT_EQ(server->closeStatus(), status::BadSecureChannelTokenUnknown);
}

TEST_F(ChannelPair, MessageBeforeOpen) {
    create();
    toServerRaw(encodeMessage(makeHello(ccfg, "opc.tcp://x:1")));
    Buffer m = request(kEchoRequest, pattern(5));
    encodeMessageHeader(m.data(), MessageType::Message, ChunkType::Final,
                        static_cast<UInt32>(m.size()));
    toServerRaw(m);
    EXPECT_EQ(server->closeStatus(), status::BadTcpMessageTypeInvalid);
}

TEST_F(ChannelPair, OpenBeforeHello) {
    create();
    Buffer body = pattern(10);
    toServerRaw(makeOpenChunk(0, 1, 1, body.data(), body.size()));
    EXPECT_EQ(server->closeStatus(), status::BadTcpMessageTypeInvalid);
}

TEST_F(ChannelPair, SecondHello) {
    open();
    toServerRaw(encodeMessage(makeHello(ccfg, "opc.tcp://x:1")));
    EXPECT_EQ(server->closeStatus(), status::BadTcpMessageTypeInvalid);
}

TEST_F(ChannelPair, ClientSendsAcknowledge) {
    create();
    toServerRaw(encodeMessage(Acknowledge{0, 8192, 8192, 0, 0}));
    EXPECT_EQ(server->closeStatus(), status::BadTcpMessageTypeInvalid);
}

// OPN requests with wrong parameters.
class OpenRequestTest : public ChannelPair {
  protected:
    StatusCode openWith(std::function<void(OpenSecureChannelRequest&)> change,
                        std::string policy = std::string(kSecurityPolicyNone)) {
        create();
        toServerRaw(encodeMessage(makeHello(ccfg, "opc.tcp://x:1")));
        OpenSecureChannelRequest req;
        req.requestType = SecurityTokenRequestType::Issue;
        req.securityMode = MessageSecurityMode::None;
        req.requestedLifetime = 5000;
        change(req);
        Buffer body;
        BinaryEncoder e(body);
        encode(e, NodeId(0, DataTypeInfo<OpenSecureChannelRequest>::binaryEncodingId));
        encode(e, req);
        Buffer chunk = makeOpenChunk(0, 1, 1, body.data(), body.size());
        if (policy != kSecurityPolicyNone) {
            // Rebuild with another policy URI.
            Buffer c(12);
            encodeMessageHeader(c.data(), MessageType::OpenSecureChannel, ChunkType::Final, 0);
            BinaryEncoder ce(c);
            ce.lengthPrefixed(policy);
            ce.number(Int32{-1});
            ce.number(Int32{-1});
            ce.number(UInt32{1});
            ce.number(UInt32{1});
            ce.raw(body.data(), body.size());
            putUInt32(c.data() + 4, static_cast<UInt32>(c.size()));
            chunk = c;
        }
        toServerRaw(chunk);
        return server->isClosed() ? server->closeStatus() : StatusCode{};
    }
};

TEST_F(OpenRequestTest, Valid) {
    EXPECT_EQ(openWith([](auto&) {}), StatusCode{});
}

// Found by the fuzzer: a client whose MaxMessageSize is smaller than even a ServiceFault
// made send() and sendServiceFault() call each other until the stack overflowed.
TEST_F(OpenRequestTest, NotEvenAServiceFaultFitsClosesTheChannel) {
    ccfg.maxMessageSize = 24;
    ASSERT_EQ(openWith([](auto&) {}), StatusCode{});
    echo = false;
    toServerRaw(
        rawMsg(2, 7, pattern(1), ChunkType::Final, server->channelId(), server->currentTokenId()));
    ASSERT_EQ(requests.size(), 1u);
    EXPECT_FALSE(server->send(requests[0], responseWithHandle(778, 100)));
    EXPECT_TRUE(server->isClosed());
    EXPECT_EQ(server->closeStatus(), status::BadResponseTooLarge);
}
TEST_F(OpenRequestTest, RenewBeforeIssue) {
    EXPECT_EQ(openWith([](auto& r) { r.requestType = SecurityTokenRequestType::Renew; }),
              status::BadRequestTypeInvalid);
}
TEST_F(OpenRequestTest, SecurityModeSign) {
    EXPECT_EQ(openWith([](auto& r) { r.securityMode = MessageSecurityMode::Sign; }),
              status::BadSecurityModeRejected);
}
TEST_F(OpenRequestTest, ProtocolVersion) {
    EXPECT_EQ(openWith([](auto& r) { r.clientProtocolVersion = 3; }),
              status::BadProtocolVersionUnsupported);
}
TEST_F(OpenRequestTest, SecurityPolicy) {
    EXPECT_EQ(openWith([](auto&) {}, "http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256"),
              status::BadSecurityPolicyRejected);
}

TEST_F(ChannelPair, IssueOnOpenChannel) {
    open();
    OpenSecureChannelRequest req;
    req.requestType = SecurityTokenRequestType::Issue;
    req.securityMode = MessageSecurityMode::None;
    Buffer body;
    BinaryEncoder e(body);
    encode(e, NodeId(0, DataTypeInfo<OpenSecureChannelRequest>::binaryEncodingId));
    encode(e, req);
    toServerRaw(makeOpenChunk(client->channelId(), 2, 9, body.data(), body.size()));
    EXPECT_EQ(server->closeStatus(), status::BadRequestTypeInvalid);
}

TEST_F(ChannelPair, CloseIsSilent) {
    open();
    client->close();
    pump();
    EXPECT_TRUE(server->isClosed());
    EXPECT_EQ(server->closeStatus(), StatusCode{});
    EXPECT_EQ(serverError(), StatusCode{});
}

TEST_F(ChannelPair, ClientRejectsBadServerChunks) {
    open();
    // A MSG from the "server" with another channel id.
    Buffer m = request(kEchoResponse, pattern(4));
    encodeMessageHeader(m.data(), MessageType::Message, ChunkType::Final,
                        static_cast<UInt32>(m.size()));
    putUInt32(m.data() + 8, client->channelId() + 1);
    putUInt32(m.data() + 12, client->currentTokenId());
    putUInt32(m.data() + 16, 2);
    putUInt32(m.data() + 20, 1);
    try {
        client->feed(m.data(), m.size(), now);
        FAIL() << "no exception";
    } catch (const TransportError& e) {
        EXPECT_EQ(e.status(), status::BadSecureChannelIdInvalid);
    }
    EXPECT_EQ(client->state(), ClientChannel::State::Closed);
    // The client said goodbye with a CLO.
    auto sent = chunksOf(toServer);
    ASSERT_FALSE(sent.empty());
    EXPECT_EQ(decodeMessageHeader(sent.back().data()).type, MessageType::CloseSecureChannel);
}

TEST_F(ChannelPair, ClientReceivesAbortedResponse) {
    open();
    UInt32 id = client->send(request(kEchoRequest, pattern(1)));
    toServer.clear();
    Buffer ab(kSymmetricHeaderSize + 8);
    encodeMessageHeader(ab.data(), MessageType::Message, ChunkType::Abort,
                        static_cast<UInt32>(ab.size()));
    putUInt32(ab.data() + 8, client->channelId());
    putUInt32(ab.data() + 12, client->currentTokenId());
    putUInt32(ab.data() + 16, 2);
    putUInt32(ab.data() + 20, id);
    putUInt32(ab.data() + 24, status::BadResponseTooLarge.value);
    putUInt32(ab.data() + 28, 0xFFFFFFFFu);
    client->feed(ab.data(), ab.size(), now);
    ASSERT_EQ(cs.responses.size(), 1u);
    EXPECT_EQ(cs.responses[0].requestId, id);
    EXPECT_EQ(cs.responses[0].status, status::BadResponseTooLarge);
    EXPECT_TRUE(client->isOpen());
}

TEST_F(ChannelPair, ClientReportsServerError) {
    create();
    client->start(now);
    Buffer err = encodeMessage(ErrorMessage{status::BadTcpServerTooBusy, "busy"});
    try {
        client->feed(err.data(), err.size(), now);
        FAIL() << "no exception";
    } catch (const TransportError& e) {
        EXPECT_EQ(e.status(), status::BadTcpServerTooBusy);
        EXPECT_NE(std::string(e.what()).find("busy"), std::string::npos);
    }
    EXPECT_EQ(client->state(), ClientChannel::State::Closed);
}

// Mutated client byte streams: the server channel never throws, never delivers a request
// after an error, and every close comes with an ERR (or is a clean CLO).
TEST_F(ChannelPair, MutatedStreamsAreRejectedCleanly) {
    open();
    client->send(request(kEchoRequest, pattern(100)));
    client->send(request(kEchoRequest, pattern(20000, 2)));  // 3 chunks
    client->renewIfDue(now + 8s);
    client->send(request(kEchoRequest, pattern(10, 3)));
    client->close();
    Buffer stream;
    for (auto& b : toServer) stream.insert(stream.end(), b.begin(), b.end());
    toServer.clear();
    // sentToServer holds HEL and OPN of open().
    Buffer full;
    for (auto& b : sentToServer) full.insert(full.end(), b.begin(), b.end());
    full.insert(full.end(), stream.begin(), stream.end());

    std::mt19937 rng(12345);
    int closedWithError = 0, survived = 0;
    for (int iter = 0; iter < 3000; ++iter) {
        Buffer m = full;
        switch (rng() % 4) {
            case 0:  // flip bytes
                for (unsigned k = 0, n = 1 + rng() % 4; k < n; ++k)
                    m[rng() % m.size()] ^= 1u << (rng() % 8);
                break;
            case 1:  // overwrite a UInt32 with an extreme value
            {
                std::size_t at = rng() % (m.size() - 4);
                UInt32 v = (rng() % 2) ? 0xFFFFFFFFu : 0x80000000u + (rng() % 1000);
                putUInt32(m.data() + at, v);
                break;
            }
            case 2:  // truncate
                m.resize(rng() % m.size());
                break;
            default:  // insert junk
            {
                Buffer junk = pattern(1 + rng() % 40, static_cast<unsigned>(iter));
                m.insert(m.begin() + static_cast<std::ptrdiff_t>(rng() % m.size()), junk.begin(),
                         junk.end());
            }
        }
        std::deque<Buffer> out;
        ServerSide side;
        side.out = &out;
        ServerChannel ch(scfg, side, now);
        std::size_t slice = 1 + rng() % 3000;
        for (std::size_t off = 0; off < m.size(); off += slice)
            ch.feed(m.data() + off, std::min(slice, m.size() - off), now);
        if (ch.isClosed()) {
            if (ch.closeStatus().isBad()) {
                ++closedWithError;
                auto chunks = chunksOf(out);
                ASSERT_FALSE(chunks.empty());
                EXPECT_EQ(decodeMessageHeader(chunks.back().data()).type, MessageType::Error);
            }
        } else {
            ++survived;
        }
    }
    EXPECT_GT(closedWithError, 500);
    std::printf("[ mutation ] %d rejected with ERR, %d still open\n", closedWithError, survived);
}

}  // namespace
}  // namespace pnp::ua::transport
