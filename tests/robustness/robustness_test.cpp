// Robustness of the whole stack against hostile and broken peers, over real sockets on
// 127.0.0.1 (ephemeral port).
//
// One server::Server (a variable, a constant and an asynchronous method) runs for the whole
// suite, and a "bystander" client::Client stays connected throughout: its own thread reads a
// value every few milliseconds (and calls the asynchronous method now and then) and counts
// every answer. Each test runs one attack on its own raw TCP connections; after each test
// the bystander must have seen no failure and must still be served. Every loop is bounded
// in count and in time.
//
// ctest runs the binary as ONE test (tests/robustness/CMakeLists.txt) so that the bystander
// spans every attack.
#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "support/loopback_server.hpp"
#include "support/raw_socket.hpp"
#include "ua/client/client.hpp"
#include "ua/server/server.hpp"
#include "ua/transport/client_connection.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua {
namespace {

namespace tp = transport;
using namespace std::chrono_literals;
using tp::Clock;
using tp::Deadline;

constexpr auto kHelloTimeout = 1000ms;
constexpr UInt32 kReceiveBufferSize = 8192;
constexpr UInt32 kMaxMessageSize = 256 * 1024;
constexpr UInt32 kMaxChunkCount = 64;
// Server-wide bytes of incomplete messages: room for one large partial message, not two.
constexpr std::size_t kIncompleteBudget = kMaxMessageSize * 3 / 2;
constexpr Int32 kConstant = 4711;

template <class T>
NodeId encodingId() {
    return NodeId(0, DataTypeInfo<T>::binaryEncodingId);
}

// ---- completes method calls later, on its own thread ----------------------------------------
class LateCompleter {
  public:
    LateCompleter() : thread_([this] { run(); }) {}
    ~LateCompleter() {
        {
            std::lock_guard lock(mutex_);
            stop_ = true;
        }
        cv_.notify_one();
        thread_.join();
        for (auto& e : queue_) e.done.fail(status::BadShutdown);
    }
    void add(std::chrono::milliseconds delay, server::MethodCompletion done,
             std::vector<Variant> outputs) {
        {
            std::lock_guard lock(mutex_);
            queue_.push_back({Clock::now() + delay, std::move(done), std::move(outputs)});
        }
        cv_.notify_one();
    }

  private:
    struct Entry {
        Clock::time_point due;
        server::MethodCompletion done;
        std::vector<Variant> outputs;
    };
    void run() {
        std::unique_lock lock(mutex_);
        while (!stop_) {
            if (queue_.empty()) {
                cv_.wait(lock);
                continue;
            }
            if (Clock::now() < queue_.front().due) {
                cv_.wait_until(lock, queue_.front().due);
                continue;
            }
            Entry e = std::move(queue_.front());
            queue_.pop_front();
            lock.unlock();
            e.done.succeed(std::move(e.outputs));
            lock.lock();
        }
    }

    std::mutex mutex_;
    std::condition_variable cv_;
    std::deque<Entry> queue_;  // same delay for every entry: ordered by due time
    bool stop_ = false;
    std::thread thread_;
};

// ---- a raw TCP connection: tests/support/raw_socket.hpp ----
using test::RawSocket;

// HEL/ACK and OpenSecureChannel by hand, then hand-made MSG chunks.
class RawChannel {
  public:
    explicit RawChannel(UInt16 port) : sock(port) {}

    bool open(UInt32 bufferSize = kReceiveBufferSize) {
        if (!sock.ok()) return false;
        tp::Hello hello;
        hello.receiveBufferSize = bufferSize;
        hello.sendBufferSize = bufferSize;
        hello.endpointUrl = "opc.tcp://127.0.0.1/";
        if (!sock.send(tp::encodeMessage(hello))) return false;
        auto ack = sock.readChunk();
        if (!ack || tp::decodeMessageHeader(ack->data()).type != tp::MessageType::Acknowledge)
            return false;
        limits = tp::decodeAcknowledge(ack->data() + 8, ack->size() - 8);

        OpenSecureChannelRequest req;
        req.requestHeader.timestamp = DateTime::now();
        req.requestType = SecurityTokenRequestType::Issue;
        req.securityMode = MessageSecurityMode::None;
        req.requestedLifetime = 600'000;
        Buffer body;
        BinaryEncoder e(body);
        encode(e, encodingId<OpenSecureChannelRequest>());
        encode(e, req);
        if (!sock.send(tp::makeOpenChunk(0, seq_++, requestId_++, body.data(), body.size())))
            return false;
        auto opn = sock.readChunk();
        if (!opn) return false;
        auto h = tp::decodeMessageHeader(opn->data());
        if (h.type != tp::MessageType::OpenSecureChannel) return false;
        auto c = tp::parseSecureChunk(tp::RawChunk{h, opn->data(), opn->size()});
        BinaryDecoder d(c.body, c.bodySize);
        NodeId type;
        decode(d, type);
        OpenSecureChannelResponse resp;
        decode(d, resp);
        channelId = resp.securityToken.channelId;
        tokenId = resp.securityToken.tokenId;
        return channelId != 0;
    }

    // One MSG chunk around `body` (a request's type NodeId + encoding, or anything).
    Buffer chunk(const Buffer& body, tp::ChunkType ct = tp::ChunkType::Final,
                 std::optional<UInt32> requestId = {}) {
        Buffer m(tp::kSymmetricHeaderSize);
        m.insert(m.end(), body.begin(), body.end());
        tp::encodeMessageHeader(m.data(), tp::MessageType::Message, ct,
                                static_cast<UInt32>(m.size()));
        tp::putUInt32(m.data() + 8, channelId);
        tp::putUInt32(m.data() + 12, tokenId);
        tp::putUInt32(m.data() + 16, seq_++);
        tp::putUInt32(m.data() + 20, requestId.value_or(requestId_));
        if (!requestId && ct == tp::ChunkType::Final) ++requestId_;
        return m;
    }
    // The next MSG response: its type and body (single-chunk responses only).
    std::optional<std::pair<NodeId, Buffer>> readResponse(Deadline deadline = Clock::now() + 5s) {
        auto c = sock.readChunk(deadline);
        if (!c) return std::nullopt;
        auto h = tp::decodeMessageHeader(c->data());
        if (h.type != tp::MessageType::Message || h.chunkType != tp::ChunkType::Final)
            return std::nullopt;
        auto sc = tp::parseSecureChunk(tp::RawChunk{h, c->data(), c->size()});
        BinaryDecoder d(sc.body, sc.bodySize);
        NodeId type;
        decode(d, type);
        return std::pair{type, Buffer(d.position(), d.position() + d.remaining())};
    }
    UInt32 nextSequenceNumber() const { return seq_; }

    RawSocket sock;
    tp::Acknowledge limits;
    UInt32 channelId = 0;
    UInt32 tokenId = 0;

  private:
    UInt32 seq_ = 1;
    UInt32 requestId_ = 1;
};

template <class Req>
Buffer encodeBody(const Req& req) {
    Buffer b;
    BinaryEncoder e(b);
    encode(e, encodingId<Req>());
    encode(e, req);
    return b;
}

template <class Req>
Buffer requestMessage(const Req& req) {
    Buffer m = tp::ClientConnection::newMessageBuffer();
    Buffer b = encodeBody(req);
    m.insert(m.end(), b.begin(), b.end());
    return m;
}

RequestHeader requestHeader(UInt32 handle, NodeId token = {}) {
    RequestHeader h;
    h.authenticationToken = std::move(token);
    h.timestamp = DateTime::now();
    h.requestHandle = handle;
    h.timeoutHint = 5000;
    return h;
}

GetEndpointsRequest getEndpoints(UInt32 handle) {
    GetEndpointsRequest r;
    r.requestHeader = requestHeader(handle);
    r.endpointUrl = "opc.tcp://127.0.0.1/";
    return r;
}

// The ServiceFault's result, or nullopt when the response is no ServiceFault.
std::optional<StatusCode> serviceFault(const NodeId& type, const transport::MessageBody& body,
                                       UInt32* handle = nullptr) {
    if (type != encodingId<ServiceFault>()) return std::nullopt;
    auto f = decodeFromBuffer<ServiceFault>(body.data(), body.size());
    if (handle) *handle = f.responseHeader.requestHandle;
    return f.responseHeader.serviceResult;
}

tp::IncomingResponse roundTrip(tp::ClientConnection& c, Buffer&& message) {
    UInt32 id = c.send(std::move(message));
    auto deadline = Clock::now() + 5s;
    while (auto r = c.receive(deadline)) {
        if (r->requestId == id) return std::move(*r);
    }
    throw std::runtime_error("no response within 5 s");
}

// ---- the bystander ----------------------------------------------------------------------------
class Bystander {
  public:
    Bystander(const std::string& url, NodeId constant, NodeId object, NodeId method)
        : constant_(std::move(constant)), object_(std::move(object)), method_(std::move(method)) {
        client::ClientConfig cfg;
        cfg.reconnect.enabled = false;  // a drop must show up as a failure
        cfg.requestTimeout = 3s;
        client_ = std::make_unique<client::Client>(cfg);
        client_->connect(url);
        thread_ = std::thread([this] { run(); });
    }
    ~Bystander() {
        stop_ = true;
        thread_.join();
    }
    std::uint64_t answers() const { return answers_.load(); }
    std::uint64_t failures() const { return failures_.load(); }
    std::string firstError() const {
        std::lock_guard lock(mutex_);
        return firstError_;
    }
    const client::Client& client() const { return *client_; }

  private:
    void run() {
        for (std::uint64_t i = 0; !stop_; ++i) {
            try {
                if (i % 10 == 9) {
                    auto r = client_->call(object_, method_, {Int32{20}, Int32{22}});
                    if (!r.ok() || r.outputs.size() != 1 || !r.outputs[0].scalar<Int32>() ||
                        *r.outputs[0].scalar<Int32>() != 42)
                        fail("method call: " + r.status.toString());
                    else
                        ++answers_;
                } else {
                    Variant v = client_->readValue(constant_);
                    if (!v.scalar<Int32>() || *v.scalar<Int32>() != kConstant)
                        fail("read: unexpected value " + v.toString());
                    else
                        ++answers_;
                }
            } catch (const std::exception& e) {
                fail(e.what());
            }
            std::this_thread::sleep_for(3ms);
        }
    }
    void fail(const std::string& what) {
        if (failures_.fetch_add(1) == 0) {
            std::lock_guard lock(mutex_);
            firstError_ = what;
        }
    }

    NodeId constant_, object_, method_;
    std::unique_ptr<client::Client> client_;
    std::atomic<bool> stop_{false};
    std::atomic<std::uint64_t> answers_{0};
    std::atomic<std::uint64_t> failures_{0};
    mutable std::mutex mutex_;
    std::string firstError_;
    std::thread thread_;
};

// ---- the suite ---------------------------------------------------------------------------------
class Robustness : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        server::ServerConfig cfg = pnp::testing::loopbackConfig();
        cfg.applicationUri = "urn:pnp:robustness";
        cfg.transport.receiveBufferSize = kReceiveBufferSize;
        cfg.transport.sendBufferSize = kReceiveBufferSize;
        cfg.transport.maxMessageSize = kMaxMessageSize;
        cfg.transport.maxChunkCount = kMaxChunkCount;
        cfg.transport.helloTimeout = kHelloTimeout;
        cfg.transport.maxConnections = 1000;
        cfg.transport.maxIncompleteMessageBytes = kIncompleteBudget;
        completer_ = new LateCompleter();
        server_ = new server::Server(cfg);
        auto& as = server_->addressSpace();
        ns_ = as.addNamespace("urn:pnp:robustness");
        server::VariableAttributes va;
        va.dataType = NodeId(0, ns0::Int32);
        va.accessLevel = server::access_level::CurrentRead | server::access_level::CurrentWrite;
        va.value = DataValue(Variant(Int32{0}));
        as.addVariable(NodeId(0, ns0::ObjectsFolder), NodeId(ns_, "Value"),
                       QualifiedName{ns_, "Value"}, va);
        va.accessLevel = server::access_level::CurrentRead;
        va.value = DataValue(Variant(Int32{kConstant}));
        as.addVariable(NodeId(0, ns0::ObjectsFolder), NodeId(ns_, "Constant"),
                       QualifiedName{ns_, "Constant"}, va);
        as.addObject(NodeId(0, ns0::ObjectsFolder), NodeId(ns_, "Object"),
                     QualifiedName{ns_, "Object"});
        Argument a;
        a.name = "a";
        a.dataType = NodeId(0, ns0::Int32);
        a.valueRank = -1;
        Argument b = a;
        b.name = "b";
        Argument sum = a;
        sum.name = "sum";
        // Adds, and completes 2 ms later on another thread.
        as.addMethod(NodeId(ns_, "Object"), NodeId(ns_, "SlowAdd"), QualifiedName{ns_, "SlowAdd"},
                     {a, b}, {sum},
                     [](const server::MethodCallContext&, std::vector<Variant> in,
                        server::MethodCompletion done) {
                         Int32 s = *in[0].scalar<Int32>() + *in[1].scalar<Int32>();
                         completer_->add(2ms, std::move(done), {Variant(s)});
                     });
        server_->start();
        url_ = pnp::testing::url(*server_);
        bystander_ = new Bystander(url_, NodeId(ns_, "Constant"), NodeId(ns_, "Object"),
                                   NodeId(ns_, "SlowAdd"));
    }
    static void TearDownTestSuite() {
        delete bystander_;
        bystander_ = nullptr;
        server_->stop();
        delete completer_;  // completes what is left (nothing) before the server goes
        completer_ = nullptr;
        delete server_;
        server_ = nullptr;
    }

    void SetUp() override { ASSERT_NE(bystander_, nullptr); }
    // After every attack: the bystander saw no failure and is still being served.
    void TearDown() override {
        EXPECT_EQ(bystander_->failures(), 0u) << bystander_->firstError();
        auto before = bystander_->answers();
        EXPECT_TRUE(eventually([&] { return bystander_->answers() >= before + 3; }, 5s))
            << "the bystander is no longer served";
    }

    static UInt16 port() { return server_->port(); }

    template <class F>
    static bool eventually(F&& cond, std::chrono::milliseconds limit) {
        auto end = Clock::now() + limit;
        while (Clock::now() < end) {
            if (cond()) return true;
            std::this_thread::sleep_for(5ms);
        }
        return cond();
    }

    // A secure channel (ClientConnection) with an activated session; returns the token.
    static std::unique_ptr<tp::ClientConnection> sessionConnection(NodeId& token) {
        tp::ClientConfig cfg;
        auto c = tp::ClientConnection::connect(url_, cfg, Clock::now() + 5s);
        CreateSessionRequest cs;
        cs.requestHeader = requestHeader(1);
        cs.endpointUrl = url_;
        cs.sessionName = "attacker";
        cs.requestedSessionTimeout = 60'000;
        auto r = roundTrip(*c, requestMessage(cs));
        EXPECT_EQ(r.typeId, encodingId<CreateSessionResponse>());
        auto created = decodeFromBuffer<CreateSessionResponse>(r.body.data(), r.body.size());
        token = created.authenticationToken;
        ActivateSessionRequest as;
        as.requestHeader = requestHeader(2, token);
        as.userIdentityToken = toExtensionObject(AnonymousIdentityToken{"anonymous"});
        r = roundTrip(*c, requestMessage(as));
        EXPECT_EQ(r.typeId, encodingId<ActivateSessionResponse>());
        return c;
    }

    static Int32 readValueOn(tp::ClientConnection& c, const NodeId& token) {
        ReadRequest rd;
        rd.requestHeader = requestHeader(50, token);
        ReadValueId id;
        id.nodeId = NodeId(ns_, "Value");
        id.attributeId = 13;
        rd.nodesToRead = {id};
        auto r = roundTrip(c, requestMessage(rd));
        EXPECT_EQ(r.typeId, encodingId<ReadResponse>());
        auto resp = decodeFromBuffer<ReadResponse>(r.body.data(), r.body.size());
        if (resp.results.size() != 1 || !resp.results[0].value ||
            !resp.results[0].value->scalar<Int32>())
            return -1;
        return *resp.results[0].value->scalar<Int32>();
    }

    // A Write request of one WriteValue whose DataValue holds `variant` (raw bytes).
    static Buffer writeWithRawVariant(const NodeId& token, UInt32 handle, const Buffer& variant) {
        Buffer m = tp::ClientConnection::newMessageBuffer();
        BinaryEncoder e(m);
        encode(e, encodingId<WriteRequest>());
        encode(e, requestHeader(handle, token));
        e.number<Int32>(1);  // nodesToWrite: one
        encode(e, NodeId(ns_, "Value"));
        e.number<UInt32>(13);  // Value
        e.number<Int32>(-1);   // IndexRange: null
        e.byte(0x01);          // DataValue: value only
        e.raw(variant.data(), variant.size());
        return m;
    }

    static inline server::Server* server_ = nullptr;
    static inline LateCompleter* completer_ = nullptr;
    static inline Bystander* bystander_ = nullptr;
    static inline std::string url_;
    static inline UInt16 ns_ = 0;
};

// ---- before HEL ----------------------------------------------------------------------------
TEST_F(Robustness, GarbageInsteadOfHello) {
    {
        RawSocket s(port());
        ASSERT_TRUE(s.ok());
        const std::string http = "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n";
        s.send(http.data(), http.size());
        EXPECT_EQ(s.expectError(), status::BadTcpMessageTypeInvalid);
        EXPECT_TRUE(s.waitClosed());
    }
    // Random bytes: closed every time (an ERR first when the 8 header bytes arrived).
    std::mt19937 rng(7);
    for (int i = 0; i < 30; ++i) {
        RawSocket s(port());
        ASSERT_TRUE(s.ok());
        Buffer junk(16 + rng() % 3000);
        for (auto& b : junk) b = static_cast<Byte>(rng());
        s.send(junk);
        EXPECT_TRUE(s.waitClosed()) << "iteration " << i;
    }
}

TEST_F(Robustness, HelloWithLyingLength) {
    {
        // The header says 2 GiB: refused as soon as the header is there, nothing allocated.
        RawSocket s(port());
        Buffer b = tp::encodeMessage(tp::Hello{0, 8192, 8192, 0, 0, "opc.tcp://x/"});
        tp::putUInt32(b.data() + 4, 0x80000000u);
        s.send(b);
        EXPECT_EQ(s.expectError(), status::BadTcpMessageTooLarge);
        EXPECT_TRUE(s.waitClosed());
    }
    {
        // The header says 4 bytes: smaller than the header itself.
        RawSocket s(port());
        Buffer b = tp::encodeMessage(tp::Hello{0, 8192, 8192, 0, 0, "opc.tcp://x/"});
        tp::putUInt32(b.data() + 4, 4);
        s.send(b);
        EXPECT_EQ(s.expectError(), status::BadDecodingError);
        EXPECT_TRUE(s.waitClosed());
    }
    {
        // Buffer sizes below 8192 (Part 6 §7.1.2.3).
        RawSocket s(port());
        s.send(tp::encodeMessage(tp::Hello{0, 1024, 1024, 0, 0, "opc.tcp://x/"}));
        EXPECT_EQ(s.expectError(), status::BadConnectionRejected);
        EXPECT_TRUE(s.waitClosed());
    }
}

TEST_F(Robustness, UnknownMessageType) {
    {
        RawChannel c(port());
        ASSERT_TRUE(c.open());
        Buffer m = c.chunk(encodeBody(getEndpoints(1)));
        std::memcpy(m.data(), "XYZ", 3);
        c.sock.send(m);
        EXPECT_EQ(c.sock.expectError(), status::BadTcpMessageTypeInvalid);
        EXPECT_TRUE(c.sock.waitClosed());
    }
    {
        // Messages a server never accepts: ACK, ERR, ReverseHello.
        RawSocket s(port());
        s.send(tp::encodeMessage(tp::ReverseHello{"urn:x", "opc.tcp://x/"}));
        EXPECT_EQ(s.expectError(), status::BadTcpMessageTypeInvalid);
        EXPECT_TRUE(s.waitClosed());
    }
    {
        // MSG before HEL.
        RawSocket s(port());
        Buffer m(tp::kSymmetricHeaderSize + 4);
        tp::encodeMessageHeader(m.data(), tp::MessageType::Message, tp::ChunkType::Final,
                                static_cast<UInt32>(m.size()));
        s.send(m);
        EXPECT_EQ(s.expectError(), status::BadTcpMessageTypeInvalid);
        EXPECT_TRUE(s.waitClosed());
    }
}

// ---- cut-off connections -----------------------------------------------------------------
TEST_F(Robustness, TruncatedChunkThenPeerVanishes) {
    for (int i = 0; i < 10; ++i) {
        {
            // Half a HEL, then FIN.
            RawSocket s(port());
            Buffer b = tp::encodeMessage(tp::Hello{0, 8192, 8192, 0, 0, "opc.tcp://x/"});
            s.send(b.data(), b.size() / 2);
            s.closeNow();
        }
        {
            // Half a MSG on an open channel, then FIN.
            RawChannel c(port());
            ASSERT_TRUE(c.open());
            Buffer m = c.chunk(encodeBody(getEndpoints(1)));
            c.sock.send(m.data(), m.size() / 2);
            c.sock.closeNow();
        }
        {
            // The first chunk of a multi-chunk message, half of the second, then a reset.
            RawChannel c(port());
            ASSERT_TRUE(c.open());
            c.sock.send(c.chunk(Buffer(4000, 0x11), tp::ChunkType::Intermediate, 9));
            Buffer m = c.chunk(Buffer(4000, 0x22), tp::ChunkType::Final, 9);
            c.sock.send(m.data(), m.size() / 2);
            c.sock.resetNow();
        }
    }
    // The server still opens channels and answers on them.
    RawChannel c(port());
    ASSERT_TRUE(c.open());
    c.sock.send(c.chunk(encodeBody(getEndpoints(5))));
    auto r = c.readResponse();
    ASSERT_TRUE(r);
    EXPECT_EQ(r->first, encodingId<GetEndpointsResponse>());
}

// ---- limits --------------------------------------------------------------------------------
TEST_F(Robustness, ChunkBeyondTheReceiveBuffer) {
    RawChannel c(port());
    ASSERT_TRUE(c.open(65536));  // we offer more; the server's 8192 bytes apply
    EXPECT_EQ(c.limits.receiveBufferSize, kReceiveBufferSize);
    Buffer m = c.chunk(Buffer(kReceiveBufferSize + 1 - tp::kSymmetricHeaderSize, 0x33));
    ASSERT_EQ(m.size(), kReceiveBufferSize + 1);
    // The header alone is enough for the verdict.
    c.sock.send(m.data(), 64);
    EXPECT_EQ(c.sock.expectError(), status::BadTcpMessageTooLarge);
    EXPECT_TRUE(c.sock.waitClosed());
}

TEST_F(Robustness, MessageBeyondMaxMessageSizeInManyChunks) {
    RawChannel c(port());
    ASSERT_TRUE(c.open());
    EXPECT_EQ(c.limits.maxMessageSize, kMaxMessageSize);
    const Buffer part(kReceiveBufferSize - tp::kSymmetricHeaderSize, 0x44);
    // Full intermediate chunks until the server objects (bounded: twice the limit).
    std::size_t sent = 0;
    for (int i = 0; i < 2 * static_cast<int>(kMaxMessageSize / part.size()) + 2; ++i) {
        if (!c.sock.send(c.chunk(part, tp::ChunkType::Intermediate, 77))) break;
        sent += part.size();
    }
    EXPECT_GT(sent, kMaxMessageSize);
    EXPECT_EQ(c.sock.expectError(), status::BadTcpMessageTooLarge);
    EXPECT_TRUE(c.sock.waitClosed());
}

// Many clients trickling in large messages: together they may hold no more than the
// server-wide budget; the one that goes beyond it is closed, the others are unaffected.
TEST_F(Robustness, PartialMessagesShareAServerWideBudget) {
    const Buffer part(kReceiveBufferSize - tp::kSymmetricHeaderSize, 0x46);
    const std::size_t chunksEach = (kMaxMessageSize * 7 / 8) / part.size();  // < MaxMessageSize
    RawChannel a(port()), b(port());
    ASSERT_TRUE(a.open());
    ASSERT_TRUE(b.open());
    for (std::size_t i = 0; i < chunksEach; ++i)
        ASSERT_TRUE(a.sock.send(a.chunk(part, tp::ChunkType::Intermediate, 90)));
    std::this_thread::sleep_for(300ms);  // the server has read all of a's chunks
    for (std::size_t i = 0; i < chunksEach; ++i)
        if (!b.sock.send(b.chunk(part, tp::ChunkType::Intermediate, 91))) break;
    EXPECT_EQ(b.sock.expectError(), status::BadTcpNotEnoughResources);
    EXPECT_TRUE(b.sock.waitClosed());
    // a still holds its part and is still open.
    EXPECT_EQ(a.sock.expectError(tp::Clock::now() + 200ms), StatusCode{});
    // When a goes away its bytes come back: a third client can do what b could not.
    a.sock.closeNow();
    std::this_thread::sleep_for(200ms);
    RawChannel c(port());
    ASSERT_TRUE(c.open());
    for (std::size_t i = 0; i < chunksEach; ++i)
        ASSERT_TRUE(c.sock.send(c.chunk(part, tp::ChunkType::Intermediate, 92)));
    EXPECT_EQ(c.sock.expectError(tp::Clock::now() + 200ms), StatusCode{});
}

TEST_F(Robustness, TooManyChunks) {
    RawChannel c(port());
    ASSERT_TRUE(c.open());
    ASSERT_EQ(c.limits.maxChunkCount, kMaxChunkCount);
    // Tiny chunks: far below MaxMessageSize, one more than MaxChunkCount.
    for (UInt32 i = 0; i < kMaxChunkCount; ++i)
        ASSERT_TRUE(c.sock.send(c.chunk(Buffer(10, 0x55), tp::ChunkType::Intermediate, 78)));
    c.sock.send(c.chunk(Buffer(10, 0x55), tp::ChunkType::Final, 78));
    EXPECT_EQ(c.sock.expectError(), status::BadTcpMessageTooLarge);
    EXPECT_TRUE(c.sock.waitClosed());
}

// ---- service level: a ServiceFault, and the connection stays usable ---------------------------
TEST_F(Robustness, UnknownRequestTypeGetsServiceFault) {
    NodeId token;
    auto c = sessionConnection(token);
    for (const NodeId& type : {NodeId(0, 4242), encodingId<AddNodesRequest>(),
                               NodeId(7, "no such request"), NodeId(0, UInt32{0})}) {
        Buffer m = tp::ClientConnection::newMessageBuffer();
        BinaryEncoder e(m);
        encode(e, type);
        encode(e, requestHeader(31337, token));
        e.number<UInt32>(0xDEADBEEF);
        auto r = roundTrip(*c, std::move(m));
        UInt32 handle = 0;
        EXPECT_EQ(serviceFault(r.typeId, r.body, &handle), status::BadServiceUnsupported)
            << type.toString();
        if (type.namespaceIndex() == 0) {
            EXPECT_EQ(handle, 31337u) << type.toString();
        }
    }
    EXPECT_TRUE(c->isOpen());
    EXPECT_EQ(readValueOn(*c, token), readValueOn(*c, token));
}

TEST_F(Robustness, MalformedVariantsInWriteGetServiceFault) {
    NodeId token;
    auto c = sessionConnection(token);

    struct Case {
        const char* name;
        Buffer variant;
        StatusCode expected;
    };
    std::vector<Case> cases;
    cases.push_back({"built-in type 30", Buffer{30, 1, 2, 3, 4}, status::BadDecodingError});
    cases.push_back(
        {"array of built-in type 63", Buffer{0x80 | 63, 1, 0, 0, 0, 0}, status::BadDecodingError});
    {
        // 1000 nested Variant arrays of one element each, then a null Variant.
        Buffer v;
        for (int i = 0; i < 1000; ++i) v.insert(v.end(), {0x80 | 24, 1, 0, 0, 0});
        v.push_back(0);
        cases.push_back({"nested 1000 deep", v, status::BadEncodingLimitsExceeded});
    }
    cases.push_back({"Int32 array of 2^31-1 elements", Buffer{0x80 | 6, 0xFF, 0xFF, 0xFF, 0x7F},
                     status::BadEncodingLimitsExceeded});
    cases.push_back({"String array of 2^31-1 elements",
                     Buffer{0x80 | 12, 0xFF, 0xFF, 0xFF, 0x7F, 0, 0, 0, 0},
                     status::BadEncodingLimitsExceeded});
    cases.push_back({"array count beyond the message", Buffer{0x80 | 6, 0x00, 0x00, 0x01, 0x00},
                     status::BadDecodingError});
    cases.push_back({"string of 2^31-1 bytes", Buffer{12, 0xFF, 0xFF, 0xFF, 0x7F, 'x'},
                     status::BadEncodingLimitsExceeded});
    cases.push_back(
        {"negative string length", Buffer{12, 0xFE, 0xFF, 0xFF, 0xFF}, status::BadDecodingError});
    {
        // A matrix whose dimensions do not match the elements.
        Buffer v{0x80 | 0x40 | 6, 2, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0};
        v.insert(v.end(), {2, 0, 0, 0, 3, 0, 0, 0, 5, 0, 0, 0});
        cases.push_back({"matrix 3x5 of 2 elements", v, status::BadDecodingError});
    }
    cases.push_back({"truncated Double", Buffer{11, 1, 2, 3}, status::BadDecodingError});

    UInt32 handle = 1000;
    for (const auto& tc : cases) {
        auto r = roundTrip(*c, writeWithRawVariant(token, ++handle, tc.variant));
        EXPECT_EQ(serviceFault(r.typeId, r.body), tc.expected) << tc.name;
        ASSERT_TRUE(c->isOpen()) << tc.name;
    }
    // The same connection and session still write and read.
    Buffer ok{6};
    Buffer v42 = encodeToBuffer(Int32{42});
    ok.insert(ok.end(), v42.begin(), v42.end());
    auto r = roundTrip(*c, writeWithRawVariant(token, ++handle, ok));
    ASSERT_EQ(r.typeId, encodingId<WriteResponse>());
    auto w = decodeFromBuffer<WriteResponse>(r.body.data(), r.body.size());
    ASSERT_EQ(w.results.size(), 1u);
    EXPECT_EQ(w.results[0], status::Good);
    EXPECT_EQ(readValueOn(*c, token), 42);
}

// ---- resource exhaustion -----------------------------------------------------------------
long maxRssMiB() {
    rusage ru{};
    ::getrusage(RUSAGE_SELF, &ru);
    return ru.ru_maxrss / 1024;
}

TEST_F(Robustness, NestedArraysDoNotMultiplyMemory) {
    // Variant arrays of Variant arrays, 25 deep, each claiming as many elements as bytes are
    // left, the innermost one 200000 null Variants: ~200 KB on the wire. Each level's count
    // passes the "fits into the remaining bytes" check against the same bytes; allocating
    // every level up front took 25 x 200000 x sizeof(Variant) (~600 MB) for a request that
    // can only fail.
    NodeId token;
    auto c = sessionConnection(token);
    constexpr int kDepth = 25;
    constexpr Int32 kNulls = 200'000;
    Buffer v;
    for (int i = 0; i < kDepth; ++i) {
        v.push_back(0x80 | 24);
        Buffer n = encodeToBuffer(Int32{5 * (kDepth - 1 - i) + kNulls});
        v.insert(v.end(), n.begin(), n.end());
    }
    v.resize(v.size() + kNulls, 0);
    const long before = maxRssMiB();
    auto r = roundTrip(*c, writeWithRawVariant(token, 5, v));
    const long grown = maxRssMiB() - before;
    EXPECT_EQ(serviceFault(r.typeId, r.body), status::BadDecodingError);
    EXPECT_LT(grown, 300) << "decoding a " << v.size() / 1024 << " KiB request peaked at +" << grown
                          << " MiB";
    EXPECT_TRUE(c->isOpen());
    EXPECT_EQ(readValueOn(*c, token), readValueOn(*c, token));
}

TEST_F(Robustness, ManySilentConnectionsAreClosedByTheHelloTimeout) {
    constexpr int kCount = 200;
    std::vector<std::unique_ptr<RawSocket>> socks;
    socks.reserve(kCount);
    const auto t0 = Clock::now();
    for (int i = 0; i < kCount; ++i) {
        socks.push_back(std::make_unique<RawSocket>(port()));
        ASSERT_TRUE(socks.back()->ok()) << i;
    }
    // Each one gets ERR BadTimeout and is closed, once the hello timeout is over.
    const Deadline deadline = t0 + kHelloTimeout + 5s;
    int timedOut = 0;
    for (auto& s : socks) {
        if (s->expectError(deadline) == status::BadTimeout && s->waitClosed(deadline)) ++timedOut;
    }
    EXPECT_EQ(timedOut, kCount);
    EXPECT_GE(Clock::now() - t0, kHelloTimeout - 100ms);
    // A new connection right after is served normally.
    RawChannel c(port());
    ASSERT_TRUE(c.open());
}

TEST_F(Robustness, SlowlorisHelloIsClosedByTheHelloTimeout) {
    RawSocket s(port());
    ASSERT_TRUE(s.ok());
    const Buffer hello = tp::encodeMessage(tp::Hello{0, 8192, 8192, 0, 0, "opc.tcp://x/"});
    const auto t0 = Clock::now();
    StatusCode err;
    bool gotError = false;
    // One byte every 50 ms: the Hello would need ~3 s; the hello timeout ends it first.
    for (std::size_t i = 0; i < hello.size() && !gotError; ++i) {
        if (!s.send(&hello[i], 1)) break;
        pollfd p{s.fd(), POLLIN, 0};
        if (::poll(&p, 1, 50) > 0) {
            err = s.expectError(Clock::now() + 2s);
            gotError = true;
        }
    }
    if (!gotError) err = s.expectError(Clock::now() + 2s);
    EXPECT_EQ(err, status::BadTimeout);
    EXPECT_TRUE(s.waitClosed());
    auto took = Clock::now() - t0;
    EXPECT_GE(took, kHelloTimeout - 100ms);
    EXPECT_LE(took, kHelloTimeout + 2s);
}

TEST_F(Robustness, SlowlorisRequestDoesNotBlockOthers) {
    // On an open channel (no idle timeout configured) a request trickling in byte by byte
    // only costs its own connection; once complete it is answered.
    RawChannel c(port());
    ASSERT_TRUE(c.open());
    Buffer m = c.chunk(encodeBody(getEndpoints(4242)));
    const auto before = bystander_->answers();
    const auto end = Clock::now() + 1s;
    std::size_t i = 0;
    for (; i + 1 < m.size() && Clock::now() < end; ++i) {
        ASSERT_TRUE(c.sock.send(&m[i], 1));
        std::this_thread::sleep_for(50ms);
    }
    EXPECT_GT(bystander_->answers(), before + 5) << "the bystander stalled meanwhile";
    ASSERT_TRUE(c.sock.send(m.data() + i, m.size() - i));
    auto r = c.readResponse();
    ASSERT_TRUE(r);
    EXPECT_EQ(r->first, encodingId<GetEndpointsResponse>());
}

TEST_F(Robustness, ClientThatNeverReadsIsThrottled) {
    // Requests without reading the responses: the server must stop reading from this
    // connection once its output queue is full (else it queues responses without bound),
    // and must go on serving everybody else.
    RawChannel c(port());
    ASSERT_TRUE(c.open());
    int small = 4096;  // keep our own receive buffer small: the responses pile up server-side
    ::setsockopt(c.sock.fd(), SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
    ::fcntl(c.sock.fd(), F_SETFL, ::fcntl(c.sock.fd(), F_GETFL) | O_NONBLOCK);

    GetEndpointsRequest req = getEndpoints(1);
    req.profileUris = {};
    const Buffer body = encodeBody(req);
    Buffer batch;
    std::size_t sent = 0, offset = 0;
    auto lastProgress = Clock::now();
    const auto start = Clock::now();
    bool stalled = false;
    constexpr std::size_t kLimit = 512u << 20;  // far more than any sane output queue
    while (Clock::now() - start < 15s && sent < kLimit) {
        if (offset == batch.size()) {
            batch.clear();
            offset = 0;
            for (int k = 0; k < 64; ++k) {
                Buffer m = c.chunk(body);
                batch.insert(batch.end(), m.begin(), m.end());
            }
        }
        ssize_t k = ::send(c.sock.fd(), batch.data() + offset, batch.size() - offset, MSG_NOSIGNAL);
        if (k > 0) {
            offset += static_cast<std::size_t>(k);
            sent += static_cast<std::size_t>(k);
            lastProgress = Clock::now();
            continue;
        }
        ASSERT_TRUE(k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            << "send failed: " << std::strerror(errno);
        if (Clock::now() - lastProgress >= 1500ms) {
            stalled = true;
            break;
        }
        pollfd p{c.sock.fd(), POLLOUT, 0};
        ::poll(&p, 1, 50);
    }
    std::printf("[   INFO   ] %zu bytes of requests taken before the server stopped reading\n",
                sent);
    EXPECT_TRUE(stalled)
        << "the server kept reading: " << sent << " bytes of requests taken in "
        << std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start).count()
        << " ms while no response was read";
    // The other clients were served meanwhile (checked in TearDown too).
    EXPECT_EQ(bystander_->failures(), 0u);
    c.sock.resetNow();
}

// ---- afterwards ------------------------------------------------------------------------------
TEST_F(Robustness, ServerStillAcceptsNewClients) {
    client::Client fresh;
    fresh.connect(url_);
    auto v = fresh.readValue(NodeId(ns_, "Constant"));
    ASSERT_NE(v.scalar<Int32>(), nullptr);
    EXPECT_EQ(*v.scalar<Int32>(), kConstant);
    auto r = fresh.call(NodeId(ns_, "Object"), NodeId(ns_, "SlowAdd"), {Int32{1}, Int32{2}});
    ASSERT_TRUE(r.ok()) << r.status.toString();
    ASSERT_EQ(r.outputs.size(), 1u);
    EXPECT_EQ(*r.outputs[0].scalar<Int32>(), 3);
    EXPECT_EQ(fresh.writeValue(NodeId(ns_, "Value"), Int32{7}), status::Good);
    EXPECT_EQ(*fresh.readValue(NodeId(ns_, "Value")).scalar<Int32>(), 7);
    fresh.disconnect();
    EXPECT_EQ(bystander_->failures(), 0u) << bystander_->firstError();
    EXPECT_GT(bystander_->answers(), 50u);
    EXPECT_EQ(bystander_->client().stats().connectionsLost, 0u);
}

}  // namespace
}  // namespace pnp::ua
