// The server under many clients (issue 26): 500 concurrent sessions over real loopback
// connections while other peers misbehave — connections that never say Hello, garbage
// instead of a message, a message header whose body never comes, a client that sends
// requests and never reads — and every session keeps being served; the session over the
// limit is refused with BadTooManySessions and nobody else notices.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <memory>
#include <thread>
#include <vector>

#include "support/loopback_server.hpp"
#include "support/raw_socket.hpp"
#include "ua/client/client.hpp"
#include "ua/server/server.hpp"
#include "ua/transport/tcp_messages.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/status_codes.hpp"

namespace {

using namespace std::chrono_literals;
namespace ua = pnp::ua;
using Clock = std::chrono::steady_clock;

constexpr std::size_t kSessions = 500;

TEST(ManySessions, FiveHundredSessionsAreServedWhileSomePeersMisbehave) {
    auto config = pnp::testing::loopbackConfig();
    config.maxSessions = kSessions + 5;
    config.transport.helloTimeout = 2s;
    ua::server::Server server(config);
    server.start();
    const std::string url = pnp::testing::url(server);
    const ua::NodeId state(0, ua::ns0::Server_ServerStatus_State);

    std::vector<std::unique_ptr<ua::client::Client>> clients;
    clients.reserve(kSessions);
    for (std::size_t i = 0; i < kSessions; ++i) {
        auto c = std::make_unique<ua::client::Client>();
        ASSERT_NO_THROW(c->connect(url)) << "session " << i;
        clients.push_back(std::move(c));
    }
    ASSERT_EQ(server.sessionCount(), kSessions);

    // The misbehaving peers, all at once.
    std::vector<std::unique_ptr<ua::test::RawSocket>> silent, garbage, stalled;
    for (int i = 0; i < 10; ++i) {
        silent.push_back(std::make_unique<ua::test::RawSocket>(server.port()));  // no Hello
        garbage.push_back(std::make_unique<ua::test::RawSocket>(server.port()));
        stalled.push_back(std::make_unique<ua::test::RawSocket>(server.port()));
    }
    for (auto& g : garbage) {
        ASSERT_TRUE(g->ok());
        const char junk[] = "GET / HTTP/1.1\r\nHost: x\r\n\r\nnot opc.tcp at all";
        g->send(junk, sizeof junk);
    }
    for (auto& s : stalled) {
        ASSERT_TRUE(s->ok());
        // A Hello chunk header that announces 64 KiB, then only part of it.
        ua::Buffer hello = ua::transport::encodeMessage(ua::transport::Hello{
            .receiveBufferSize = 65536, .sendBufferSize = 65536, .endpointUrl = url});
        ua::transport::encodeMessageHeader(hello.data(), ua::transport::MessageType::Hello,
                                           ua::transport::ChunkType::Final, 65536);
        s->send(hello);
    }
    // A client with a session that sends requests and never reads the responses.
    ua::client::Client flooder;
    flooder.connect(url);
    for (int i = 0; i < 2000; ++i)  // no background thread: nothing reads the responses
        flooder.readValueAsync(
            state, [](ua::client::Result<ua::Variant>) {}, 60s);

    // Every session is served meanwhile, each within the request's deadline.
    std::size_t served = 0;
    double worstMs = 0;
    for (auto& c : clients) {
        const auto t0 = Clock::now();
        try {
            c->readValue(state, 5s);
            ++served;
        } catch (const std::exception& e) {
            ADD_FAILURE() << "a session was not served: " << e.what();
        }
        worstMs =
            std::max(worstMs, std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    }
    EXPECT_EQ(served, kSessions);
    std::printf("[ figures  ] %zu sessions served while 30 peers misbehaved: worst Read %.1f ms\n",
                served, worstMs);

    // Garbage gets an ERR and the close; silence and half a Hello end with the Hello timeout.
    for (auto& g : garbage) {
        EXPECT_TRUE(g->expectError().isBad());
        EXPECT_TRUE(g->waitClosed(Clock::now() + 5s));
    }
    for (auto& s : silent) EXPECT_TRUE(s->waitClosed(Clock::now() + 10s));
    for (auto& s : stalled) EXPECT_TRUE(s->waitClosed(Clock::now() + 10s));

    // Up to the limit, then BadTooManySessions for the next one only.
    std::vector<std::unique_ptr<ua::client::Client>> more;
    while (server.sessionCount() < config.maxSessions) {
        more.push_back(std::make_unique<ua::client::Client>());
        ASSERT_NO_THROW(more.back()->connect(url));
    }
    ua::client::Client over;
    EXPECT_EQ(pnp::testing::errorOf([&] { over.connect(url); }), ua::status::BadTooManySessions);
    for (std::size_t i = 0; i < kSessions; i += 50)
        EXPECT_NO_THROW(clients[i]->readValue(state, 5s)) << "session " << i;

    // Every session closes cleanly.
    more.clear();
    flooder.disconnect();
    for (auto& c : clients) c->disconnect();
    const auto until = Clock::now() + 10s;
    while (server.sessionCount() > 0 && Clock::now() < until) std::this_thread::sleep_for(10ms);
    EXPECT_EQ(server.sessionCount(), 0u);
    server.stop();
}

}  // namespace
