// Attacks on a secured server over real sockets (issue 24 point 6). An attacker speaks the
// secure conversation itself on a raw TCP connection, with real keys: it seals its own
// OpenSecureChannel (so that it can name a wrong receiver thumbprint while signing and
// encrypting correctly), derives the symmetric keys from the nonces, and seals its own MSG
// chunks (so that it can send a padding byte that is wrong under a valid signature, replay or
// skip a sequence number, or flood chunks that are all valid). Each attack must close that
// channel with an ERR that says only what OPC 10000-6 §6.7.6 allows (BadSecurityChecksFailed,
// the same text and about the same time whatever check failed), while an honest secured client,
// connected before the attack and reading in a loop, keeps getting Good values in bounded time.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "support/loopback_server.hpp"
#include "support/raw_socket.hpp"
#include "ua/client/client.hpp"
#include "ua/pki/pki.hpp"
#include "ua/server/server.hpp"
#include "ua/transport/channel_security.hpp"
#include "ua/transport/secure_channel.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::secured_attacks_test {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using transport::ChunkType;
using transport::MessageType;

// The honest client's reads must each complete within this (generous: two cores shared by
// several builds and ASan; an attack that stalled the server would take seconds).
constexpr auto kMaxHonestLatency = 1000ms;

// ---- identities (a 2048-bit key takes ~100 ms: each made once per program) -----------------
constexpr const char* kServerUri = "urn:pnp:test:attacks:server";
constexpr const char* kHonestUri = "urn:pnp:test:attacks:honest";
constexpr const char* kAttackerUri = "urn:pnp:test:attacks:attacker";

pki::CertificateRequest request(const std::string& uri) {
    pki::CertificateRequest r;
    r.applicationUri = uri;
    r.commonName = uri;
    r.dnsNames = {"localhost"};
    return r;
}
const pki::Identity& serverIdentity() {
    static const pki::Identity id = pki::createSelfSigned(request(kServerUri));
    return id;
}
const pki::Identity& honestIdentity() {
    static const pki::Identity id = pki::createSelfSigned(request(kHonestUri));
    return id;
}
// Trusted: holds the keys of a legitimate application and abuses them.
const pki::Identity& attackerIdentity() {
    static const pki::Identity id = pki::createSelfSigned(request(kAttackerUri));
    return id;
}
// Never trusted.
const pki::Identity& strangerIdentity() {
    static const pki::Identity id = pki::createSelfSigned(request("urn:pnp:test:attacks:stranger"));
    return id;
}
// Trusted, but its validity ended a year ago.
const pki::Identity& expiredIdentity() {
    static const pki::Identity id = [] {
        auto r = request("urn:pnp:test:attacks:expired");
        r.notBefore = std::chrono::system_clock::now() - std::chrono::hours(24 * 730);
        r.validity = std::chrono::hours(24 * 365);
        return pki::createSelfSigned(r);
    }();
    return id;
}
// A CA in issuers/ with its CRL in issuers/crl; it signed a revoked and a good leaf, both in
// trusted/ themselves.
const pki::Identity& caIdentity() {
    static const pki::Identity id = [] {
        auto r = request("urn:pnp:test:attacks:ca");
        r.ca = true;
        return pki::createSelfSigned(r);
    }();
    return id;
}
const pki::Identity& revokedIdentity() {
    static const pki::Identity id =
        pki::createSigned(request("urn:pnp:test:attacks:revoked"), caIdentity());
    return id;
}
const pki::Identity& caSignedIdentity() {
    static const pki::Identity id =
        pki::createSigned(request("urn:pnp:test:attacks:ca-signed"), caIdentity());
    return id;
}
// Trusted; its SubjectAltName URI only contains the ApplicationUri it will claim.
constexpr const char* kClaimedUri = "urn:pnp:test:attacks:device";
const pki::Identity& uriIdentity() {
    static const pki::Identity id =
        pki::createSelfSigned(request(std::string(kClaimedUri) + "-evil"));
    return id;
}

template <class T>
NodeId encodingId() {
    return NodeId(0, DataTypeInfo<T>::binaryEncodingId);
}

// ---- the attacker ---------------------------------------------------------------------------
// What to get wrong in a sealed MSG chunk.
enum class Tamper { None, Signature, Padding };

// A secure conversation client written out by hand on a raw socket, so that every byte is
// under the test's control. Every wait has a deadline.
class Attacker {
  public:
    Attacker(UInt16 port, std::string url) : socket_(port), url_(std::move(url)) {}

    bool connected() const { return socket_.ok(); }
    test::RawSocket& socket() { return socket_; }
    const transport::Acknowledge& ack() const { return ack_; }
    UInt32 nextSequence() const { return sequence_; }

    // HEL -> ACK.
    bool hello() {
        transport::TransportLimits own;
        if (!socket_.send(transport::encodeMessage(transport::makeHello(own, url_)))) return false;
        auto c = socket_.readChunk(deadline());
        if (!c || transport::decodeMessageHeader(c->data()).type != MessageType::Acknowledge)
            return false;
        ack_ = transport::decodeAcknowledge(c->data() + 8, c->size() - 8);
        return true;
    }

    // The OPN request of SignAndEncrypt (or Sign) for `policy`, signed with `own` and encrypted
    // for the server's key; the header names `thumbprint` as the receiver (default: the
    // server's).
    Buffer sealOpen(const crypto::SecurityPolicy& policy, MessageSecurityMode mode,
                    const pki::Identity& own, std::optional<crypto::Bytes> thumbprint = {}) {
        policy_ = &policy;
        mode_ = mode;
        own_ = own;
        clientNonce_ = crypto::randomBytes(policy.nonceLength);
        OpenSecureChannelRequest req;
        req.requestHeader.timestamp = DateTime::now();
        req.requestHeader.requestHandle = 1;
        req.clientProtocolVersion = 0;
        req.requestType = SecurityTokenRequestType::Issue;
        req.securityMode = mode;
        req.clientNonce = ByteString(clientNonce_.data(), clientNonce_.size());
        req.requestedLifetime = 600'000;
        Buffer body;
        BinaryEncoder be(body);
        encode(be, encodingId<OpenSecureChannelRequest>());
        encode(be, req);

        const crypto::PublicKey serverKey = serverIdentity().certificate.publicKey();
        const int serverBits = serverKey.bits();
        const std::size_t plainBlock =
            crypto::plainBlockSize(serverBits, policy.asymmetricEncryption);
        const std::size_t cipherBlock = crypto::cipherBlockSize(serverBits);
        const std::size_t signatureSize = static_cast<std::size_t>(own.key.bits()) / 8;

        Buffer chunk(8);
        BinaryEncoder e(chunk);
        e.number(UInt32{0});  // secure channel id: none yet
        e.lengthPrefixed(policy.uri);
        const auto& der = own.certificate.der();
        e.lengthPrefixed(der.data(), der.size());
        const crypto::Bytes thumb =
            thumbprint ? *thumbprint : serverIdentity().certificate.thumbprint();
        e.lengthPrefixed(thumb.data(), thumb.size());
        const std::size_t headerEnd = chunk.size();
        e.number(sequence_++);
        e.number(nextRequestId_++);
        e.raw(body.data(), body.size());
        // PaddingSize + 1 bytes of PaddingSize, so that sequence header, body, padding and
        // signature fill whole plaintext blocks (a 2048-bit server key: no ExtraPaddingSize).
        const std::size_t unpadded = chunk.size() - headerEnd + 1 + signatureSize;
        const std::size_t paddingSize = (plainBlock - unpadded % plainBlock) % plainBlock;
        for (std::size_t i = 0; i <= paddingSize; ++i) e.number(static_cast<Byte>(paddingSize));
        const std::size_t plainSize = chunk.size() - headerEnd + signatureSize;
        transport::encodeMessageHeader(
            chunk.data(), MessageType::OpenSecureChannel, ChunkType::Final,
            static_cast<UInt32>(headerEnd + plainSize / plainBlock * cipherBlock));
        const crypto::Bytes signature = crypto::sign(own.key, policy.asymmetricSignature,
                                                     crypto::ByteView(chunk.data(), chunk.size()));
        e.raw(signature.data(), signature.size());
        const crypto::Bytes cipher =
            crypto::encrypt(serverKey, policy.asymmetricEncryption,
                            crypto::ByteView(chunk.data() + headerEnd, chunk.size() - headerEnd));
        chunk.resize(headerEnd);
        BinaryEncoder(chunk).raw(cipher.data(), cipher.size());
        return chunk;
    }

    // Reads the OPN response: decrypts and verifies it, derives the keys of the token. False
    // (and err() set when the server sent one) when none came.
    bool readOpenResponse() {
        auto c = readChunk();
        if (!c) return false;
        const auto h = transport::decodeMessageHeader(c->data());
        if (h.type != MessageType::OpenSecureChannel) return false;
        const transport::RawChunk raw{h, c->data(), c->size()};
        transport::ChannelSecurity sec(*policy_, mode_, own_, serverIdentity().certificate);
        const Buffer plain = sec.openOpen(raw, transport::parseAsymmetricHeader(raw));
        BinaryDecoder d(plain.data() + 8, plain.size() - 8);
        NodeId type;
        decode(d, type);
        if (type != encodingId<OpenSecureChannelResponse>()) return false;
        OpenSecureChannelResponse resp;
        decode(d, resp);
        channelId_ = resp.securityToken.channelId;
        tokenId_ = resp.securityToken.tokenId;
        const crypto::ByteView clientNonce(clientNonce_);
        const crypto::ByteView serverNonce(resp.serverNonce.data(), resp.serverNonce.size());
        send_.emplace(*policy_, crypto::deriveKeys(*policy_, serverNonce, clientNonce));
        receive_.emplace(*policy_, crypto::deriveKeys(*policy_, clientNonce, serverNonce));
        return true;
    }

    // HEL, OPN: true when the channel is open. Otherwise err() says what the server sent.
    bool open(const crypto::SecurityPolicy& policy, MessageSecurityMode mode,
              const pki::Identity& own, std::optional<crypto::Bytes> thumbprint = {}) {
        if (!hello()) return false;
        if (!socket_.send(sealOpen(policy, mode, own, std::move(thumbprint)))) return false;
        return readOpenResponse();
    }

    // One sealed MSG / CLO chunk around `body` (type NodeId + encoded request, or a slice of
    // one), with the next sequence number unless `sequence` is given.
    Buffer seal(const Buffer& body, UInt32 requestId, ChunkType chunkType = ChunkType::Final,
                Tamper tamper = Tamper::None, std::optional<UInt32> sequence = {}) {
        if (!send_) throw std::logic_error("no channel open: no keys to seal with");
        const bool encrypt = mode_ == MessageSecurityMode::SignAndEncrypt;
        Buffer chunk(transport::kSymmetricHeaderSize);
        BinaryEncoder e(chunk);
        e.raw(body.data(), body.size());
        if (encrypt) {
            const std::size_t unpadded = 8 + body.size() + 1 + 32;
            const std::size_t paddingSize = (16 - unpadded % 16) % 16;
            for (std::size_t i = 0; i <= paddingSize; ++i) e.number(static_cast<Byte>(paddingSize));
            // A padding byte that disagrees with the others, under a valid signature: only
            // the padding check can find it.
            if (tamper == Tamper::Padding) chunk[chunk.size() - 1 - paddingSize] ^= 0x01;
        }
        const std::size_t size = chunk.size() + 32;
        transport::encodeMessageHeader(chunk.data(), MessageType::Message, chunkType,
                                       static_cast<UInt32>(size));
        transport::putUInt32(chunk.data() + 8, channelId_);
        transport::putUInt32(chunk.data() + 12, tokenId_);
        transport::putUInt32(chunk.data() + 16, sequence ? *sequence : sequence_++);
        transport::putUInt32(chunk.data() + 20, requestId);
        Byte* signature = chunk.append(32);
        send_->sign(crypto::ByteView(chunk.data(), size - 32), signature);
        if (tamper == Tamper::Signature) signature[31] ^= 0x01;
        if (encrypt) send_->encrypt(std::span<std::uint8_t>(chunk.data() + 16, size - 16));
        return chunk;
    }

    // The largest body of one chunk the server accepts (its receive buffer).
    std::size_t maxBodyPerChunk() const {
        const std::size_t encrypted = (ack_.receiveBufferSize - 16) / 16 * 16;
        return encrypted - 8 - 32 - 1;
    }

    UInt32 newRequestId() { return nextRequestId_++; }

    Buffer getEndpointsRequest() const {
        Buffer b;
        BinaryEncoder e(b);
        GetEndpointsRequest req;
        req.requestHeader.timestamp = DateTime::now();
        req.requestHeader.requestHandle = 7;
        req.endpointUrl = url_;
        encode(e, encodingId<GetEndpointsRequest>());
        encode(e, req);
        return b;
    }

    // A response on the open channel: verified and decrypted, its ResponseHeader's result.
    // nullopt when none came (err() says whether an ERR did).
    std::optional<StatusCode> readResponse() {
        auto c = readChunk();
        if (!c) return std::nullopt;
        const auto h = transport::decodeMessageHeader(c->data());
        if (h.type != MessageType::Message || h.chunkType != ChunkType::Final || !receive_)
            return std::nullopt;
        Byte* p = c->data();
        std::size_t size = c->size();
        const bool encrypted = mode_ == MessageSecurityMode::SignAndEncrypt;
        if (encrypted) receive_->decrypt(std::span<std::uint8_t>(p + 16, size - 16));
        if (!receive_->verify(crypto::ByteView(p, size - 32), crypto::ByteView(p + size - 32, 32)))
            return std::nullopt;
        size -= 32;
        if (encrypted) size -= p[size - 1] + 1u;
        BinaryDecoder d(p + transport::kSymmetricHeaderSize,
                        size - transport::kSymmetricHeaderSize);
        NodeId type;
        decode(d, type);
        ResponseHeader header;
        decode(d, header);
        return header.serviceResult;
    }

    // A request whose answer proves the channel works: GetEndpoints needs no session.
    bool channelWorks() {
        if (!socket_.send(seal(getEndpointsRequest(), newRequestId()))) return false;
        auto r = readResponse();
        return r && r->isGood();
    }

    // The ERR the server closes the channel with (error Good: none before EOF / deadline).
    const transport::ErrorMessage& awaitErr() {
        while (!err_ && readChunk()) {
        }
        if (!err_) err_ = transport::ErrorMessage{};
        return *err_;
    }
    const std::optional<transport::ErrorMessage>& err() const { return err_; }

    // Sends one chunk and waits for the ERR: how long it took.
    Clock::duration timeToErr(const Buffer& chunk) {
        const auto start = Clock::now();
        if (!socket_.send(chunk)) return Clock::duration::max();
        awaitErr();
        return Clock::now() - start;
    }

    // Whether the server has answered anything (an ERR) within `wait`.
    bool somethingArrives(std::chrono::milliseconds wait) {
        pollfd p{socket_.fd(), POLLIN, 0};
        return ::poll(&p, 1, static_cast<int>(wait.count())) > 0;
    }

  private:
    static test::RawSocket::Deadline deadline() { return Clock::now() + 5s; }
    // The next chunk; an ERR is kept in err_ (and nullopt returned).
    std::optional<Buffer> readChunk() {
        auto c = socket_.readChunk(deadline());
        if (c && transport::decodeMessageHeader(c->data()).type == MessageType::Error) {
            err_ = transport::decodeError(c->data() + 8, c->size() - 8);
            return std::nullopt;
        }
        return c;
    }

    test::RawSocket socket_;
    std::string url_;
    transport::Acknowledge ack_;
    const crypto::SecurityPolicy* policy_ = nullptr;
    MessageSecurityMode mode_ = MessageSecurityMode::SignAndEncrypt;
    pki::Identity own_;
    crypto::Bytes clientNonce_;
    UInt32 channelId_ = 0;
    UInt32 tokenId_ = 0;
    UInt32 sequence_ = 1;
    UInt32 nextRequestId_ = 1;
    std::optional<crypto::SymmetricCipher> send_;
    std::optional<crypto::SymmetricCipher> receive_;
    std::optional<transport::ErrorMessage> err_;
};

// ---- the honest client ----------------------------------------------------------------------
// Reads a variable in a loop on its own secured session (no reconnect: a dropped channel
// would show as failures) until stopped, at most 20 s / 200 000 reads.
class HonestReader {
  public:
    explicit HonestReader(const std::string& url) {
        client::ClientConfig c;
        c.applicationUri = kHonestUri;
        c.reconnect.enabled = false;
        client::ClientSecurity s;
        s.identity = honestIdentity();  // trust: null (accepts the server)
        c.security = s;
        client_ = std::make_unique<client::Client>(c);
        client_->connect(url);
        thread_ = std::thread([this] { run(); });
    }
    ~HonestReader() { stop(); }

    void stop() {
        stop_ = true;
        if (thread_.joinable()) thread_.join();
    }
    int reads() const { return reads_.load(); }
    int failures() const { return failures_.load(); }
    Clock::duration maxLatency() const { return Clock::duration(maxLatency_.load()); }
    std::string firstFailure() const {
        std::lock_guard lock(mutex_);
        return firstFailure_;
    }
    // Waits (bounded) until n more reads succeeded.
    bool readsMore(int n, std::chrono::milliseconds timeout = 5000ms) const {
        const int target = reads() + n;
        const auto until = Clock::now() + timeout;
        while (reads() < target && failures() == 0 && Clock::now() < until)
            std::this_thread::sleep_for(1ms);
        return reads() >= target;
    }
    client::Client& client() { return *client_; }

  private:
    void run() {
        const auto until = Clock::now() + 20s;
        for (int i = 0; i < 200'000 && !stop_ && Clock::now() < until; ++i) {
            const auto start = Clock::now();
            try {
                const Variant v = client_->readValue(NodeId(0, ns0::Server_ServerStatus_State));
                if (!(v == Variant(Int32{0}))) throw std::runtime_error("unexpected value");
                ++reads_;
            } catch (const std::exception& e) {
                if (failures_++ == 0) {
                    std::lock_guard lock(mutex_);
                    firstFailure_ = e.what();
                }
                std::this_thread::sleep_for(10ms);
            }
            const auto took = (Clock::now() - start).count();
            auto seen = maxLatency_.load();
            while (took > seen && !maxLatency_.compare_exchange_weak(seen, took)) {
            }
        }
    }

    std::unique_ptr<client::Client> client_;
    std::thread thread_;
    std::atomic<bool> stop_{false};
    std::atomic<int> reads_{0}, failures_{0};
    std::atomic<Clock::duration::rep> maxLatency_{0};
    mutable std::mutex mutex_;
    std::string firstFailure_;
};

// ---- the fixture: a secured server with a PKI folder, an honest client reading --------------
class SecuredAttacks : public ::testing::Test {
  protected:
    void SetUp() override {
        static int counter = 0;
        pkiDir = std::filesystem::temp_directory_path() /
                 ("pnp-attacks-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
        std::filesystem::remove_all(pkiDir);
        store = std::make_shared<pki::CertificateStore>(pkiDir);
        store->ensureLayout();
        for (const auto* id : {&honestIdentity(), &attackerIdentity(), &expiredIdentity(),
                               &revokedIdentity(), &caSignedIdentity(), &uriIdentity()})
            store->addTrusted(id->certificate);
        store->addIssuer(caIdentity().certificate);
        store->addCrl(pki::createCrl(caIdentity(), {revokedIdentity().certificate.serialHex()}),
                      true);

        auto c = pnp::testing::loopbackConfig();
        c.applicationUri = kServerUri;
        server::ServerSecurity s;
        s.identity = serverIdentity();
        s.trust = store;
        c.security = s;
        server = std::make_unique<server::Server>(c);
        server->start();
        url = pnp::testing::url(*server);
        honest = std::make_unique<HonestReader>(url);
        ASSERT_TRUE(honest->readsMore(5)) << honest->firstFailure();
    }

    void TearDown() override {
        if (honest) {
            // Served after the attack too, and throughout without a failure or a stall.
            EXPECT_TRUE(honest->readsMore(20)) << honest->firstFailure();
            honest->stop();
            EXPECT_EQ(honest->failures(), 0) << honest->firstFailure();
            EXPECT_LT(honest->maxLatency(), kMaxHonestLatency)
                << std::chrono::duration_cast<std::chrono::microseconds>(honest->maxLatency())
                       .count()
                << " us";
            RecordProperty("honest_reads", honest->reads());
            RecordProperty("honest_max_latency_us",
                           static_cast<int>(std::chrono::duration_cast<std::chrono::microseconds>(
                                                honest->maxLatency())
                                                .count()));
            honest.reset();
        }
        server.reset();
        std::error_code ec;
        std::filesystem::remove_all(pkiDir, ec);
    }

    // An attacker whose channel is open and proven to work.
    std::unique_ptr<Attacker> openAttacker(
        const crypto::SecurityPolicy& policy = crypto::securityPolicies().front(),
        MessageSecurityMode mode = MessageSecurityMode::SignAndEncrypt) {
        auto a = std::make_unique<Attacker>(server->port(), url);
        EXPECT_TRUE(a->connected());
        EXPECT_TRUE(a->open(policy, mode, attackerIdentity()))
            << (a->err() ? a->err()->error.toString() : "no answer");
        EXPECT_TRUE(a->channelWorks());
        return a;
    }

    // The ERR every failed check of a secured chunk gets: nothing about which one failed.
    static void expectSecurityChecksFailed(const transport::ErrorMessage& err) {
        EXPECT_EQ(err.error, status::BadSecurityChecksFailed) << err.error.toString();
        EXPECT_EQ(err.reason, "security checks failed");
    }

    std::filesystem::path pkiDir;
    std::shared_ptr<pki::CertificateStore> store;
    std::unique_ptr<server::Server> server;
    std::string url;
    std::unique_ptr<HonestReader> honest;
};

const crypto::SecurityPolicy& policyNamed(std::string_view uri) { return *crypto::findPolicy(uri); }

// ---- symmetric chunks: every policy, SignAndEncrypt ----------------------------------------
class SymmetricAttacks : public SecuredAttacks,
                         public ::testing::WithParamInterface<std::string_view> {
  protected:
    const crypto::SecurityPolicy& policy() const { return policyNamed(GetParam()); }
};

TEST_P(SymmetricAttacks, TamperedSignatureClosesTheChannel) {
    auto a = openAttacker(policy());
    a->socket().send(
        a->seal(a->getEndpointsRequest(), a->newRequestId(), ChunkType::Final, Tamper::Signature));
    expectSecurityChecksFailed(a->awaitErr());
    EXPECT_TRUE(a->socket().waitClosed());
}

TEST_P(SymmetricAttacks, FlippedPaddingByteUnderAValidSignatureClosesTheChannel) {
    auto a = openAttacker(policy());
    a->socket().send(
        a->seal(a->getEndpointsRequest(), a->newRequestId(), ChunkType::Final, Tamper::Padding));
    expectSecurityChecksFailed(a->awaitErr());
    EXPECT_TRUE(a->socket().waitClosed());
}

TEST_P(SymmetricAttacks, ReplayedChunkClosesTheChannel) {
    auto a = openAttacker(policy());
    const Buffer chunk = a->seal(a->getEndpointsRequest(), a->newRequestId());
    ASSERT_TRUE(a->socket().send(chunk));
    ASSERT_TRUE(a->readResponse().has_value());
    a->socket().send(chunk);  // the same bytes again: a valid signature, an old number
    expectSecurityChecksFailed(a->awaitErr());
    EXPECT_TRUE(a->socket().waitClosed());
}

TEST_P(SymmetricAttacks, SkippedSequenceNumberClosesTheChannel) {
    auto a = openAttacker(policy());
    a->socket().send(a->seal(a->getEndpointsRequest(), a->newRequestId(), ChunkType::Final,
                             Tamper::None, a->nextSequence() + 1));
    expectSecurityChecksFailed(a->awaitErr());
    EXPECT_TRUE(a->socket().waitClosed());
}

INSTANTIATE_TEST_SUITE_P(
    Policies, SymmetricAttacks,
    ::testing::Values("http://opcfoundation.org/UA/SecurityPolicy#Aes256_Sha256_RsaPss",
                      "http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256",
                      "http://opcfoundation.org/UA/SecurityPolicy#Aes128_Sha256_RsaOaep"),
    [](const auto& info) {
        std::string p(info.param);
        return p.substr(p.find('#') + 1);
    });

TEST_F(SecuredAttacks, TamperedSignatureInSignModeClosesTheChannel) {
    auto a = openAttacker(crypto::securityPolicies().front(), MessageSecurityMode::Sign);
    a->socket().send(
        a->seal(a->getEndpointsRequest(), a->newRequestId(), ChunkType::Final, Tamper::Signature));
    expectSecurityChecksFailed(a->awaitErr());
}

// Tampered signature, flipped padding and replay: the same ERR, byte for byte, and no time
// difference beyond the noise of the machine (medians of interleaved trials).
TEST_F(SecuredAttacks, CryptoFailuresRevealNothingInTheErrOrItsTiming) {
    constexpr int kTrials = 9;
    std::vector<Clock::duration> times[3];
    std::optional<transport::ErrorMessage> errs[3];
    for (int trial = 0; trial < kTrials; ++trial) {
        for (int kind = 0; kind < 3; ++kind) {
            auto a = openAttacker();
            Buffer chunk;
            if (kind == 2) {
                chunk = a->seal(a->getEndpointsRequest(), a->newRequestId());
                ASSERT_TRUE(a->socket().send(chunk));
                ASSERT_TRUE(a->readResponse().has_value());
            } else {
                chunk = a->seal(a->getEndpointsRequest(), a->newRequestId(), ChunkType::Final,
                                kind == 0 ? Tamper::Signature : Tamper::Padding);
            }
            times[kind].push_back(a->timeToErr(chunk));
            const auto& err = a->awaitErr();
            if (!errs[kind]) errs[kind] = err;
            EXPECT_EQ(err, *errs[kind]) << "kind " << kind << " trial " << trial;
        }
    }
    EXPECT_EQ(*errs[0], *errs[1]) << errs[0]->error.toString() << " vs "
                                  << errs[1]->error.toString();
    EXPECT_EQ(*errs[0], *errs[2]) << errs[0]->error.toString() << " vs "
                                  << errs[2]->error.toString() << " (" << errs[2]->reason << ")";
    expectSecurityChecksFailed(*errs[0]);

    std::chrono::microseconds median[3];
    for (int kind = 0; kind < 3; ++kind) {
        std::sort(times[kind].begin(), times[kind].end());
        median[kind] =
            std::chrono::duration_cast<std::chrono::microseconds>(times[kind][kTrials / 2]);
    }
    const auto [lo, hi] = std::minmax({median[0], median[1], median[2]});
    RecordProperty("median_us_signature", static_cast<int>(median[0].count()));
    RecordProperty("median_us_padding", static_cast<int>(median[1].count()));
    RecordProperty("median_us_replay", static_cast<int>(median[2].count()));
    // Which check failed costs nanoseconds (the HMAC is checked before anything else, in
    // constant time); a leak worth having — a skipped step, an extra RSA operation, a
    // delay — costs hundreds of microseconds.
    EXPECT_LT(hi - lo, 400us + lo / 2)
        << "signature " << median[0].count() << " us, padding " << median[1].count()
        << " us, replay " << median[2].count() << " us";
}

// ---- OpenSecureChannel: thumbprint and client certificates -----------------------------------
TEST_F(SecuredAttacks, CorrectOpenSealedByHandIsAccepted) {
    // The control of the attacks below: the same code with nothing wrong opens a channel.
    for (const auto& p : crypto::securityPolicies())
        for (auto mode : {MessageSecurityMode::Sign, MessageSecurityMode::SignAndEncrypt}) {
            Attacker a(server->port(), url);
            EXPECT_TRUE(a.open(p, mode, attackerIdentity())) << p.uri;
            EXPECT_TRUE(a.channelWorks()) << p.uri;
        }
    Attacker a(server->port(), url);
    EXPECT_TRUE(a.open(crypto::securityPolicies().front(), MessageSecurityMode::SignAndEncrypt,
                       caSignedIdentity()));  // a CA-signed leaf whose CA has a CRL: fine
}

TEST_F(SecuredAttacks, WrongReceiverThumbprintIsRefused) {
    // Signed and encrypted correctly for the server's key; only the thumbprint names another
    // certificate.
    Attacker a(server->port(), url);
    EXPECT_FALSE(a.open(crypto::securityPolicies().front(), MessageSecurityMode::SignAndEncrypt,
                        attackerIdentity(), strangerIdentity().certificate.thumbprint()));
    expectSecurityChecksFailed(a.awaitErr());
    EXPECT_TRUE(a.socket().waitClosed());
}

TEST_F(SecuredAttacks, UntrustedCertificateIsRefusedAndLandsInRejected) {
    Attacker a(server->port(), url);
    EXPECT_FALSE(a.open(crypto::securityPolicies().front(), MessageSecurityMode::SignAndEncrypt,
                        strangerIdentity()));
    expectSecurityChecksFailed(a.awaitErr());
    EXPECT_TRUE(a.socket().waitClosed());
    const auto entry = store->find(strangerIdentity().certificate.thumbprintHex());
    ASSERT_TRUE(entry.has_value());
    EXPECT_EQ(entry->state, pki::TrustState::Rejected);
}

TEST_F(SecuredAttacks, ExpiredCertificateIsRefused) {
    // What the store finds (for the log) is not what the attacker is told.
    EXPECT_EQ(store->validate({expiredIdentity().certificate}, {}),
              status::BadCertificateTimeInvalid);
    Attacker a(server->port(), url);
    EXPECT_FALSE(a.open(crypto::securityPolicies().front(), MessageSecurityMode::SignAndEncrypt,
                        expiredIdentity()));
    expectSecurityChecksFailed(a.awaitErr());
    EXPECT_TRUE(a.socket().waitClosed());
}

TEST_F(SecuredAttacks, RevokedCertificateIsRefused) {
    EXPECT_EQ(store->validate({revokedIdentity().certificate}, {}), status::BadCertificateRevoked);
    Attacker a(server->port(), url);
    EXPECT_FALSE(a.open(crypto::securityPolicies().front(), MessageSecurityMode::SignAndEncrypt,
                        revokedIdentity()));
    expectSecurityChecksFailed(a.awaitErr());
    EXPECT_TRUE(a.socket().waitClosed());
}

// ---- CreateSession: the certificate's URI must be the ApplicationUri, exactly ----------------
TEST_F(SecuredAttacks, CertificateWhoseUriOnlyContainsTheApplicationUriGetsNoSession) {
    auto createSession = [&](const std::string& applicationUri) {
        Attacker a(server->port(), url);
        EXPECT_TRUE(a.open(crypto::securityPolicies().front(), MessageSecurityMode::SignAndEncrypt,
                           uriIdentity()));
        CreateSessionRequest req;
        req.requestHeader.timestamp = DateTime::now();
        req.requestHeader.requestHandle = 3;
        req.clientDescription.applicationUri = applicationUri;
        req.clientDescription.applicationType = ApplicationType::Client;
        req.endpointUrl = url;
        req.sessionName = "attack";
        const auto nonce = crypto::randomBytes(32);
        req.clientNonce = ByteString(nonce.data(), nonce.size());
        const auto& der = uriIdentity().certificate.der();
        req.clientCertificate = ByteString(der.data(), der.size());
        req.requestedSessionTimeout = 10'000;
        Buffer body;
        BinaryEncoder e(body);
        encode(e, encodingId<CreateSessionRequest>());
        encode(e, req);
        EXPECT_TRUE(a.socket().send(a.seal(body, a.newRequestId())));
        const auto result = a.readResponse();
        EXPECT_TRUE(result.has_value()) << (a.err() ? a.err()->error.toString() : "no answer");
        return result.value_or(StatusCode(status::BadUnexpectedError));
    };
    // Control: the exact URI of its certificate gets a session.
    EXPECT_EQ(createSession(std::string(kClaimedUri) + "-evil"), StatusCode{});
    // "urn:...:device" is a prefix of the certificate's "urn:...:device-evil": refused.
    EXPECT_EQ(createSession(kClaimedUri), status::BadCertificateUriInvalid);
}

// ---- chunk floods on an open encrypted channel ----------------------------------------------
TEST_F(SecuredAttacks, FloodBeyondTheChunkCountClosesTheChannel) {
    auto a = openAttacker();
    const UInt32 limit = a->ack().maxChunkCount;
    ASSERT_GT(limit, 0u);
    ASSERT_LT(limit, 100'000u);
    const Buffer piece(100, Byte{0x5A});
    const UInt32 id = a->newRequestId();
    // Valid intermediate chunks up to the limit: accepted silently.
    for (UInt32 i = 0; i < limit; ++i)
        ASSERT_TRUE(a->socket().send(a->seal(piece, id, ChunkType::Intermediate)));
    EXPECT_FALSE(a->somethingArrives(100ms)) << "closed before the limit";
    // One more: the message exceeds MaxChunkCount.
    a->socket().send(a->seal(piece, id, ChunkType::Intermediate));
    const auto& err = a->awaitErr();
    EXPECT_EQ(err.error, status::BadTcpMessageTooLarge)
        << err.error.toString() << " " << err.reason;
    EXPECT_TRUE(a->socket().waitClosed());
}

TEST_F(SecuredAttacks, FloodBeyondTheMessageSizeClosesTheChannel) {
    auto a = openAttacker();
    const std::size_t maxMessage = a->ack().maxMessageSize;
    ASSERT_GT(maxMessage, 0u);
    ASSERT_LE(maxMessage, 64u << 20);
    const Buffer piece(a->maxBodyPerChunk(), Byte{0xA5});
    const std::size_t fit = maxMessage / piece.size();  // whole chunks that still fit
    ASSERT_LT(fit, a->ack().maxChunkCount) << "the chunk count would end it first";
    const UInt32 id = a->newRequestId();
    for (std::size_t i = 0; i < fit; ++i) {
        ASSERT_TRUE(a->socket().send(a->seal(piece, id, ChunkType::Intermediate))) << i;
        ASSERT_FALSE(a->somethingArrives(0ms)) << "closed after " << i << " chunks";
    }
    a->socket().send(a->seal(piece, id, ChunkType::Intermediate));
    const auto& err = a->awaitErr();
    EXPECT_EQ(err.error, status::BadTcpMessageTooLarge)
        << err.error.toString() << " " << err.reason;
    EXPECT_TRUE(a->socket().waitClosed());
}

TEST_F(SecuredAttacks, FloodOfForgedChunksEndsAtTheFirst) {
    auto a = openAttacker();
    // Chunks with the right channel and token ids but random contents, sent in one go.
    Buffer flood;
    for (int i = 0; i < 500; ++i) {
        Buffer chunk = a->seal(Buffer(1000, Byte{0}), 99, ChunkType::Intermediate);
        crypto::randomBytes(std::span<std::uint8_t>(chunk.data() + 16, chunk.size() - 16));
        flood.insert(flood.end(), chunk.begin(), chunk.end());
    }
    a->socket().trySend(flood, 2000ms);  // the server closes after the first
    expectSecurityChecksFailed(a->awaitErr());
    EXPECT_TRUE(a->socket().waitClosed());
}

TEST_F(SecuredAttacks, ParallelAttackersDoNotStarveTheHonestClient) {
    // Four attackers at once, each a different attack, each repeated on new channels.
    // attack(): one attack on a new connection; whether it was refused with the right ERR.
    auto attack = [&](int kind, int round) {
        Attacker a(server->port(), url);
        const auto& policy = crypto::securityPolicies()[round % 3];
        if (kind == 0) {  // an untrusted OpenSecureChannel
            a.open(policy, MessageSecurityMode::SignAndEncrypt, strangerIdentity());
            return a.awaitErr().error == status::BadSecurityChecksFailed;
        }
        if (!a.open(policy, MessageSecurityMode::SignAndEncrypt, attackerIdentity())) return false;
        if (kind == 3) {  // a flood beyond the chunk count
            const UInt32 id = a.newRequestId();
            Buffer flood;
            for (UInt32 i = 0; i <= a.ack().maxChunkCount; ++i) {
                Buffer c = a.seal(Buffer(200, Byte{1}), id, ChunkType::Intermediate);
                flood.insert(flood.end(), c.begin(), c.end());
            }
            a.socket().trySend(flood, 2000ms);
            return a.awaitErr().error == status::BadTcpMessageTooLarge;
        }
        a.socket().send(a.seal(a.getEndpointsRequest(), a.newRequestId(), ChunkType::Final,
                               kind == 1 ? Tamper::Signature : Tamper::Padding));
        return a.awaitErr().error == status::BadSecurityChecksFailed;
    };
    std::atomic<int> refused{0}, unexpected{0};
    std::vector<std::thread> attackers;
    for (int kind = 0; kind < 4; ++kind) {
        attackers.emplace_back([&, kind] {
            for (int round = 0; round < 5; ++round) {
                try {
                    ++(attack(kind, round) ? refused : unexpected);
                } catch (const std::exception&) {
                    ++unexpected;  // must not escape the thread (std::terminate)
                }
            }
        });
    }
    for (auto& t : attackers) t.join();
    EXPECT_EQ(refused.load(), 20);
    EXPECT_EQ(unexpected.load(), 0);
}

}  // namespace pnp::ua::secured_attacks_test
