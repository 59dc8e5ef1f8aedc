// The server's hot path allocates nothing per request beyond the response Buffer the
// handler creates: counts operator new calls on the connection's thread (where the server
// reads, decodes, calls the handler and writes) during steady-state round trips.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>

#include "ua/transport/client_connection.hpp"
#include "ua/transport/tcp_server.hpp"

namespace {
thread_local std::size_t t_allocations = 0;
}

void* operator new(std::size_t n) {
    ++t_allocations;
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void* operator new[](std::size_t n) {
    ++t_allocations;
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

namespace pnp::ua::transport {
namespace {

using namespace std::chrono_literals;

class EchoHandler : public ServiceHandler {
  public:
    void onRequest(const std::shared_ptr<ServerConnection>& c, const IncomingRequest& r) override {
        allocationsSeen.store(t_allocations);             // this thread's count before this request
        Buffer m = ServerConnection::newMessageBuffer();  // the one expected allocation
        BinaryEncoder e(m);
        encode(e, NodeId(1, 2));
        e.raw(r.body, r.size);
        c->send(r.requestId, std::move(m));
    }
    std::atomic<std::size_t> allocationsSeen{0};
};

TEST(ServerHotPath, OneAllocationPerRequest) {
    EchoHandler handler;
    ServerTransportConfig cfg;
    cfg.host = "127.0.0.1";
    cfg.port = 0;
    TcpServer server(cfg, handler);
    server.start();
    auto c = ClientConnection::connect("opc.tcp://127.0.0.1:" + std::to_string(server.port()),
                                       ClientConfig{}, Clock::now() + 5s);
    Buffer body(200, 7);
    auto roundTrip = [&] {
        Buffer m = ClientConnection::newMessageBuffer();
        BinaryEncoder e(m);
        encode(e, NodeId(1, 1));
        e.raw(body.data(), body.size());
        UInt32 id = c->send(std::move(m));
        auto r = c->receive(Clock::now() + 5s);
        ASSERT_TRUE(r);
        ASSERT_EQ(r->requestId, id);
    };
    for (int i = 0; i < 200; ++i) roundTrip();  // warm up
    const std::size_t before = handler.allocationsSeen.load();
    const int n = 2000;
    for (int i = 0; i < n; ++i) roundTrip();
    const std::size_t after = handler.allocationsSeen.load();
    std::printf("[ allocs   ] connection thread: %.3f allocations per request\n",
                static_cast<double>(after - before) / n);
    // One for the response buffer, a little slack.
    EXPECT_LE(after - before, static_cast<std::size_t>(n) + 20);
    c.reset();
    server.stop();
}

}  // namespace
}  // namespace pnp::ua::transport
