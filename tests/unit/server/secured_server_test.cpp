// A secured server over real sockets: our client with every policy, and attackers on other
// connections (garbage in a well-formed OPN: BadSecurityChecksFailed; a flood of chunks
// before any channel is open) who are closed while the honest client keeps being served.
// (Attacks on an open encrypted channel — tampered, replayed, flooded chunks — and
// certificates refused at OPN / CreateSession: secured_attacks_test.cpp.)
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/pki/pki.hpp"
#include "ua/server/server.hpp"
#include "ua/transport/secure_channel.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::secured_server_test {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

pki::Identity makeIdentity(const std::string& uri) {
    pki::CertificateRequest r;
    r.applicationUri = uri;
    r.commonName = uri;
    r.dnsNames = {"localhost"};
    return pki::createSelfSigned(r);
}
const pki::Identity& serverIdentity() {
    static const pki::Identity id = makeIdentity("urn:pnp:test:secured-server");
    return id;
}
const pki::Identity& clientIdentity() {
    static const pki::Identity id = makeIdentity("urn:pnp:test:secured-client");
    return id;
}

server::ServerConfig securedConfig() {
    auto c = pnp::testing::loopbackConfig();
    c.applicationUri = "urn:pnp:test:secured-server";
    server::ServerSecurity s;
    s.identity = serverIdentity();  // trust: null (every well-formed certificate)
    c.security = s;
    return c;
}

client::ClientConfig securedClient(const std::string& policyUri) {
    client::ClientConfig c;
    c.applicationUri = "urn:pnp:test:secured-client";
    client::ClientSecurity s;
    s.identity = clientIdentity();
    s.policyUri = policyUri;
    c.security = s;
    return c;
}

// A raw TCP connection to the server (bounded waits).
class RawSocket {
  public:
    explicit RawSocket(UInt16 port) : fd_(::socket(AF_INET, SOCK_STREAM, 0)) {
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(port);
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
    }
    ~RawSocket() { ::close(fd_); }
    bool connected() const { return connected_; }
    bool send(const Buffer& b) {
        return ::send(fd_, b.data(), b.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(b.size());
    }
    // Everything until the server closes the connection (or the deadline).
    std::vector<Byte> readUntilClosed(std::chrono::milliseconds timeout) {
        std::vector<Byte> all;
        const auto until = Clock::now() + timeout;
        while (Clock::now() < until) {
            pollfd p{fd_, POLLIN, 0};
            if (::poll(&p, 1, 50) <= 0) continue;
            Byte buf[4096];
            const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
            if (n <= 0) return all;
            all.insert(all.end(), buf, buf + n);
        }
        return all;
    }

  private:
    int fd_;
    bool connected_ = false;
};

// The status of the first ERR message in `bytes`, Good when there is none.
StatusCode errIn(const std::vector<Byte>& bytes) {
    std::size_t at = 0;
    while (at + 8 <= bytes.size()) {
        const auto h = transport::decodeMessageHeader(bytes.data() + at);
        if (h.size < 8 || at + h.size > bytes.size()) break;
        if (h.type == transport::MessageType::Error)
            return transport::decodeError(bytes.data() + at + 8, h.size - 8).error;
        at += h.size;
    }
    return StatusCode{};
}

TEST(SecuredServer, EveryPolicyOverRealSockets) {
    server::Server s(securedConfig());
    s.start();
    for (const auto& policy : crypto::securityPolicies()) {
        client::Client c(securedClient(std::string(policy.uri)));
        c.connect(pnp::testing::url(s));
        EXPECT_TRUE(c.readValue(NodeId(0, ns0::Server_ServerStatus_State)) == Variant(Int32{0}))
            << policy.uri;
    }
}

TEST(SecuredServer, AWithoutSecurityClientGetsNoSessionButDiscovery) {
    server::Server s(securedConfig());
    s.start();
    client::Client c;  // no security: the None channel serves discovery only
    EXPECT_GE(c.getEndpoints(pnp::testing::url(s)).size(), 6u);
    try {
        c.connect(pnp::testing::url(s));
        FAIL() << "a session on SecurityPolicy None was accepted";
    } catch (const client::Error& e) {
        EXPECT_EQ(e.status(), status::BadSecurityPolicyRejected);
    }
}

TEST(SecuredServer, AttackersAreClosedWhileAnHonestClientIsServed) {
    server::Server s(securedConfig());
    s.start();
    client::Client honest(securedClient(""));
    honest.connect(pnp::testing::url(s));

    std::atomic<bool> stop{false};
    std::atomic<int> reads{0}, failures{0};
    std::thread reader([&] {
        while (!stop) {
            try {
                honest.readValue(NodeId(0, ns0::Server_ServerStatus_State));
                ++reads;
            } catch (const std::exception&) {
                ++failures;
            }
        }
    });

    const auto& policy = crypto::securityPolicies().front();
    const Buffer hello = transport::encodeMessage(
        transport::makeHello(transport::ClientConfig{}, pnp::testing::url(s)));
    // 1. A well-formed OPN header (our policy, a certificate, the server's thumbprint) around
    //    garbage, 20 times on new connections.
    for (int i = 0; i < 20; ++i) {
        RawSocket a(s.port());
        ASSERT_TRUE(a.connected());
        Buffer opn(8);
        BinaryEncoder e(opn);
        e.number(UInt32{0});
        e.number(static_cast<Int32>(policy.uri.size()));
        e.raw(policy.uri.data(), policy.uri.size());
        const auto& der = clientIdentity().certificate.der();
        e.number(static_cast<Int32>(der.size()));
        e.raw(der.data(), der.size());
        const auto thumb = serverIdentity().certificate.thumbprint();
        e.number(static_cast<Int32>(thumb.size()));
        e.raw(thumb.data(), thumb.size());
        for (int k = 0; k < 256 * 4; ++k) e.number(static_cast<Byte>(k * 7 + i));
        transport::encodeMessageHeader(opn.data(), transport::MessageType::OpenSecureChannel,
                                       transport::ChunkType::Final,
                                       static_cast<UInt32>(opn.size()));
        ASSERT_TRUE(a.send(hello));
        ASSERT_TRUE(a.send(opn));
        EXPECT_EQ(errIn(a.readUntilClosed(5s)), status::BadSecurityChecksFailed);
    }
    // 2. A flood of MSG chunks on one connection after its HEL, before any OpenSecureChannel.
    {
        RawSocket a(s.port());
        ASSERT_TRUE(a.connected());
        ASSERT_TRUE(a.send(hello));
        Buffer flood;
        for (int i = 0; i < 200; ++i) {
            Buffer chunk(8 + 8 + 8 + 64);
            transport::encodeMessageHeader(chunk.data(), transport::MessageType::Message,
                                           transport::ChunkType::Intermediate,
                                           static_cast<UInt32>(chunk.size()));
            flood.insert(flood.end(), chunk.begin(), chunk.end());
        }
        a.send(flood);  // the server may close before it has read it all
        EXPECT_TRUE(errIn(a.readUntilClosed(5s)).isBad());
    }
    stop = true;
    reader.join();
    EXPECT_GT(reads.load(), 20);
    EXPECT_EQ(failures.load(), 0);
    // And it still answers afterwards.
    EXPECT_TRUE(honest.readValue(NodeId(0, ns0::Server_ServerStatus_State)) == Variant(Int32{0}));
}

}  // namespace pnp::ua::secured_server_test
