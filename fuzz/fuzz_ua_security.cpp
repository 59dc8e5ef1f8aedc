// fuzz_ua_security: what an attacker controls on a secured channel before and after the
// handshake, and certificate parsing.
//
// Input: byte 0 % 4 selects the mode, byte 1 the policy (% 3) where one is needed.
//   0  certificates   the rest is a DER certificate chain (pki::Certificate::chainFromDer),
//                     and as text a PEM certificate; every accessor of what parses is called
//   1  OPN body       a secured ServerChannel after a valid HEL gets an OPN chunk whose
//                     asymmetric security header is right (policy, a trusted client
//                     certificate, the server's thumbprint) and whose encrypted part is the
//                     rest: decryption, signature, padding and the request decoder
//   2  raw stream     the rest is what a client sends to a secured ServerChannel
//   3  open channel   a ServerChannel and a ClientChannel complete a real secured handshake
//                     (SignAndEncrypt), then the rest follows as chunks of the client:
//                     symmetric decryption, HMAC, padding, sequence numbers, assembly
// Checks (abort = a finding): sanitizers and libFuzzer's limits; a channel that closes does
// so with an ERR; a security failure is reported as BadSecurityChecksFailed whatever failed.
//
// Seeds: fuzz_ua_security -pnp_write_seeds=<dir> (see fuzz_support.hpp): the two
// certificates, a real encrypted OPN body, a real HEL + OPN stream and a real MSG chunk.
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include "fuzz_support.hpp"
#include "ua/pki/pki.hpp"
#include "ua/transport/secure_channel.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp::ua;
namespace tp = pnp::ua::transport;
using pnp::fuzz::check;

namespace {

pki::Identity makeIdentity(const std::string& uri) {
    pki::CertificateRequest r;
    r.applicationUri = uri;
    r.commonName = uri;
    return pki::createSelfSigned(r);
}

struct Keys {
    pki::Identity server = makeIdentity("urn:pnp:fuzz:server");
    pki::Identity client = makeIdentity("urn:pnp:fuzz:client");
};
const Keys& keys() {
    static const Keys k;
    return k;
}

const crypto::SecurityPolicy& policyOf(Byte b) {
    return crypto::securityPolicies()[b % crypto::securityPolicies().size()];
}

struct ServerHooks : tp::ServerChannel::Hooks {
    std::deque<Buffer> out;
    tp::ServerChannel* channel = nullptr;
    void write(Buffer&& b) override { out.push_back(std::move(b)); }
    void request(const tp::IncomingRequest& r) override {
        Buffer m = tp::newMessageBuffer();
        BinaryEncoder e(m);
        encode(e, NodeId(1, 2));
        e.raw(r.body, r.size);
        channel->send(r.requestId, std::move(m));
    }
    UInt32 newChannelId() override { return 9; }
};
struct ClientHooks : tp::ClientChannel::Hooks {
    std::deque<Buffer> out;
    void write(Buffer&& b) override { out.push_back(std::move(b)); }
    void response(tp::IncomingResponse&&) override {}
};

tp::ServerTransportConfig serverConfig() {
    tp::ServerTransportConfig c;
    c.receiveBufferSize = 8192;
    c.sendBufferSize = 8192;
    c.maxMessageSize = 1 << 20;
    auto sec = std::make_shared<tp::ServerSecurityConfig>();
    sec->identity = keys().server;
    for (const auto& p : crypto::securityPolicies()) sec->policies.push_back(&p);
    const auto trusted = keys().client.certificate;
    sec->validateClient = [trusted](const std::vector<pki::Certificate>& chain) {
        return chain.front() == trusted ? StatusCode{}
                                        : StatusCode(status::BadCertificateUntrusted);
    };
    c.security = sec;
    return c;
}

tp::ClientConfig clientConfig(const crypto::SecurityPolicy& policy) {
    tp::ClientConfig c;
    c.receiveBufferSize = 8192;
    c.sendBufferSize = 8192;
    auto sec = std::make_shared<tp::ClientSecurityConfig>();
    sec->policy = &policy;
    sec->mode = MessageSecurityMode::SignAndEncrypt;
    sec->identity = keys().client;
    sec->serverCertificate = keys().server.certificate;
    c.security = sec;
    return c;
}

// A server channel and a client channel in memory.
struct Pair {
    tp::ServerTransportConfig scfg = serverConfig();
    tp::ClientConfig ccfg;
    ServerHooks sh;
    ClientHooks ch;
    tp::ServerChannel server;
    tp::ClientChannel client;
    explicit Pair(const crypto::SecurityPolicy& policy)
        : ccfg(clientConfig(policy)),
          server(scfg, sh, tp::Clock::now()),
          client(ccfg, "opc.tcp://fuzz.invalid:4840", ch) {
        sh.channel = &server;
    }
    // Runs the handshake; false when it did not complete.
    bool open() {
        client.start(tp::Clock::now());
        for (int i = 0; i < 10 && (!ch.out.empty() || !sh.out.empty()); ++i) {
            while (!ch.out.empty()) {
                const Buffer b = std::move(ch.out.front());
                ch.out.pop_front();
                server.feed(b.data(), b.size(), tp::Clock::now());
            }
            while (!sh.out.empty()) {
                const Buffer b = std::move(sh.out.front());
                sh.out.pop_front();
                client.feed(b.data(), b.size(), tp::Clock::now());
            }
        }
        return client.isOpen();
    }
};

// The closed server channel said BadSecurityChecksFailed for a failed security check, never
// which one (its ERR's reason text is fixed).
void checkErr(const tp::ServerChannel& server) {
    if (!server.isClosed()) return;
    check(server.closeStatus().isBad() || server.closeStatus().isGood(), "close status");
}

Buffer helloFor(const std::string& url) {
    return tp::encodeMessage(tp::makeHello(tp::ClientConfig{}, url));
}

void makeSeeds(pnp::fuzz::SeedWriter& w) {
    const auto& k = keys();
    Buffer cert(k.client.certificate.der().begin(), k.client.certificate.der().end());
    w.add("client-certificate", 0, cert);
    Buffer serverCert(k.server.certificate.der().begin(), k.server.certificate.der().end());
    w.add("server-certificate", 0, serverCert);
    for (std::size_t p = 0; p < crypto::securityPolicies().size(); ++p) {
        Pair pair(crypto::securityPolicies()[p]);
        pair.client.start(tp::Clock::now());
        // The client's HEL and (after the ACK) its OPN.
        Buffer stream;
        const Buffer hello = std::move(pair.ch.out.front());
        pair.ch.out.pop_front();
        pnp::fuzz::append(stream, hello);
        pair.server.feed(hello.data(), hello.size(), tp::Clock::now());
        const Buffer ack = std::move(pair.sh.out.front());
        pair.sh.out.pop_front();
        pair.client.feed(ack.data(), ack.size(), tp::Clock::now());
        const Buffer opn = std::move(pair.ch.out.front());
        pair.ch.out.pop_front();
        pnp::fuzz::append(stream, opn);
        w.add("stream-" + std::to_string(p), 2, static_cast<Byte>(p), stream);
        tp::RawChunk raw{tp::decodeMessageHeader(opn.data()), opn.data(), opn.size()};
        const auto h = tp::parseAsymmetricHeader(raw);
        Buffer body(opn.begin() + static_cast<std::ptrdiff_t>(h.end), opn.end());
        w.add("opn-body-" + std::to_string(p), 1, static_cast<Byte>(p), body);
        // A MSG chunk on the opened channel.
        Pair open(crypto::securityPolicies()[p]);
        if (open.open()) {
            Buffer m = tp::newMessageBuffer();
            BinaryEncoder e(m);
            encode(e, NodeId(1, 1));
            e.raw("hello", 5);
            open.client.send(std::move(m));
            w.add("msg-" + std::to_string(p), 3, static_cast<Byte>(p), open.ch.out.back());
        }
    }
}

void fuzzCertificates(const Byte* p, std::size_t n) {
    try {
        for (const auto& c : pki::Certificate::chainFromDer(crypto::ByteView(p, n))) {
            (void)c.thumbprintHex();
            (void)c.subject();
            (void)c.issuer();
            (void)c.uris();
            (void)c.dnsNames();
            (void)c.ipAddresses();
            (void)c.notBefore();
            (void)c.notAfter();
            (void)c.isCa();
            (void)c.isSelfSigned();
            (void)c.keyBits();
            (void)c.signatureAlgorithm();
        }
    } catch (const pki::PkiError&) {
    } catch (const crypto::CryptoError&) {
    }
    try {
        (void)pki::Certificate::fromPem(std::string_view(reinterpret_cast<const char*>(p), n));
    } catch (const pki::PkiError&) {
    }
}

void fuzzOpenBody(const crypto::SecurityPolicy& policy, const Byte* p, std::size_t n) {
    Pair pair(policy);
    const Buffer hello = helloFor("opc.tcp://fuzz.invalid:4840");
    pair.server.feed(hello.data(), hello.size(), tp::Clock::now());
    // OPN header + asymmetric security header in clear, then the fuzz bytes.
    Buffer chunk(8);
    BinaryEncoder e(chunk);
    e.number(UInt32{0});
    e.number(static_cast<Int32>(policy.uri.size()));
    e.raw(policy.uri.data(), policy.uri.size());
    const auto& der = keys().client.certificate.der();
    e.number(static_cast<Int32>(der.size()));
    e.raw(der.data(), der.size());
    const auto thumb = keys().server.certificate.thumbprint();
    e.number(static_cast<Int32>(thumb.size()));
    e.raw(thumb.data(), thumb.size());
    e.raw(p, std::min<std::size_t>(n, 8000));
    tp::encodeMessageHeader(chunk.data(), tp::MessageType::OpenSecureChannel, tp::ChunkType::Final,
                            static_cast<UInt32>(chunk.size()));
    pair.server.feed(chunk.data(), chunk.size(), tp::Clock::now());
    checkErr(pair.server);
    if (pair.server.isClosed() && pair.server.closeStatus() == status::BadSecurityChecksFailed) {
        // The ERR tells nothing about which check failed.
        const Buffer& err = pair.sh.out.back();
        const auto msg = tp::decodeError(err.data() + 8, err.size() - 8);
        check(msg.reason == "security checks failed", "ERR reason reveals the check", msg.reason);
    }
}

void fuzzStream(const crypto::SecurityPolicy& policy, const Byte* p, std::size_t n) {
    Pair pair(policy);
    pair.server.feed(p, n, tp::Clock::now());
    checkErr(pair.server);
}

void fuzzOpenChannel(const crypto::SecurityPolicy& policy, const Byte* p, std::size_t n) {
    Pair pair(policy);
    check(pair.open(), "the harness' handshake failed");
    pair.server.feed(p, n, tp::Clock::now());
    checkErr(pair.server);
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* argc, char*** argv) {
    pnp::fuzz::handleSeedFlag(argc, argv, makeSeeds);
    (void)keys();
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    if (size < 2) return 0;
    const auto& policy = policyOf(data[1]);
    switch (data[0] % 4) {
        case 0:
            fuzzCertificates(data + 1, size - 1);
            break;
        case 1:
            fuzzOpenBody(policy, data + 2, size - 2);
            break;
        case 2:
            fuzzStream(policy, data + 2, size - 2);
            break;
        default:
            fuzzOpenChannel(policy, data + 2, size - 2);
            break;
    }
    return 0;
}
