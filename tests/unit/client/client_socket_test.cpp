// The client against raw TCP listeners that are no OPC UA server: one that never answers,
// one that accepts and drops the connection, a closed port. Deadlines must hold and the
// client must stay usable.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "fake_server.hpp"
#include "support/loopback.hpp"
#include "ua/client/client.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::client {
namespace {

using namespace std::chrono_literals;
using pnp::testing::errorOf;

// A listening socket on 127.0.0.1 that never accepts (the kernel completes the handshake).
class SilentListener {
  public:
    SilentListener() {
        fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        a.sin_port = 0;
        EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
        EXPECT_EQ(::listen(fd_, 16), 0);
        socklen_t len = sizeof a;
        ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &len);
        port_ = ntohs(a.sin_port);
    }
    ~SilentListener() { ::close(fd_); }
    int fd() const { return fd_; }
    std::string url() const { return pnp::testing::url(port_); }

  private:
    int fd_ = -1;
    UInt16 port_ = 0;
};

// Accepts connections and closes them at once (after reading the first bytes).
class DroppingListener {
  public:
    DroppingListener() {
        thread_ = std::thread([this] {
            while (!stop_) {
                pollfd p{listener_.fd(), POLLIN, 0};
                if (::poll(&p, 1, 20) <= 0) continue;
                int c = ::accept(listener_.fd(), nullptr, nullptr);
                if (c < 0) continue;
                char buf[256];
                pollfd q{c, POLLIN, 0};
                if (::poll(&q, 1, 500) > 0) [[maybe_unused]]
                    auto n = ::read(c, buf, sizeof buf);
                ::close(c);
                ++accepted_;
            }
        });
    }
    ~DroppingListener() {
        stop_ = true;
        thread_.join();
    }
    std::string url() const { return listener_.url(); }
    int accepted() const { return accepted_; }

  private:
    SilentListener listener_;
    std::atomic<bool> stop_{false};
    std::atomic<int> accepted_{0};
    std::thread thread_;
};

TEST(ClientSocket, CallsWithoutConnectionFailWithBadNotConnected) {
    Client c;
    EXPECT_FALSE(c.isConnected());
    EXPECT_EQ(c.nativeHandle(), -1);
    EXPECT_EQ(errorOf([&] { c.readValue(NodeId(0, 2258)); }), status::BadNotConnected);
    EXPECT_EQ(errorOf([&] { c.getEndpoints(); }), status::BadNotConnected);
    EXPECT_EQ(errorOf([&] { c.writeValue(NodeId(1, 1), Int32{1}); }), status::BadNotConnected);
    c.disconnect();  // harmless
}

TEST(ClientSocket, ConnectToSilentListenerTimesOut) {
    SilentListener l;
    Client c;
    auto t0 = Clock::now();
    EXPECT_EQ(errorOf([&] { c.connect(l.url(), Anonymous{}, 200ms); }), status::BadTimeout);
    auto elapsed = Clock::now() - t0;
    EXPECT_GE(elapsed, 190ms);
    EXPECT_LT(elapsed, 1500ms);
    EXPECT_FALSE(c.isConnected());

    // The default deadline is config().connectTimeout.
    ClientConfig cfg;
    cfg.connectTimeout = 150ms;
    Client c2(cfg);
    t0 = Clock::now();
    EXPECT_EQ(errorOf([&] { c2.connect(l.url()); }), status::BadTimeout);
    EXPECT_LT(Clock::now() - t0, 1500ms);

    // Still usable afterwards.
    testing::FakeServer server;
    c.connect(server.url());
    EXPECT_TRUE(c.isConnected());
    EXPECT_EQ(c.readValue(NodeId(1, "Int32")), Variant(Int32{7}));
}

TEST(ClientSocket, DiscoveryAgainstSilentListenerTimesOut) {
    SilentListener l;
    Client c;
    auto t0 = Clock::now();
    EXPECT_EQ(errorOf([&] { c.getEndpoints(l.url(), 150ms); }), status::BadTimeout);
    EXPECT_LT(Clock::now() - t0, 1500ms);
}

TEST(ClientSocket, ListenerThatDropsTheConnection) {
    DroppingListener l;
    Client c;
    auto t0 = Clock::now();
    StatusCode s = errorOf([&] { c.connect(l.url(), Anonymous{}, 5s); });
    EXPECT_TRUE(s.isBad());
    EXPECT_NE(s, status::BadTimeout);
    EXPECT_LT(Clock::now() - t0, 2s);
    EXPECT_FALSE(c.isConnected());
    // Again: the client is reusable.
    s = errorOf([&] { c.connect(l.url(), Anonymous{}, 5s); });
    EXPECT_TRUE(s.isBad());
    EXPECT_GE(l.accepted(), 1);
}

TEST(ClientSocket, ClosedPortIsRefused) {
    UInt16 port;
    {
        SilentListener l;  // grab a free port, then close it
        port = static_cast<UInt16>(std::stoi(l.url().substr(l.url().rfind(':') + 1)));
    }
    Client c;
    auto t0 = Clock::now();
    StatusCode s = errorOf([&] { c.connect(pnp::testing::url(port), Anonymous{}, 5s); });
    EXPECT_TRUE(s.isBad());
    EXPECT_LT(Clock::now() - t0, 2s);
}

TEST(ClientSocket, InvalidUrl) {
    Client c;
    EXPECT_EQ(errorOf([&] { c.connect("http://nowhere"); }), status::BadTcpEndpointUrlInvalid);
}

}  // namespace
}  // namespace pnp::ua::client
