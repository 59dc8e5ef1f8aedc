// Secured channels in memory: ServerChannel <-> ClientChannel with every supported policy in
// Sign and SignAndEncrypt — handshake, requests of every size (one chunk and many), token
// renewal — and the attacks of OPC 10000-6 §6.7: a tampered signature, a flipped padding byte,
// a wrong receiver thumbprint, an untrusted client, a replayed or skipped sequence number. Each
// closes the channel with an ERR whose status does not say which check failed.
#include <gtest/gtest.h>

#include <deque>
#include <functional>
#include <tuple>

#include "transport_test_util.hpp"
#include "ua/pki/pki.hpp"
#include "ua/transport/secure_channel.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport::secured_test {

using namespace std::chrono_literals;
using test_util::pattern;

const NodeId kEchoRequest(1, 1001);
const NodeId kEchoResponse(1, 1002);

pki::Identity makeIdentity(const std::string& uri, int bits) {
    pki::CertificateRequest r;
    r.applicationUri = uri;
    r.commonName = uri;
    r.dnsNames = {"localhost"};
    r.keyBits = bits;
    return pki::createSelfSigned(r);
}
// Keys take ~100 ms each to generate: made once for the whole test program.
const pki::Identity& serverIdentity() {
    static const pki::Identity id = makeIdentity("urn:pnp:test:server", 2048);
    return id;
}
const pki::Identity& clientIdentity() {
    static const pki::Identity id = makeIdentity("urn:pnp:test:client", 2048);
    return id;
}
const pki::Identity& clientIdentity4096() {
    static const pki::Identity id = makeIdentity("urn:pnp:test:client4096", 4096);
    return id;
}

struct Server : ServerChannel::Hooks {
    std::deque<Buffer>* out = nullptr;
    ServerChannel* channel = nullptr;
    std::vector<UInt32> requests;
    void write(Buffer&& b) override { out->push_back(std::move(b)); }
    void request(const IncomingRequest& r) override {
        requests.push_back(r.requestId);
        Buffer m = newMessageBuffer();
        BinaryEncoder e(m);
        encode(e, kEchoResponse);
        e.raw(r.body, r.size);
        channel->send(r.requestId, std::move(m));
    }
    UInt32 newChannelId() override { return 77; }
};

struct Client : ClientChannel::Hooks {
    std::deque<Buffer>* out = nullptr;
    std::vector<IncomingResponse> responses;
    void write(Buffer&& b) override { out->push_back(std::move(b)); }
    void response(IncomingResponse&& r) override { responses.push_back(std::move(r)); }
};

Buffer echoRequest(const Buffer& body) {
    Buffer m = newMessageBuffer();
    BinaryEncoder e(m);
    encode(e, kEchoRequest);
    e.raw(body.data(), body.size());
    return m;
}

// policy URI, mode
using Param = std::tuple<std::string_view, MessageSecurityMode>;

class SecuredChannel : public ::testing::TestWithParam<Param> {
  protected:
    void SetUp() override {
        policy = crypto::findPolicy(std::get<0>(GetParam()));
        ASSERT_NE(policy, nullptr);
        auto sec = std::make_shared<ServerSecurityConfig>();
        sec->identity = serverIdentity();
        for (const auto& p : crypto::securityPolicies()) sec->policies.push_back(&p);
        sec->validateClient = [this](const std::vector<pki::Certificate>& chain) {
            return chain.front() == trustedClient ? StatusCode{}
                                                  : StatusCode(status::BadCertificateUntrusted);
        };
        serverSecurity = sec;
        scfg.receiveBufferSize = 8192;
        scfg.sendBufferSize = 8192;
        scfg.maxMessageSize = 4 << 20;
        scfg.minTokenLifetime = 1000ms;
        scfg.security = serverSecurity;
        ccfg.receiveBufferSize = 8192;
        ccfg.sendBufferSize = 8192;
        ccfg.maxMessageSize = 4 << 20;
        ccfg.requestedLifetime = 10000ms;
        trustedClient = clientIdentity().certificate;
    }

    void create(const pki::Identity& client = clientIdentity()) {
        auto cs = std::make_shared<ClientSecurityConfig>();
        cs->policy = policy;
        cs->mode = std::get<1>(GetParam());
        cs->identity = client;
        cs->serverCertificate =
            serverCertificate ? *serverCertificate : serverIdentity().certificate;
        ccfg.security = cs;
        serverHooks.out = &toClient;
        clientHooks.out = &toServer;
        server = std::make_unique<ServerChannel>(scfg, serverHooks, now);
        serverHooks.channel = server.get();
        this->client = std::make_unique<ClientChannel>(ccfg, "opc.tcp://test:4840", clientHooks);
    }

    void open(const pki::Identity& client = clientIdentity()) {
        create(client);
        this->client->start(now);
        pump();
        ASSERT_TRUE(this->client->isOpen()) << clientError.toString();
        ASSERT_EQ(server->state(), ServerChannel::State::Open);
        ASSERT_NE(server->security(), nullptr);
        EXPECT_EQ(server->securityMode(), std::get<1>(GetParam()));
        EXPECT_EQ(server->securityPolicyUri(), policy->uri);
    }

    // Delivers what is queued both ways; `tamper` may change a chunk to the server first.
    void pump(const std::function<void(Buffer&)>& tamper = {}) {
        for (int rounds = 0; rounds < 1000 && (!toServer.empty() || !toClient.empty()); ++rounds) {
            if (!toServer.empty()) {
                Buffer b = std::move(toServer.front());
                toServer.pop_front();
                if (tamper) tamper(b);
                sentToServer.push_back(b);
                server->feed(b.data(), b.size(), now);
            }
            if (!toClient.empty()) {
                Buffer b = std::move(toClient.front());
                toClient.pop_front();
                try {
                    client->feed(b.data(), b.size(), now);
                } catch (const TransportError& e) {
                    clientError = e.status();
                }
            }
        }
    }

    Buffer roundTrip(const Buffer& body) {
        const std::size_t before = clientHooks.responses.size();
        const UInt32 id = client->send(echoRequest(body));
        pump();
        EXPECT_EQ(clientHooks.responses.size(), before + 1);
        if (clientHooks.responses.size() != before + 1) return {};
        EXPECT_EQ(clientHooks.responses.back().requestId, id);
        const auto& r = clientHooks.responses.back().body;
        return Buffer(r.begin(), r.end());
    }

    // The server's ERR: what the client was told.
    StatusCode serverClosedWith() const { return server->closeStatus(); }

    const crypto::SecurityPolicy* policy = nullptr;
    std::shared_ptr<const ServerSecurityConfig> serverSecurity;
    std::optional<pki::Certificate> serverCertificate;
    pki::Certificate trustedClient;
    ServerTransportConfig scfg;
    ClientConfig ccfg;
    TimePoint now = Clock::now();
    Server serverHooks;
    Client clientHooks;
    std::unique_ptr<ServerChannel> server;
    std::unique_ptr<ClientChannel> client;
    std::deque<Buffer> toServer, toClient, sentToServer;
    StatusCode clientError;
};

TEST_P(SecuredChannel, EchoOfEverySize) {
    open();
    for (std::size_t n : {0u, 1u, 2u, 15u, 16u, 17u, 100u, 8000u, 8200u, 40000u, 300000u}) {
        const Buffer body = pattern(n);
        EXPECT_EQ(roundTrip(body), body) << n << " bytes";
    }
    EXPECT_EQ(server->state(), ServerChannel::State::Open);
}

TEST_P(SecuredChannel, WhatTravelsIsEncryptedOnlyInSignAndEncrypt) {
    open();
    Buffer body(64);
    for (auto& b : body) b = 0xA5;
    roundTrip(body);
    const Buffer& wire = sentToServer.back();
    bool clear = std::search(wire.begin(), wire.end(), body.begin(), body.end()) != wire.end();
    EXPECT_EQ(clear, std::get<1>(GetParam()) == MessageSecurityMode::Sign);
}

TEST_P(SecuredChannel, TokenRenewalKeepsTheChannel) {
    scfg.minTokenLifetime = 1000ms;
    ccfg.requestedLifetime = 1000ms;
    open();
    const UInt32 first = client->currentTokenId();
    now += 800ms;
    ASSERT_TRUE(client->renewIfDue(now));
    pump();
    EXPECT_NE(client->currentTokenId(), first);
    const Buffer body = pattern(5000);
    EXPECT_EQ(roundTrip(body), body);
    now += 800ms;
    ASSERT_TRUE(client->renewIfDue(now));
    pump();
    EXPECT_EQ(roundTrip(body), body);
    EXPECT_EQ(server->state(), ServerChannel::State::Open);
}

TEST_P(SecuredChannel, FourThousandBitClientKey) {
    trustedClient = clientIdentity4096().certificate;
    open(clientIdentity4096());
    const Buffer body = pattern(20000);
    EXPECT_EQ(roundTrip(body), body);
}

TEST_P(SecuredChannel, TamperedSignatureClosesTheChannel) {
    open();
    client->send(echoRequest(pattern(100)));
    pump([](Buffer& b) { b[b.size() - 1] ^= 0x01; });
    EXPECT_EQ(serverClosedWith(), status::BadSecurityChecksFailed);
    EXPECT_TRUE(serverHooks.requests.empty());
}

TEST_P(SecuredChannel, FlippedBodyOrPaddingByteClosesTheChannel) {
    open();
    client->send(echoRequest(pattern(100)));
    // The byte before the signature: the padding in SignAndEncrypt, the body in Sign.
    pump([](Buffer& b) { b[b.size() - 33] ^= 0x01; });
    EXPECT_EQ(serverClosedWith(), status::BadSecurityChecksFailed);
    EXPECT_TRUE(serverHooks.requests.empty());
}

TEST_P(SecuredChannel, ReplayedSequenceNumberClosesTheChannel) {
    open();
    roundTrip(pattern(10));
    const Buffer replay = sentToServer.back();
    server->feed(replay.data(), replay.size(), now);
    // Part 6 §6.7.6: one more failed security check, the same status as the others.
    EXPECT_EQ(serverClosedWith(), status::BadSecurityChecksFailed);
    EXPECT_EQ(serverHooks.requests.size(), 1u);
}

TEST_P(SecuredChannel, SkippedSequenceNumberClosesTheChannel) {
    open();
    client->send(echoRequest(pattern(10)));
    toServer.clear();  // lost: the next one skips a number
    client->send(echoRequest(pattern(10)));
    pump();
    EXPECT_EQ(serverClosedWith(), status::BadSecurityChecksFailed);
    EXPECT_TRUE(serverHooks.requests.empty());
}

TEST_P(SecuredChannel, UntrustedClientIsRefused) {
    trustedClient = clientIdentity4096().certificate;  // not the one that connects
    create();
    client->start(now);
    pump();
    EXPECT_FALSE(client->isOpen());
    EXPECT_EQ(serverClosedWith(), status::BadSecurityChecksFailed);
    EXPECT_EQ(clientError, status::BadSecurityChecksFailed);
}

TEST_P(SecuredChannel, WrongReceiverThumbprintIsRefused) {
    // The client believes the server has another certificate: it encrypts for that one and
    // names its thumbprint.
    serverCertificate = clientIdentity4096().certificate;
    create();
    client->start(now);
    pump();
    EXPECT_FALSE(client->isOpen());
    EXPECT_EQ(serverClosedWith(), status::BadSecurityChecksFailed);
}

TEST_P(SecuredChannel, TamperedOpenRequestIsRefused) {
    create();
    client->start(now);
    bool first = true;
    pump([&](Buffer& b) {
        if (decodeMessageHeader(b.data()).type == MessageType::Hello) return;
        if (first) b[b.size() - 10] ^= 0x40;
        first = false;
    });
    EXPECT_FALSE(client->isOpen());
    EXPECT_EQ(serverClosedWith(), status::BadSecurityChecksFailed);
}

TEST_P(SecuredChannel, NoneOpenOnASecuredServerStillWorks) {
    ccfg.security.reset();
    serverHooks.out = &toClient;
    clientHooks.out = &toServer;
    server = std::make_unique<ServerChannel>(scfg, serverHooks, now);
    serverHooks.channel = server.get();
    client = std::make_unique<ClientChannel>(ccfg, "opc.tcp://test:4840", clientHooks);
    client->start(now);
    pump();
    ASSERT_TRUE(client->isOpen());
    EXPECT_EQ(server->security(), nullptr);
    EXPECT_EQ(server->securityMode(), MessageSecurityMode::None);
    const Buffer body = pattern(100);
    EXPECT_EQ(roundTrip(body), body);
}

INSTANTIATE_TEST_SUITE_P(
    Policies, SecuredChannel,
    ::testing::Combine(
        ::testing::Values("http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256",
                          "http://opcfoundation.org/UA/SecurityPolicy#Aes128_Sha256_RsaOaep",
                          "http://opcfoundation.org/UA/SecurityPolicy#Aes256_Sha256_RsaPss"),
        ::testing::Values(MessageSecurityMode::Sign, MessageSecurityMode::SignAndEncrypt)),
    [](const auto& info) {
        std::string p(std::get<0>(info.param));
        p = p.substr(p.find('#') + 1);
        return p +
               (std::get<1>(info.param) == MessageSecurityMode::Sign ? "_Sign" : "_SignAndEncrypt");
    });

TEST(SecuredChannelPolicies, DeprecatedAndUnknownPoliciesAreNotFound) {
    EXPECT_EQ(crypto::findPolicy("http://opcfoundation.org/UA/SecurityPolicy#Basic128Rsa15"),
              nullptr);
    EXPECT_EQ(crypto::findPolicy("http://opcfoundation.org/UA/SecurityPolicy#Basic256"), nullptr);
    EXPECT_EQ(crypto::findPolicy(kSecurityPolicyNone), nullptr);
}

}  // namespace pnp::ua::transport::secured_test
