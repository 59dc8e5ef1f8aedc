// TcpServer + ClientConnection over real sockets on 127.0.0.1 (ephemeral ports). Every
// attack is followed by a check that an observer client, connected throughout, still gets
// answers. Every wait is bounded by a deadline.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <filesystem>
#include <future>
#include <mutex>
#include <random>
#include <set>
#include <thread>

#include "support/raw_socket.hpp"
#include "transport_test_util.hpp"
#include "ua/transport/client_connection.hpp"
#include "ua/transport/tcp_server.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {
namespace {

using test_util::pattern;

using namespace std::chrono_literals;

const NodeId kEcho(1, 1);  // respond with the same body
const NodeId kEchoReply(1, 2);
const NodeId kLater(1, 3);  // respond from another thread after 5 ms
const NodeId kBig(1, 4);    // body: UInt32 handle, UInt32 n -> header + n bytes
const NodeId kClose(1, 5);  // the server closes the connection
const NodeId kFault(1, 6);  // ServiceFault BadNodeIdUnknown via sendServiceFault

Buffer requestMessage(const NodeId& type, const Buffer& body) {
    Buffer m = ClientConnection::newMessageBuffer();
    BinaryEncoder e(m);
    encode(e, type);
    e.raw(body.data(), body.size());
    return m;
}

class Handler : public ServiceHandler {
  public:
    void onRequest(const std::shared_ptr<ServerConnection>& c, const IncomingRequest& r) override {
        // Handlers run one at a time (the network lock), whichever connection they serve.
        if (inside.fetch_add(1) != 0) overlaps.fetch_add(1);
        struct Leave {
            std::atomic<int>& n;
            ~Leave() { n.fetch_sub(1); }
        } leave{inside};
        requests.fetch_add(1);
        if (r.typeId == kEcho) {
            Buffer m = ServerConnection::newMessageBuffer();
            BinaryEncoder e(m);
            encode(e, kEchoReply);
            e.raw(r.body, r.size);
            c->send(r.requestId, std::move(m));
        } else if (r.typeId == kLater) {
            Buffer body(r.body, r.body + r.size);
            std::lock_guard lk(mutex);
            workers.emplace_back([c, id = r.requestId, body] {
                std::this_thread::sleep_for(5ms);
                Buffer m = ServerConnection::newMessageBuffer();
                BinaryEncoder e(m);
                encode(e, kEchoReply);
                e.raw(body.data(), body.size());
                c->send(id, std::move(m));
            });
        } else if (r.typeId == kBig) {
            UInt32 handle = getUInt32(r.body), n = getUInt32(r.body + 4);
            Buffer m = ServerConnection::newMessageBuffer();
            BinaryEncoder e(m);
            encode(e, kEchoReply);
            encode(e, DateTime::now());
            encode(e, handle);
            m.resize(m.size() + n, 0x5A);
            c->send(r.requestId, std::move(m));
        } else if (r.typeId == kClose) {
            c->close();
        } else if (r.typeId == kFault) {
            c->sendServiceFault(r.requestId, 4242, status::BadNodeIdUnknown);
        }
    }
    void onConnectionClosed(const std::shared_ptr<ServerConnection>&) override {
        closed.fetch_add(1);
    }
    ~Handler() override { joinWorkers(); }
    void joinWorkers() {
        std::vector<std::thread> w;
        {
            std::lock_guard lk(mutex);
            w.swap(workers);
        }
        for (auto& t : w) t.join();
    }

    std::atomic<int> requests{0};
    std::atomic<int> closed{0};
    std::atomic<int> inside{0};
    std::atomic<int> overlaps{0};
    std::mutex mutex;
    std::vector<std::thread> workers;
};

// ---- a raw socket for misbehaving clients: tests/support/raw_socket.hpp ----
using test::RawSocket;

// A raw socket that completed HEL/ACK/OPN through a ClientChannel and then sends hand-made
// chunks (sequence numbers continue at 2).
class RawClient : private ClientChannel::Hooks {
  public:
    RawClient(UInt16 port, ClientConfig cfg = defaultConfig())
        : sock(port), channel_(cfg, "opc.tcp://127.0.0.1:" + std::to_string(port), *this) {}
    static ClientConfig defaultConfig() {
        ClientConfig c;
        c.receiveBufferSize = 8192;
        c.sendBufferSize = 8192;
        return c;
    }
    bool open() {
        channel_.start(Clock::now());
        auto deadline = Clock::now() + 5s;
        while (!channel_.isOpen()) {
            auto c = sock.readChunk(deadline);
            if (!c) return false;
            channel_.feed(c->data(), c->size(), Clock::now());
        }
        return true;
    }
    Buffer msg(UInt32 seq, UInt32 req, const Buffer& body, ChunkType ct = ChunkType::Final,
               std::optional<UInt32> channel = {}, std::optional<UInt32> token = {}) {
        Buffer m = requestMessage(kEcho, body);
        encodeMessageHeader(m.data(), MessageType::Message, ct, static_cast<UInt32>(m.size()));
        putUInt32(m.data() + 8, channel.value_or(channel_.channelId()));
        putUInt32(m.data() + 12, token.value_or(channel_.currentTokenId()));
        putUInt32(m.data() + 16, seq);
        putUInt32(m.data() + 20, req);
        return m;
    }
    UInt32 channelId() const { return channel_.channelId(); }
    const NegotiatedLimits& limits() const { return channel_.limits(); }
    RawSocket sock;

  private:
    void write(Buffer&& b) override { sock.send(b); }
    void response(IncomingResponse&&) override {}
    ClientChannel channel_;
};

// ---------------------------------------------------------------------------------------
class TcpTest : public ::testing::Test {
  protected:
    void SetUp() override {
        scfg.host = "127.0.0.1";
        scfg.port = 0;
        scfg.receiveBufferSize = 8192;
        scfg.sendBufferSize = 8192;
        scfg.maxMessageSize = 4 << 20;
        scfg.minTokenLifetime = 500ms;
        scfg.helloTimeout = 2000ms;
        ccfg.receiveBufferSize = 8192;
        ccfg.sendBufferSize = 8192;
        ccfg.maxMessageSize = 4 << 20;
    }
    void TearDown() override {
        observer.reset();
        if (server) server->stop();
        handler.joinWorkers();
    }
    void start() {
        server = std::make_unique<TcpServer>(scfg, handler);
        server->start();
        ASSERT_NE(server->port(), 0);
        observer = connect();
        expectObserverWorks();
    }
    std::string url() const { return "opc.tcp://127.0.0.1:" + std::to_string(server->port()); }
    std::unique_ptr<ClientConnection> connect(ClientConfig cfg) {
        return ClientConnection::connect(url(), cfg, Clock::now() + 5s);
    }
    std::unique_ptr<ClientConnection> connect() { return connect(ccfg); }

    // Sends an echo request and waits for its response.
    static IncomingResponse roundTrip(ClientConnection& c, const Buffer& body,
                                      const NodeId& type = kEcho) {
        UInt32 id = c.send(requestMessage(type, body));
        auto deadline = Clock::now() + 10s;
        while (auto r = c.receive(deadline)) {
            if (r->requestId == id) return std::move(*r);
        }
        throw std::runtime_error("no response");
    }
    void expectObserverWorks() {
        ASSERT_TRUE(observer);
        Buffer body = pattern(64, 99);
        auto r = roundTrip(*observer, body);
        EXPECT_EQ(r.typeId, kEchoReply);
        EXPECT_EQ(r.body, body);
    }
    // Runs `clients` threads at once, each with a connection of its own: perClient(k, c)
    // returns how many responses were wrong. The sum; 1000 for each client that threw.
    template <class F>
    int runClients(int clients, F&& perClient) {
        std::atomic<int> wrong{0};
        std::vector<std::thread> threads;
        for (int k = 0; k < clients; ++k) {
            threads.emplace_back([&, k] {
                try {
                    auto c = connect();
                    wrong.fetch_add(perClient(k, *c));
                } catch (const std::exception&) {
                    wrong.fetch_add(1000);
                }
            });
        }
        for (auto& t : threads) t.join();
        return wrong.load();
    }
    // Waits (bounded) until cond holds.
    template <class F>
    static bool eventually(F&& cond, std::chrono::milliseconds limit = 5000ms) {
        auto end = Clock::now() + limit;
        while (Clock::now() < end) {
            if (cond()) return true;
            std::this_thread::sleep_for(5ms);
        }
        return cond();
    }

    ServerTransportConfig scfg;
    ClientConfig ccfg;
    Handler handler;
    std::unique_ptr<TcpServer> server;
    std::unique_ptr<ClientConnection> observer;
};

// ---- round trips -----------------------------------------------------------------------
TEST_F(TcpTest, SmallRoundTrip) {
    start();
    auto c = connect();
    EXPECT_TRUE(c->isOpen());
    EXPECT_NE(c->channelId(), 0u);
    EXPECT_NE(c->channelId(), observer->channelId());
    EXPECT_EQ(c->limits().sendBufferSize, 8192u);
    EXPECT_GE(c->nativeHandle(), 0);
    for (int i = 0; i < 100; ++i) {
        Buffer body = pattern(static_cast<std::size_t>(i * 13), i);
        auto r = roundTrip(*c, body);
        EXPECT_EQ(r.body, body);
    }
    EXPECT_EQ(server->connectionCount(), 2u);
}

TEST_F(TcpTest, MultiChunkOneMiBBothWays) {
    start();
    auto c = connect();
    Buffer body = pattern(1 << 20, 3);
    auto r = roundTrip(*c, body);
    EXPECT_EQ(r.body, body);
    expectObserverWorks();
}

TEST_F(TcpTest, PipelinedRequests) {
    start();
    auto c = connect();
    std::vector<UInt32> ids;
    for (int i = 0; i < 200; ++i) ids.push_back(c->send(requestMessage(kEcho, pattern(100, i))));
    std::size_t got = 0;
    auto deadline = Clock::now() + 10s;
    while (got < ids.size()) {
        auto r = c->receive(deadline);
        ASSERT_TRUE(r);
        EXPECT_EQ(r->requestId, ids[got]);  // in order
        EXPECT_EQ(r->body, pattern(100, static_cast<unsigned>(got)));
        ++got;
    }
}

// Connections are read by several event loops; the handler still sees one request at a
// time, and every client gets exactly its own responses.
TEST_F(TcpTest, ConcurrentClientsAreServedOneHandlerAtATime) {
    start();
    constexpr int kClients = 6;
    constexpr int kRequests = 300;
    EXPECT_EQ(runClients(kClients,
                         [](int k, ClientConnection& c) {
                             int wrong = 0;
                             for (int i = 0; i < kRequests; ++i) {
                                 Buffer body = pattern(16 + static_cast<std::size_t>(i % 200),
                                                       static_cast<unsigned>(k * 1000 + i));
                                 if (!(roundTrip(c, body).body == body)) ++wrong;
                             }
                             return wrong;
                         }),
              0);
    EXPECT_EQ(handler.overlaps.load(), 0);
    EXPECT_GE(handler.requests.load(), kClients * kRequests);
    expectObserverWorks();
}

// All connections on one event loop, next to a client that sends but never reads: every
// client gets exactly its own responses, in the order of its requests, and the stalled one
// holds up nobody.
TEST_F(TcpTest, OneEventLoopServesManyPipeliningClientsInOrder) {
    scfg.eventLoops = 1;
    start();
    RawClient stalled(server->port());
    ASSERT_TRUE(stalled.open());
    Buffer big = pattern(8000);
    UInt32 seq = 2;
    for (int i = 0; i < 2000; ++i, ++seq) {  // until the server stops reading it
        if (!stalled.sock.trySend(stalled.msg(seq, seq, big), 100ms)) break;
    }
    constexpr int kClients = 32;
    constexpr int kRounds = 10;
    constexpr int kPipelined = 20;
    auto body = [](int k, int round, int i) {
        return pattern(10 + static_cast<std::size_t>(i),
                       static_cast<unsigned>(k * 10000 + round * 100 + i));
    };
    EXPECT_EQ(
        runClients(kClients,
                   [&](int k, ClientConnection& c) {
                       int wrong = 0;
                       for (int round = 0; round < kRounds; ++round) {
                           std::vector<UInt32> ids;
                           for (int i = 0; i < kPipelined; ++i)
                               ids.push_back(c.send(requestMessage(kEcho, body(k, round, i))));
                           auto deadline = Clock::now() + 20s;
                           for (int i = 0; i < kPipelined; ++i) {
                               auto r = c.receive(deadline);
                               if (!r || r->requestId != ids[static_cast<std::size_t>(i)] ||
                                   !(r->body == body(k, round, i)))
                                   ++wrong;
                           }
                       }
                       return wrong;
                   }),
        0);
    EXPECT_EQ(handler.overlaps.load(), 0);
    // The observer and the stalled client remain.
    EXPECT_TRUE(eventually([&] { return server->connectionCount() == 2u; }));
    expectObserverWorks();
    // The stalled client's connection still works: its first response is a MSG, not an ERR.
    auto first = stalled.sock.readChunk();
    ASSERT_TRUE(first);
    EXPECT_EQ(decodeMessageHeader(first->data()).type, MessageType::Message);
}

// The automatic loop count: one loop per core to begin with; another once every loop serves
// 8 connections, at most two per core; every connection is served wherever it landed.
TEST_F(TcpTest, AutomaticLoopCountGrowsWithConnectionsUpToTwoPerCore) {
    scfg.eventLoops = 0;
    start();  // the observer: 1 connection
    const std::size_t cores = std::clamp<std::size_t>(std::thread::hardware_concurrency(), 1, 4);
    auto threads = [] {
        std::size_t n = 0;
        for (const auto& e : std::filesystem::directory_iterator("/proc/self/task")) {
            (void)e;
            ++n;
        }
        return n;
    };
    const std::size_t before = threads();
    std::vector<std::unique_ptr<ClientConnection>> conns;
    while (conns.size() + 1 < 8 * cores) conns.push_back(connect());
    EXPECT_EQ(threads(), before) << "8 connections per loop fit the first loops";
    conns.push_back(connect());  // 8 * cores + 1 connections
    EXPECT_EQ(threads(), before + 1) << "one more loop";
    while (conns.size() + 1 < 16 * cores + 8) conns.push_back(connect());
    EXPECT_EQ(threads(), before + cores) << "at most two loops per core";
    for (std::size_t k = 0; k < conns.size(); ++k) {
        Buffer body = pattern(32, static_cast<unsigned>(k));
        auto r = roundTrip(*conns[k], body);
        EXPECT_EQ(r.body, body) << "connection " << k;
    }
    expectObserverWorks();
}

TEST_F(TcpTest, ResponseFromWorkerThread) {
    start();
    auto c = connect();
    for (int i = 0; i < 20; ++i) {
        Buffer body = pattern(50, i);
        auto r = roundTrip(*c, body, kLater);
        EXPECT_EQ(r.body, body);
    }
}

TEST_F(TcpTest, ServiceFault) {
    start();
    auto c = connect();
    auto r = roundTrip(*c, {}, kFault);
    EXPECT_EQ(r.typeId, NodeId(0, DataTypeInfo<ServiceFault>::binaryEncodingId));
    auto f = decodeFromBuffer<ServiceFault>(r.body.data(), r.body.size());
    EXPECT_EQ(f.responseHeader.serviceResult, status::BadNodeIdUnknown);
    EXPECT_EQ(f.responseHeader.requestHandle, 4242u);
}

TEST_F(TcpTest, ReceiveTimesOutWithoutClosing) {
    start();
    auto t0 = Clock::now();
    EXPECT_FALSE(observer->receive(Clock::now() + 100ms).has_value());
    EXPECT_GE(Clock::now() - t0, 100ms);
    EXPECT_FALSE(observer->receive(Clock::now() - 1s).has_value());  // non-blocking
    expectObserverWorks();
}

// ---- token renewal ---------------------------------------------------------------------
TEST_F(TcpTest, TokenRenewalWhileBusy) {
    start();
    ClientConfig cfg = ccfg;
    cfg.requestedLifetime = 1000ms;
    auto c = connect(cfg);
    EXPECT_EQ(c->revisedLifetime(), 1000ms);
    std::set<UInt32> tokens{c->tokenId()};
    auto end = Clock::now() + 3s;
    int n = 0;
    while (Clock::now() < end) {
        Buffer body = pattern(20, n++);
        EXPECT_EQ(roundTrip(*c, body).body, body);
        tokens.insert(c->tokenId());
        std::this_thread::sleep_for(20ms);
    }
    EXPECT_GE(tokens.size(), 3u);  // renewed at 750 ms, 1.5 s, 2.25 s
    EXPECT_TRUE(c->isOpen());
}

TEST_F(TcpTest, TokenRenewalWhileWaitingInReceive) {
    start();
    ClientConfig cfg = ccfg;
    cfg.requestedLifetime = 1000ms;
    auto c = connect(cfg);
    UInt32 first = c->tokenId();
    // Idle in receive() for 3 s: it wakes up to renew by itself.
    EXPECT_FALSE(c->receive(Clock::now() + 3s).has_value());
    EXPECT_NE(c->tokenId(), first);
    Buffer body = pattern(10);
    EXPECT_EQ(roundTrip(*c, body).body, body);
}

TEST_F(TcpTest, ExpiredTokenClosesChannel) {
    start();
    RawClient raw(server->port(), [] {
        auto c = RawClient::defaultConfig();
        c.requestedLifetime = 500ms;
        return c;
    }());
    ASSERT_TRUE(raw.open());
    auto t0 = Clock::now();
    // No renewal: closed after 500 ms * 1.25 (+ housekeeping period).
    EXPECT_EQ(raw.sock.expectError(Clock::now() + 3s), status::BadSecureChannelClosed);
    EXPECT_TRUE(raw.sock.waitClosed());
    auto took = Clock::now() - t0;
    EXPECT_GE(took, 550ms);
    EXPECT_LE(took, 1500ms);
    expectObserverWorks();
}

// ---- limits ----------------------------------------------------------------------------
TEST_F(TcpTest, RequestLargerThanMaxMessageSize) {
    scfg.maxMessageSize = 64 * 1024;
    start();
    // The well-behaved client refuses to send it; the connection stays usable.
    auto c = connect();
    try {
        c->send(requestMessage(kEcho, pattern(100 * 1024)));
        FAIL() << "no exception";
    } catch (const TransportError& e) {
        EXPECT_EQ(e.status(), status::BadRequestTooLarge);
    }
    EXPECT_TRUE(c->isOpen());
    EXPECT_EQ(roundTrip(*c, pattern(1000)).body, pattern(1000));
    // A lying client gets ERR BadTcpMessageTooLarge.
    RawClient raw(server->port());
    ASSERT_TRUE(raw.open());
    UInt32 seq = 2;
    bool sent = true;
    for (int i = 0; i < 9 && sent; ++i)
        sent = raw.sock.send(raw.msg(seq++, 7, pattern(8000), ChunkType::Intermediate));
    raw.sock.send(raw.msg(seq++, 7, pattern(8000), ChunkType::Final));
    EXPECT_EQ(raw.sock.expectError(), status::BadTcpMessageTooLarge);
    EXPECT_TRUE(raw.sock.waitClosed());
    expectObserverWorks();
}

TEST_F(TcpTest, TooManyChunks) {
    scfg.maxChunkCount = 4;
    start();
    RawClient raw(server->port());
    ASSERT_TRUE(raw.open());
    EXPECT_EQ(raw.limits().maxSendChunkCount, 4u);
    for (UInt32 i = 0; i < 4; ++i)
        raw.sock.send(raw.msg(2 + i, 7, pattern(10), ChunkType::Intermediate));
    raw.sock.send(raw.msg(6, 7, pattern(10), ChunkType::Final));
    EXPECT_EQ(raw.sock.expectError(), status::BadTcpMessageTooLarge);
    EXPECT_TRUE(raw.sock.waitClosed());
    expectObserverWorks();
}

TEST_F(TcpTest, ResponseLargerThanClientAccepts) {
    start();
    ClientConfig cfg = ccfg;
    cfg.maxMessageSize = 64 * 1024;
    auto c = connect(cfg);
    Buffer req(8);
    putUInt32(req.data(), 31337);       // request handle
    putUInt32(req.data() + 4, 100000);  // response size
    auto r = roundTrip(*c, req, kBig);
    EXPECT_EQ(r.typeId, NodeId(0, DataTypeInfo<ServiceFault>::binaryEncodingId));
    auto f = decodeFromBuffer<ServiceFault>(r.body.data(), r.body.size());
    EXPECT_EQ(f.responseHeader.serviceResult, status::BadResponseTooLarge);
    EXPECT_EQ(f.responseHeader.requestHandle, 31337u);
    // Within the limit it arrives.
    putUInt32(req.data() + 4, 60000);
    r = roundTrip(*c, req, kBig);
    EXPECT_EQ(r.typeId, kEchoReply);
    EXPECT_EQ(r.body.size(), 60000u + 12);
}

TEST_F(TcpTest, MaxConnections) {
    scfg.maxConnections = 3;
    start();  // observer: 1
    auto a = connect();
    auto b = connect();
    EXPECT_TRUE(eventually([&] { return server->connectionCount() == 3; }));
    try {
        auto d = connect();
        FAIL() << "connected beyond maxConnections";
    } catch (const TransportError& e) {
        EXPECT_EQ(e.status(), status::BadTcpServerTooBusy);
    }
    a.reset();  // sends CLO
    EXPECT_TRUE(eventually([&] { return server->connectionCount() == 2; }));
    auto d = connect();
    EXPECT_TRUE(d->isOpen());
    expectObserverWorks();
}

// ---- misbehaving peers -----------------------------------------------------------------
TEST_F(TcpTest, GarbageBytes) {
    start();
    RawSocket s(server->port());
    ASSERT_TRUE(s.ok());
    std::string junk = "GET / HTTP/1.1\r\nHost: x\r\n\r\n";
    s.send(junk.data(), junk.size());
    EXPECT_EQ(s.expectError(), status::BadTcpMessageTypeInvalid);
    EXPECT_TRUE(s.waitClosed());
    // Random bytes, many times.
    for (int i = 0; i < 20; ++i) {
        RawSocket r(server->port());
        Buffer b = pattern(200 + i * 31, 1000 + i);
        r.send(b);
        EXPECT_TRUE(r.waitClosed()) << i;
    }
    expectObserverWorks();
}

TEST_F(TcpTest, WrongMessageType) {
    start();
    RawClient raw(server->port());
    ASSERT_TRUE(raw.open());
    Buffer m = raw.msg(2, 1, pattern(5));
    std::memcpy(m.data(), "XYZ", 3);
    raw.sock.send(m);
    EXPECT_EQ(raw.sock.expectError(), status::BadTcpMessageTypeInvalid);
    EXPECT_TRUE(raw.sock.waitClosed());
    // An ACK sent to a server.
    RawSocket s(server->port());
    s.send(encodeMessage(Acknowledge{0, 8192, 8192, 0, 0}));
    EXPECT_EQ(s.expectError(), status::BadTcpMessageTypeInvalid);
    expectObserverWorks();
}

TEST_F(TcpTest, LyingLengthField) {
    start();
    RawSocket s(server->port());
    Byte h[8];
    encodeMessageHeader(h, MessageType::Hello, ChunkType::Final, 0x80000000u);  // 2 GiB
    s.send(h, 8);
    EXPECT_EQ(s.expectError(), status::BadTcpMessageTooLarge);
    EXPECT_TRUE(s.waitClosed());
    // After the handshake too: a MSG header claiming 2 GiB.
    RawClient raw(server->port());
    ASSERT_TRUE(raw.open());
    Buffer m = raw.msg(2, 1, pattern(5));
    putUInt32(m.data() + 4, 0x80000000u);
    raw.sock.send(m);
    EXPECT_EQ(raw.sock.expectError(), status::BadTcpMessageTooLarge);
    expectObserverWorks();
}

TEST_F(TcpTest, TruncatedChunkThenPeerVanishes) {
    start();
    int closedBefore = handler.closed.load();
    {
        RawClient raw(server->port());
        ASSERT_TRUE(raw.open());
        Buffer m = raw.msg(2, 1, pattern(4000));
        raw.sock.send(m.data(), m.size() / 2);
        std::this_thread::sleep_for(20ms);
    }  // socket closed mid-chunk
    EXPECT_TRUE(eventually([&] { return handler.closed.load() == closedBefore + 1; }));
    EXPECT_TRUE(eventually([&] { return server->connectionCount() == 1; }));
    expectObserverWorks();
}

TEST_F(TcpTest, HelloWithOversizedEndpointUrl) {
    start();
    RawSocket s(server->port());
    Hello h{0, 8192, 8192, 0, 0, ""};
    Buffer m = encodeMessage(h);
    std::string url(5000, 'x');
    m.resize(m.size() - 4);
    Int32 len = static_cast<Int32>(url.size());
    m.insert(m.end(), reinterpret_cast<Byte*>(&len), reinterpret_cast<Byte*>(&len) + 4);
    m.insert(m.end(), url.begin(), url.end());
    putUInt32(m.data() + 4, static_cast<UInt32>(m.size()));
    s.send(m);
    EXPECT_EQ(s.expectError(), status::BadTcpEndpointUrlInvalid);
    EXPECT_TRUE(s.waitClosed());
    expectObserverWorks();
}

TEST_F(TcpTest, MessageBeforeOpenSecureChannel) {
    start();
    RawSocket s(server->port());
    ClientConfig cfg = RawClient::defaultConfig();
    s.send(encodeMessage(makeHello(cfg, url())));
    auto ack = s.readChunk();
    ASSERT_TRUE(ack);
    EXPECT_EQ(decodeMessageHeader(ack->data()).type, MessageType::Acknowledge);
    Buffer m = requestMessage(kEcho, pattern(10));
    encodeMessageHeader(m.data(), MessageType::Message, ChunkType::Final,
                        static_cast<UInt32>(m.size()));
    s.send(m);
    EXPECT_EQ(s.expectError(), status::BadTcpMessageTypeInvalid);
    EXPECT_TRUE(s.waitClosed());
    expectObserverWorks();
}

TEST_F(TcpTest, WrongChannelId) {
    start();
    RawClient raw(server->port());
    ASSERT_TRUE(raw.open());
    raw.sock.send(raw.msg(2, 1, pattern(5), ChunkType::Final, raw.channelId() + 1000));
    EXPECT_EQ(raw.sock.expectError(), status::BadSecureChannelIdInvalid);
    EXPECT_TRUE(raw.sock.waitClosed());
    expectObserverWorks();
}

TEST_F(TcpTest, WrongTokenId) {
    start();
    RawClient raw(server->port());
    ASSERT_TRUE(raw.open());
    raw.sock.send(raw.msg(2, 1, pattern(5), ChunkType::Final, {}, 999999));
    EXPECT_EQ(raw.sock.expectError(), status::BadSecureChannelTokenUnknown);
    EXPECT_TRUE(raw.sock.waitClosed());
    expectObserverWorks();
}

TEST_F(TcpTest, WrongSequenceNumber) {
    start();
    RawClient raw(server->port());
    ASSERT_TRUE(raw.open());
    raw.sock.send(raw.msg(2, 1, pattern(5)));
    auto resp = raw.sock.readChunk();  // the echo of request 1
    ASSERT_TRUE(resp);
    EXPECT_EQ(decodeMessageHeader(resp->data()).type, MessageType::Message);
    raw.sock.send(raw.msg(2, 2, pattern(5)));  // repeated
    EXPECT_EQ(raw.sock.expectError(), status::BadSequenceNumberInvalid);
    EXPECT_TRUE(raw.sock.waitClosed());
    expectObserverWorks();
}

TEST_F(TcpTest, AbortChunkKeepsConnection) {
    start();
    RawClient raw(server->port());
    ASSERT_TRUE(raw.open());
    raw.sock.send(raw.msg(2, 1, pattern(3000), ChunkType::Intermediate));
    Buffer ab = raw.msg(3, 1, {}, ChunkType::Abort);
    ab.resize(kSymmetricHeaderSize + 8);
    putUInt32(ab.data() + 4, static_cast<UInt32>(ab.size()));
    putUInt32(ab.data() + 24, status::BadRequestCancelledByClient.value);
    putUInt32(ab.data() + 28, 0xFFFFFFFFu);
    raw.sock.send(ab);
    raw.sock.send(raw.msg(4, 2, pattern(7)));
    auto resp = raw.sock.readChunk();
    ASSERT_TRUE(resp);
    auto h = decodeMessageHeader(resp->data());
    EXPECT_EQ(h.type, MessageType::Message);
    EXPECT_EQ(getUInt32(resp->data() + 20), 2u);  // request 1 was dropped
    expectObserverWorks();
}

TEST_F(TcpTest, ClientThatNeverReadsIsThrottled) {
    start();
    RawClient raw(server->port());
    ASSERT_TRUE(raw.open());
    // Send 8 KB echo requests (one chunk each) without reading the responses until the
    // server stops reading (its queued output is bounded, then the kernel buffers fill up).
    Buffer body = pattern(8000);
    std::size_t sentBytes = 0;
    UInt32 seq = 2;
    auto end = Clock::now() + 20s;
    while (Clock::now() < end && sentBytes < (512u << 20)) {
        Buffer m = raw.msg(seq, seq, body);
        if (!raw.sock.trySend(m, 300ms)) break;  // the server stopped reading
        sentBytes += m.size();
        ++seq;
    }
    std::printf("[ throttle ] server stopped reading after %.1f MiB of unanswered requests\n",
                static_cast<double>(sentBytes) / (1 << 20));
    EXPECT_LT(sentBytes, 128u << 20);
    // Still a working connection: nothing was answered with an ERR.
    auto first = raw.sock.readChunk();
    ASSERT_TRUE(first);
    EXPECT_EQ(decodeMessageHeader(first->data()).type, MessageType::Message);
    expectObserverWorks();
}

TEST_F(TcpTest, HelloTimeout) {
    scfg.helloTimeout = 300ms;
    start();
    RawSocket s(server->port());
    auto t0 = Clock::now();
    EXPECT_EQ(s.expectError(), status::BadTimeout);
    EXPECT_TRUE(s.waitClosed());
    EXPECT_GE(Clock::now() - t0, 250ms);
    EXPECT_LE(Clock::now() - t0, 2000ms);
    expectObserverWorks();
}

TEST_F(TcpTest, IdleTimeout) {
    scfg.idleTimeout = 300ms;
    start();
    auto c = connect();
    std::this_thread::sleep_for(800ms);
    try {
        roundTrip(*c, pattern(1));
        FAIL() << "idle connection not closed";
    } catch (const TransportError& e) {
        EXPECT_EQ(e.status(), status::BadTimeout);  // the server's ERR
    }
    EXPECT_FALSE(c->isOpen());
}

// ---- closing ---------------------------------------------------------------------------
TEST_F(TcpTest, ServerClosesConnection) {
    start();
    auto c = connect();
    int closedBefore = handler.closed.load();
    c->send(requestMessage(kClose, {}));
    try {
        c->receive(Clock::now() + 5s);
        FAIL() << "no exception";
    } catch (const TransportError& e) {
        EXPECT_EQ(e.status(), status::BadConnectionClosed);
    }
    EXPECT_FALSE(c->isOpen());
    EXPECT_TRUE(eventually([&] { return handler.closed.load() == closedBefore + 1; }));
    expectObserverWorks();
}

TEST_F(TcpTest, ClientCloseSendsClo) {
    start();
    auto c = connect();
    int closedBefore = handler.closed.load();
    c->close();
    EXPECT_FALSE(c->isOpen());
    EXPECT_EQ(c->nativeHandle(), -1);
    EXPECT_TRUE(eventually([&] { return handler.closed.load() == closedBefore + 1; }));
    try {
        c->send(requestMessage(kEcho, {}));
        FAIL() << "sent on a closed connection";
    } catch (const TransportError& e) {
        EXPECT_EQ(e.status(), status::BadConnectionClosed);
    }
}

TEST_F(TcpTest, StopClosesEverything) {
    start();
    auto c = connect();
    server->stop();
    EXPECT_EQ(handler.closed.load(), 2);
    EXPECT_FALSE(server->running());
    try {
        c->receive(Clock::now() + 5s);
        FAIL() << "no exception";
    } catch (const TransportError& e) {
        EXPECT_EQ(e.status(), status::BadConnectionClosed);
    }
    observer.reset();
}

TEST_F(TcpTest, StopWhileClientsAreBusy) {
    start();
    constexpr int kClients = 4;
    std::atomic<bool> go{true};
    std::atomic<int> connected{0};
    std::vector<std::thread> clients;
    for (int k = 0; k < kClients; ++k) {
        clients.emplace_back([&] {
            try {
                auto c = connect();
                connected.fetch_add(1);
                Buffer body = pattern(3000);
                for (int i = 0; i < 100000 && go.load(); ++i) roundTrip(*c, body);
            } catch (const std::exception&) {
                // the server went away: expected
            }
        });
    }
    EXPECT_TRUE(eventually([&] { return connected.load() == kClients; }));
    std::this_thread::sleep_for(50ms);
    auto t0 = Clock::now();
    server->stop();
    EXPECT_LT(Clock::now() - t0, 2s);
    EXPECT_EQ(handler.closed.load(), kClients + 1);  // + the observer
    go = false;
    for (auto& t : clients) t.join();
    observer.reset();
}

TEST_F(TcpTest, PostAndTick) {
    start();
    std::atomic<int> ticks{0};
    std::atomic<bool> onNetworkThread{false};
    server->setTick(20ms, [&] {
        if (server->isNetworkThread()) ticks.fetch_add(1);
    });
    std::promise<void> done;
    server->post([&] {
        onNetworkThread = server->isNetworkThread();
        done.set_value();
    });
    EXPECT_EQ(done.get_future().wait_for(5s), std::future_status::ready);
    EXPECT_TRUE(onNetworkThread.load());
    EXPECT_FALSE(server->isNetworkThread());
    EXPECT_TRUE(eventually([&] { return ticks.load() >= 5; }));
    server->setTick(0ms, {});
    std::this_thread::sleep_for(50ms);
    int now = ticks.load();
    std::this_thread::sleep_for(100ms);
    EXPECT_EQ(ticks.load(), now);
}

// ---- client errors ---------------------------------------------------------------------
TEST(ClientConnect, Errors) {
    ClientConfig cfg;
    auto statusOf = [&](const std::string& url, std::chrono::milliseconds t = 2000ms) {
        try {
            ClientConnection::connect(url, cfg, Clock::now() + t);
        } catch (const TransportError& e) {
            return e.status();
        }
        return StatusCode{};
    };
    EXPECT_EQ(statusOf("http://127.0.0.1:1"), status::BadTcpEndpointUrlInvalid);
    // A port nobody listens on.
    int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    socklen_t len = sizeof a;
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    UInt16 port = ntohs(a.sin_port);
    EXPECT_EQ(statusOf("opc.tcp://127.0.0.1:" + std::to_string(port)),
              status::BadCommunicationError);
    // A listener that never answers the Hello.
    ASSERT_EQ(::listen(fd, 4), 0);
    auto t0 = Clock::now();
    EXPECT_EQ(statusOf("opc.tcp://127.0.0.1:" + std::to_string(port), 300ms), status::BadTimeout);
    EXPECT_LT(Clock::now() - t0, 2s);
    ::close(fd);
    EXPECT_EQ(statusOf("opc.tcp://no-such-host.invalid:4840"), status::BadCommunicationError);
}

// ---- latency (informational) -----------------------------------------------------------
TEST_F(TcpTest, RoundTripLatency) {
    start();
    auto c = connect();
    Buffer body = pattern(64);
    for (int i = 0; i < 200; ++i) roundTrip(*c, body);  // warm up
    const int n = 5000;
    std::vector<double> us;
    us.reserve(n);
    for (int i = 0; i < n; ++i) {
        auto t0 = Clock::now();
        roundTrip(*c, body);
        us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
    }
    std::sort(us.begin(), us.end());
    std::printf(
        "[ latency  ] 64-byte echo round trip over 127.0.0.1: median %.1f us, p99 %.1f us\n",
        us[n / 2], us[n * 99 / 100]);
    Buffer mib = pattern(1 << 20);
    auto t0 = Clock::now();
    for (int i = 0; i < 20; ++i) roundTrip(*c, mib);
    double s = std::chrono::duration<double>(Clock::now() - t0).count();
    std::printf(
        "[ latency  ] 1 MiB echo (8 KiB chunks): %.2f ms per round trip, %.0f MiB/s each way\n",
        s / 20 * 1000, 20 / s);
}

}  // namespace
}  // namespace pnp::ua::transport
