// The Part 12 push model (pnp_ua_certificate_management) over real sockets with our client:
// a SecurityAdmin on a SignAndEncrypt channel reads the trust list, trusts a device that was
// just rejected (AddCertificate) and removes it again, replaces the trust list through the
// file (Open / Write / CloseAndUpdate), has the server create a signing request that a test CA
// signs, and installs the certificate (UpdateCertificate, ApplyChanges): a new client then
// sees it in GetEndpoints and connects. Operators, anonymous sessions and a SecurityAdmin
// without encryption are refused; malformed input gets a clear status and the server keeps
// serving.
#include "ua/certificate_management/certificate_management.hpp"

#include <gtest/gtest.h>
#include <openssl/err.h>
#include <openssl/x509.h>
#include <openssl/x509v3.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <future>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "support/child_process.hpp"
#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/pki/pki.hpp"
#include "ua/server/access_control.hpp"
#include "ua/server/server.hpp"
#include "ua/server/user_store.hpp"
#include "ua/types/binary.hpp"
#include "ua/types/ns0_ids_methods.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types_other.hpp"
#include "ua/types/status_codes.hpp"

#ifndef PNP_SOURCE_DIR
#error "PNP_SOURCE_DIR must be defined"
#endif

namespace pnp::ua::certificate_management_test {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

constexpr const char* kServerUri = "urn:pnp:test:push-server";
constexpr const char* kAdminUri = "urn:pnp:test:push-admin";
constexpr std::size_t kMaxTrustListSize = 64 * 1024;  // small, so a test can exceed it

// ---- node ids ------------------------------------------------------------------------------
const NodeId kServerConfiguration(0, ns0::ServerConfiguration);
const NodeId kTrustList(
    0, ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList);
const NodeId kGroup(0, ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup);
const NodeId kRsaSha256(0, ns0::RsaSha256ApplicationCertificateType);
namespace m {
constexpr UInt32 UpdateCertificate = ns0::ServerConfiguration_UpdateCertificate;
constexpr UInt32 CreateSigningRequest = ns0::ServerConfiguration_CreateSigningRequest;
constexpr UInt32 ApplyChanges = ns0::ServerConfiguration_ApplyChanges;
constexpr UInt32 CancelChanges = ns0::ServerConfiguration_CancelChanges;
constexpr UInt32 GetRejectedList = ns0::ServerConfiguration_GetRejectedList;
constexpr UInt32 Open =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Open;
constexpr UInt32 OpenWithMasks =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_OpenWithMasks;
constexpr UInt32 Read =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Read;
constexpr UInt32 Write =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Write;
constexpr UInt32 Close =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Close;
constexpr UInt32 GetPosition =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_GetPosition;
constexpr UInt32 SetPosition =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_SetPosition;
constexpr UInt32 CloseAndUpdate =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_CloseAndUpdate;
constexpr UInt32 AddCertificate =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_AddCertificate;
constexpr UInt32 RemoveCertificate =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_RemoveCertificate;
}  // namespace m
bool isTrustListMethod(UInt32 method) {
    return method != m::UpdateCertificate && method != m::CreateSigningRequest &&
           method != m::ApplyChanges && method != m::CancelChanges && method != m::GetRejectedList;
}

// ---- certificates --------------------------------------------------------------------------
pki::Identity makeIdentity(const std::string& uri, bool ca = false) {
    pki::CertificateRequest r;
    r.applicationUri = uri;
    r.commonName = uri;
    r.dnsNames = {"localhost"};
    r.ipAddresses = {"127.0.0.1"};
    r.ca = ca;
    return pki::createSelfSigned(r);
}
const pki::Identity& adminIdentity() {
    static const pki::Identity id = makeIdentity(kAdminUri);
    return id;
}
const pki::Identity& testCa() {
    static const pki::Identity id = makeIdentity("urn:pnp:test:push-ca", true);
    return id;
}
ByteString bytesOf(const crypto::Bytes& b) { return ByteString(b.data(), b.size()); }
ByteString derOf(const pki::Certificate& c) { return bytesOf(c.der()); }

// What a CA does with a PKCS#10 request: checks its signature and issues a certificate for
// its subject, key and requested extensions (the test's GDS).
pki::Certificate signRequest(const ByteString& csr, const pki::Identity& ca) {
    const unsigned char* p = csr.data();
    std::unique_ptr<X509_REQ, decltype(&X509_REQ_free)> req(
        d2i_X509_REQ(nullptr, &p, static_cast<long>(csr.size())), X509_REQ_free);
    if (!req) throw std::runtime_error("not a PKCS#10 request");
    EVP_PKEY* key = X509_REQ_get0_pubkey(req.get());
    if (key == nullptr || X509_REQ_verify(req.get(), key) != 1)
        throw std::runtime_error("the request's signature does not verify");
    std::unique_ptr<X509, decltype(&X509_free)> x(X509_new(), X509_free);
    X509_set_version(x.get(), X509_VERSION_3);
    ASN1_INTEGER_set(X509_get_serialNumber(x.get()),
                     static_cast<long>(std::random_device{}() & 0x7fffffff));
    X509_set_issuer_name(x.get(), X509_get_subject_name(ca.certificate.native()));
    X509_set_subject_name(x.get(), X509_REQ_get_subject_name(req.get()));
    X509_gmtime_adj(X509_getm_notBefore(x.get()), -3600);
    X509_gmtime_adj(X509_getm_notAfter(x.get()), 30L * 24 * 3600);
    X509_set_pubkey(x.get(), key);
    STACK_OF(X509_EXTENSION)* exts = X509_REQ_get_extensions(req.get());
    for (int i = 0; exts != nullptr && i < sk_X509_EXTENSION_num(exts); ++i)
        X509_add_ext(x.get(), sk_X509_EXTENSION_value(exts, i), -1);
    sk_X509_EXTENSION_pop_free(exts, X509_EXTENSION_free);
    X509V3_CTX ctx;
    X509V3_set_ctx(&ctx, ca.certificate.native(), x.get(), nullptr, nullptr, 0);
    for (auto [nid, value] : {std::pair{NID_subject_key_identifier, "hash"},
                              std::pair{NID_authority_key_identifier, "keyid:always"}}) {
        X509_EXTENSION* e = X509V3_EXT_conf_nid(nullptr, &ctx, nid, value);
        X509_add_ext(x.get(), e, -1);
        X509_EXTENSION_free(e);
    }
    if (X509_sign(x.get(), ca.key.native(), EVP_sha256()) <= 0) throw std::runtime_error("sign");
    unsigned char* out = nullptr;
    const int n = i2d_X509(x.get(), &out);
    crypto::Bytes der(out, out + n);
    OPENSSL_free(out);
    return pki::Certificate::fromDer(der);
}

// The public key (SubjectPublicKeyInfo DER) of a PKCS#10 request.
crypto::Bytes requestKey(const ByteString& csr) {
    const unsigned char* p = csr.data();
    X509_REQ* req = d2i_X509_REQ(nullptr, &p, static_cast<long>(csr.size()));
    if (req == nullptr) return {};
    unsigned char* out = nullptr;
    const int n = i2d_PUBKEY(X509_REQ_get0_pubkey(req), &out);
    crypto::Bytes der(out, out + std::max(n, 0));
    OPENSSL_free(out);
    X509_REQ_free(req);
    return der;
}

// ---- the server ------------------------------------------------------------------------------
// A temporary folder, removed at the end.
struct TempDir {
    fs::path path;
    TempDir() {
        std::mt19937_64 rng(std::random_device{}());
        path = fs::temp_directory_path() / ("pnp-push-" + std::to_string(rng()));
        fs::create_directories(path);
    }
    ~TempDir() {
        std::error_code ec;
        fs::remove_all(path, ec);
    }
};

struct PushServer {
    TempDir dir;
    std::shared_ptr<pki::CertificateStore> store;
    pki::Identity identity;
    std::unique_ptr<server::Server> server;

    explicit PushServer(std::size_t filesPerSession = 2) {
        store = std::make_shared<pki::CertificateStore>(dir.path / "server-pki");
        store->ensureLayout();
        pki::CertificateRequest r;
        r.applicationUri = kServerUri;
        r.commonName = "pnp push test server";
        r.dnsNames = {"localhost"};
        r.ipAddresses = {"127.0.0.1"};
        identity = store->loadOrCreateOwn(r, "pnp");
        store->addTrusted(adminIdentity().certificate);  // the tool that manages it

        auto users = std::make_shared<server::UserStore>();
        constexpr unsigned fast = server::UserStore::kMinIterations;
        users->addUser("admin", "keys", {server::role::securityAdmin()}, fast);
        users->addUser("admin2", "keys2", {server::role::securityAdmin()}, fast);
        users->addUser("operator", "secret", {server::role::operator_()}, fast);
        server::UserAccessConfig access;
        access.users = users;

        auto c = pnp::testing::loopbackConfig();
        c.applicationUri = kServerUri;
        server::ServerSecurity sec;
        sec.identity = identity;
        sec.trust = store;
        c.security = sec;
        c.accessControl = std::make_shared<server::UserAccessControl>(access);
        server = std::make_unique<server::Server>(c);

        certificate_management::Options o;
        o.maxTrustListSize = kMaxTrustListSize;
        o.maxOpenFilesPerSession = filesPerSession;
        o.maxReadLength = 1024;  // several Reads for one trust list
        certificate_management::enableCertificateManagement(*server, store, o);
        server->start();
    }
    std::string url() const { return pnp::testing::url(*server); }
};

client::ClientConfig clientConfig(const pki::Identity& id, const std::string& uri,
                                  std::shared_ptr<pki::CertificateStore> trust = nullptr) {
    client::ClientConfig c;
    c.applicationUri = uri;
    c.requestTimeout = 10s;
    c.connectTimeout = 10s;
    c.reconnect.enabled = false;
    client::ClientSecurity s;
    s.identity = id;
    s.trust = std::move(trust);  // null: every server certificate (the server's own test)
    c.security = s;
    return c;
}

std::unique_ptr<client::Client> connectAdmin(const PushServer& s, const std::string& user = "admin",
                                             const std::string& password = "keys") {
    auto c = std::make_unique<client::Client>(clientConfig(adminIdentity(), kAdminUri));
    c->connect(s.url(), client::UserName{user, password});
    return c;
}

client::CallResult call(client::Client& c, UInt32 method, std::vector<Variant> in = {}) {
    return c.call(isTrustListMethod(method) ? kTrustList : kServerConfiguration, NodeId(0, method),
                  std::move(in));
}

template <class T>
T output(const client::CallResult& r, std::size_t i = 0) {
    if (!r.ok() || i >= r.outputs.size() || r.outputs[i].scalar<T>() == nullptr)
        throw std::runtime_error("no output " + std::to_string(i) + ": " + r.status.toString());
    return *r.outputs[i].scalar<T>();
}

// The trust list through the file: OpenWithMasks, Read until the end (bounded), Close.
TrustListDataType readTrustList(client::Client& c, UInt32 masks = 15) {
    const UInt32 handle = output<UInt32>(call(c, m::OpenWithMasks, {Variant(masks)}));
    std::vector<Byte> bytes;
    for (int i = 0; i < 1000; ++i) {
        const ByteString chunk =
            output<ByteString>(call(c, m::Read, {Variant(handle), Variant(Int32{4096})}));
        if (chunk.empty()) break;
        EXPECT_LE(chunk.size(), 1024u);  // maxReadLength
        bytes.insert(bytes.end(), chunk.begin(), chunk.end());
    }
    EXPECT_TRUE(call(c, m::Close, {Variant(handle)}).ok());
    TrustListDataType list;
    BinaryDecoder d(bytes.data(), bytes.size());
    decode(d, list);
    EXPECT_EQ(d.remaining(), 0u);
    return list;
}

std::vector<Byte> encoded(const TrustListDataType& list) {
    Buffer b;
    BinaryEncoder e(b);
    encode(e, list);
    return std::vector<Byte>(b.begin(), b.end());
}

bool contains(const std::vector<ByteString>& list, const pki::Certificate& cert) {
    return std::find(list.begin(), list.end(), derOf(cert)) != list.end();
}

// Whether a client with `id` gets a session (an untrusted one is refused by the server).
bool connects(const PushServer& s, const pki::Identity& id, const std::string& uri) {
    try {
        client::Client c(clientConfig(id, uri));
        c.connect(s.url());
        return c.readValue(NodeId(0, ns0::Server_ServerStatus_State)) == Variant(Int32{0});
    } catch (const client::Error&) {
        return false;
    }
}

bool storeHas(const pki::CertificateStore& store, pki::TrustState state,
              const pki::Certificate& c) {
    for (const auto& e : store.list())
        if (e.state == state && e.certificate == c) return true;
    return false;
}

// ---- tests -----------------------------------------------------------------------------------
TEST(CertificateManagement, VariablesTellWhatTheServerSupports) {
    PushServer s;
    auto admin = connectAdmin(s);
    EXPECT_EQ(admin->readValue(NodeId(0, ns0::ServerConfiguration_SupportedPrivateKeyFormats)),
              Variant(std::vector<String>{"PEM"}));
    EXPECT_EQ(admin->readValue(NodeId(0, ns0::ServerConfiguration_MaxTrustListSize)),
              Variant(static_cast<UInt32>(kMaxTrustListSize)));
    EXPECT_EQ(
        admin->readValue(NodeId(
            0,
            ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_CertificateTypes)),
        Variant(std::vector<NodeId>{kRsaSha256}));
    EXPECT_EQ(
        admin->readValue(NodeId(
            0,
            ns0::
                ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_OpenCount)),
        Variant(UInt16{0}));
    const Variant size = admin->readValue(NodeId(
        0, ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Size));
    ASSERT_NE(size.scalar<UInt64>(), nullptr);
    EXPECT_EQ(*size.scalar<UInt64>(), encoded(readTrustList(*admin)).size());
}

TEST(CertificateManagement, AdminTrustsARejectedDeviceAndRemovesItAgain) {
    PushServer s;
    auto admin = connectAdmin(s);
    const TrustListDataType before = readTrustList(*admin);
    EXPECT_EQ(before.specifiedLists, 15u);
    EXPECT_TRUE(contains(before.trustedCertificates, adminIdentity().certificate));

    // A new device is refused and lands in rejected/.
    const pki::Identity device = makeIdentity("urn:pnp:test:push-device");
    EXPECT_FALSE(connects(s, device, "urn:pnp:test:push-device"));
    const auto rejected = call(*admin, m::GetRejectedList);
    ASSERT_TRUE(rejected.ok()) << rejected.status.toString();
    ASSERT_EQ(rejected.outputs.size(), 1u);
    ASSERT_NE(rejected.outputs[0].array<ByteString>(), nullptr);
    EXPECT_TRUE(contains(*rejected.outputs[0].array<ByteString>(), device.certificate));

    // The operator's decision, remotely.
    const DateTime lastUpdate =
        *admin
             ->readValue(NodeId(
                 0,
                 ns0::
                     ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_LastUpdateTime))
             .scalar<DateTime>();
    auto added = call(*admin, m::AddCertificate,
                      {Variant(derOf(device.certificate)), Variant(Boolean{true})});
    ASSERT_TRUE(added.ok()) << added.status.toString();
    EXPECT_TRUE(connects(s, device, "urn:pnp:test:push-device"));
    EXPECT_TRUE(contains(readTrustList(*admin, 1).trustedCertificates, device.certificate));
    EXPECT_FALSE(storeHas(*s.store, pki::TrustState::Rejected, device.certificate));
    EXPECT_GT(
        admin
            ->readValue(NodeId(
                0,
                ns0::
                    ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_LastUpdateTime))
            .scalar<DateTime>()
            ->ticks,
        lastUpdate.ticks);

    auto removed =
        call(*admin, m::RemoveCertificate,
             {Variant(String(device.certificate.thumbprintHex())), Variant(Boolean{true})});
    ASSERT_TRUE(removed.ok()) << removed.status.toString();
    EXPECT_FALSE(connects(s, device, "urn:pnp:test:push-device"));
    EXPECT_FALSE(contains(readTrustList(*admin).trustedCertificates, device.certificate));
    // Not there (any more): Bad_InvalidArgument.
    EXPECT_EQ(call(*admin, m::RemoveCertificate,
                   {Variant(String(device.certificate.thumbprintHex())), Variant(Boolean{true})})
                  .status,
              status::BadInvalidArgument);
}

TEST(CertificateManagement, CloseAndUpdateReplacesTheTrustList) {
    PushServer s;
    auto admin = connectAdmin(s);
    const pki::Identity old = makeIdentity("urn:pnp:test:push-old");
    s.store->addTrusted(old.certificate);
    const pki::Identity device = makeIdentity("urn:pnp:test:push-device2");
    const crypto::Bytes crl = pki::createCrl(testCa(), {});

    TrustListDataType list;
    list.specifiedLists = 1 | 4 | 8;  // trusted certificates, issuers and their CRLs
    list.trustedCertificates = {derOf(adminIdentity().certificate), derOf(device.certificate)};
    list.issuerCertificates = {derOf(testCa().certificate)};
    list.issuerCrls = {bytesOf(crl)};
    const std::vector<Byte> data = encoded(list);

    const UInt32 handle = output<UInt32>(call(*admin, m::Open, {Variant(Byte{6})}));
    // Written in pieces; the position follows.
    const std::size_t half = data.size() / 2;
    ASSERT_TRUE(
        call(*admin, m::Write, {Variant(handle), Variant(ByteString(data.data(), half))}).ok());
    EXPECT_EQ(output<UInt64>(call(*admin, m::GetPosition, {Variant(handle)})), half);
    ASSERT_TRUE(call(*admin, m::Write,
                     {Variant(handle), Variant(ByteString(data.data() + half, data.size() - half))})
                    .ok());
    const auto done = call(*admin, m::CloseAndUpdate, {Variant(handle)});
    ASSERT_TRUE(done.ok()) << done.status.toString();
    EXPECT_EQ(output<Boolean>(done), false);  // applyChangesRequired: the store takes it at once

    EXPECT_TRUE(storeHas(*s.store, pki::TrustState::Trusted, device.certificate));
    EXPECT_FALSE(storeHas(*s.store, pki::TrustState::Trusted, old.certificate));
    EXPECT_TRUE(storeHas(*s.store, pki::TrustState::Issuer, testCa().certificate));
    const TrustListDataType after = readTrustList(*admin);
    EXPECT_EQ(after.issuerCrls, list.issuerCrls);
    EXPECT_TRUE(contains(after.trustedCertificates, device.certificate));
    EXPECT_EQ(after.trustedCertificates.size(), 2u);
    EXPECT_TRUE(connects(s, device, "urn:pnp:test:push-device2"));
    EXPECT_FALSE(connects(s, old, "urn:pnp:test:push-old"));
    // The handle is gone.
    EXPECT_EQ(call(*admin, m::Close, {Variant(handle)}).status, status::BadInvalidArgument);
}

TEST(CertificateManagement, SigningRequestSignedByACaBecomesTheServersCertificate) {
    PushServer s;
    auto admin = connectAdmin(s);

    // With the current key.
    const auto same = call(*admin, m::CreateSigningRequest,
                           {Variant(kGroup), Variant(kRsaSha256), Variant(String{}),
                            Variant(Boolean{false}), Variant(ByteString{})});
    ASSERT_TRUE(same.ok()) << same.status.toString();
    EXPECT_EQ(requestKey(output<ByteString>(same)), s.identity.certificate.publicKey().toDer());

    // With a new key (and the caller's entropy).
    const crypto::Bytes nonce = crypto::randomBytes(32);
    const auto csr =
        call(*admin, m::CreateSigningRequest,
             {Variant(NodeId{}), Variant(NodeId{}), Variant(String("CN=pnp renewed/O=pnp test")),
              Variant(Boolean{true}), Variant(bytesOf(nonce))});
    ASSERT_TRUE(csr.ok()) << csr.status.toString();
    const pki::Certificate issued = signRequest(output<ByteString>(csr), testCa());
    EXPECT_NE(issued.publicKey().toDer(), s.identity.certificate.publicKey().toDer());
    EXPECT_EQ(issued.uris(), std::vector<std::string>{kServerUri});
    EXPECT_EQ(issued.commonName(), "pnp renewed");

    const auto update = call(*admin, m::UpdateCertificate,
                             {Variant(kGroup), Variant(kRsaSha256), Variant(derOf(issued)),
                              Variant(std::vector<ByteString>{derOf(testCa().certificate)}),
                              Variant(String{}), Variant(ByteString{})});
    ASSERT_TRUE(update.ok()) << update.status.toString();
    EXPECT_EQ(output<Boolean>(update), true);  // applyChangesRequired
    // Nothing changes before ApplyChanges.
    client::Client probe(clientConfig(adminIdentity(), kAdminUri));
    EXPECT_EQ(probe.getEndpoints(s.url()).front().serverCertificate, derOf(s.identity.certificate));

    const auto applied = call(*admin, m::ApplyChanges);
    ASSERT_TRUE(applied.ok()) << applied.status.toString();
    for (const auto& e : probe.getEndpoints(s.url()))
        EXPECT_EQ(e.serverCertificate, derOf(issued)) << toString(e.securityMode);
    EXPECT_EQ(s.store->ownCertificate("pnp"), issued);

    // A client that trusts the CA (with its CRL) validates the new certificate and connects.
    TempDir clientDir;
    auto clientTrust = std::make_shared<pki::CertificateStore>(clientDir.path);
    clientTrust->ensureLayout();
    clientTrust->addTrusted(testCa().certificate);
    clientTrust->addCrl(pki::createCrl(testCa(), {}));
    client::Client fresh(clientConfig(adminIdentity(), kAdminUri, clientTrust));
    fresh.connect(s.url(), client::UserName{"admin", "keys"});
    EXPECT_EQ(fresh.readValue(NodeId(0, ns0::Server_ServerStatus_State)), Variant(Int32{0}));
    // The admin's channel, opened with the old certificate, keeps working.
    EXPECT_EQ(admin->readValue(NodeId(0, ns0::Server_ServerStatus_State)), Variant(Int32{0}));
}

TEST(CertificateManagement, UpdateCertificateWithItsOwnKey) {
    PushServer s;
    auto admin = connectAdmin(s);
    pki::CertificateRequest r;
    r.applicationUri = kServerUri;
    r.commonName = "pnp with a key from elsewhere";
    r.ipAddresses = {"127.0.0.1"};
    const pki::Identity next = pki::createSigned(r, testCa());
    const std::string pem = next.key.toPem();
    auto update = call(
        *admin, m::UpdateCertificate,
        {Variant(NodeId{}), Variant(NodeId{}), Variant(derOf(next.certificate)),
         Variant(std::vector<ByteString>{}), Variant(String("PEM")), Variant(ByteString(pem))});
    ASSERT_TRUE(update.ok()) << update.status.toString();
    // CancelChanges drops it: ApplyChanges then changes nothing.
    ASSERT_TRUE(call(*admin, m::CancelChanges).ok());
    ASSERT_TRUE(call(*admin, m::ApplyChanges).ok());
    EXPECT_EQ(client::Client(clientConfig(adminIdentity(), kAdminUri))
                  .getEndpoints(s.url())
                  .front()
                  .serverCertificate,
              derOf(s.identity.certificate));
    update = call(
        *admin, m::UpdateCertificate,
        {Variant(NodeId{}), Variant(NodeId{}), Variant(derOf(next.certificate)),
         Variant(std::vector<ByteString>{}), Variant(String("PEM")), Variant(ByteString(pem))});
    ASSERT_TRUE(update.ok()) << update.status.toString();
    ASSERT_TRUE(call(*admin, m::ApplyChanges).ok());
    client::Client fresh(clientConfig(adminIdentity(), kAdminUri));
    fresh.connect(s.url());  // the server proves it holds the new key (CreateSession signature)
    EXPECT_EQ(fresh.getEndpoints().front().serverCertificate, derOf(next.certificate));
}

TEST(CertificateManagement, OnlyASecurityAdminOnAnEncryptedChannel) {
    PushServer s;
    // Operator and anonymous sessions over SignAndEncrypt.
    client::Client op(clientConfig(adminIdentity(), kAdminUri));
    op.connect(s.url(), client::UserName{"operator", "secret"});
    client::Client anon(clientConfig(adminIdentity(), kAdminUri));
    anon.connect(s.url());
    for (client::Client* c : {&op, &anon}) {
        EXPECT_EQ(call(*c, m::GetRejectedList).status, status::BadUserAccessDenied);
        EXPECT_EQ(call(*c, m::Open, {Variant(Byte{1})}).status, status::BadUserAccessDenied);
        EXPECT_EQ(call(*c, m::ApplyChanges).status, status::BadUserAccessDenied);
        EXPECT_EQ(call(*c, m::AddCertificate,
                       {Variant(derOf(makeIdentity("urn:x").certificate)), Variant(Boolean{true})})
                      .status,
                  status::BadUserAccessDenied);
        EXPECT_EQ(call(*c, m::CreateSigningRequest,
                       {Variant(NodeId{}), Variant(NodeId{}), Variant(String{}),
                        Variant(Boolean{false}), Variant(ByteString{})})
                      .status,
                  status::BadUserAccessDenied);
    }
    // A SecurityAdmin whose channel is not encrypted (Sign): the role does not count. (Our
    // client always takes SignAndEncrypt when offered, so the session layer's view of such a
    // session is given to the address space directly.)
    server::SessionIdentity signOnly;
    signOnly.anonymous = false;
    signOnly.userName = "admin";
    signOnly.grant(server::role::anonymous());
    signOnly.grant(server::role::authenticatedUser());
    signOnly.grant(server::role::securityAdmin());
    signOnly.encryptedChannel = false;
    CallRequest req;
    CallMethodRequest mr;
    mr.objectId = kServerConfiguration;
    mr.methodId = NodeId(0, m::GetRejectedList);
    req.methodsToCall.push_back(mr);
    std::promise<CallResponse> response;
    s.server->addressSpace().call(
        req, NodeId(1, "sign-only"), [&](CallResponse r) { response.set_value(std::move(r)); },
        &signOnly);
    auto result = response.get_future();
    ASSERT_EQ(result.wait_for(5s), std::future_status::ready);
    EXPECT_EQ(result.get().results.at(0).statusCode, status::BadUserAccessDenied);
    // No certificate change happened meanwhile: the admin still reads the old one.
    auto admin = connectAdmin(s);
    EXPECT_TRUE(call(*admin, m::GetRejectedList).ok());
}

TEST(CertificateManagement, BadInputGetsClearStatusAndTheServerKeepsServing) {
    PushServer s;
    auto admin = connectAdmin(s);
    const ByteString garbage("\x30\x82\x01\x00not a certificate at all");
    const auto args = [](std::vector<Variant> v) { return v; };

    // UpdateCertificate.
    EXPECT_EQ(
        call(*admin, m::UpdateCertificate,
             args({Variant(NodeId{}), Variant(NodeId{}), Variant(garbage),
                   Variant(std::vector<ByteString>{}), Variant(String{}), Variant(ByteString{})}))
            .status,
        status::BadCertificateInvalid);
    EXPECT_EQ(
        call(*admin, m::UpdateCertificate,
             {Variant(NodeId(0, 12345)), Variant(NodeId{}), Variant(derOf(s.identity.certificate)),
              Variant(std::vector<ByteString>{}), Variant(String{}), Variant(ByteString{})})
            .status,
        status::BadInvalidArgument);  // not a certificate group
    const pki::Identity other = makeIdentity("urn:pnp:test:someone-else");
    EXPECT_EQ(call(*admin, m::UpdateCertificate,
                   {Variant(NodeId{}), Variant(NodeId{}), Variant(derOf(other.certificate)),
                    Variant(std::vector<ByteString>{}), Variant(String("PEM")),
                    Variant(ByteString(other.key.toPem()))})
                  .status,
              status::BadCertificateUriInvalid);
    pki::CertificateRequest r;
    r.applicationUri = kServerUri;
    r.commonName = "no key known";
    const pki::Identity unknownKey = pki::createSelfSigned(r);
    EXPECT_EQ(call(*admin, m::UpdateCertificate,
                   {Variant(NodeId{}), Variant(NodeId{}), Variant(derOf(unknownKey.certificate)),
                    Variant(std::vector<ByteString>{}), Variant(String{}), Variant(ByteString{})})
                  .status,
              status::BadSecurityChecksFailed);  // neither the current key nor a new one
    EXPECT_EQ(call(*admin, m::UpdateCertificate,
                   {Variant(NodeId{}), Variant(NodeId{}), Variant(derOf(unknownKey.certificate)),
                    Variant(std::vector<ByteString>{}), Variant(String("PFX")),
                    Variant(ByteString("pfx bytes"))})
                  .status,
              status::BadNotSupported);
    // Nothing pending: ApplyChanges changes nothing.
    ASSERT_TRUE(call(*admin, m::ApplyChanges).ok());
    EXPECT_EQ(client::Client(clientConfig(adminIdentity(), kAdminUri))
                  .getEndpoints(s.url())
                  .front()
                  .serverCertificate,
              derOf(s.identity.certificate));

    // CreateSigningRequest.
    EXPECT_EQ(call(*admin, m::CreateSigningRequest,
                   {Variant(NodeId{}), Variant(NodeId{}), Variant(String{}), Variant(Boolean{true}),
                    Variant(ByteString("short"))})
                  .status,
              status::BadInvalidArgument);  // a new key needs >= 32 bytes of entropy
    EXPECT_EQ(call(*admin, m::CreateSigningRequest,
                   {Variant(NodeId{}), Variant(NodeId{}), Variant(String("no attributes here")),
                    Variant(Boolean{false}), Variant(ByteString{})})
                  .status,
              status::BadInvalidArgument);

    // The TrustList file.
    EXPECT_EQ(call(*admin, m::Open, {Variant(Byte{2})}).status,
              status::BadInvalidArgument);  // Write without EraseExisting
    EXPECT_EQ(call(*admin, m::OpenWithMasks, {Variant(UInt32{16})}).status,
              status::BadInvalidArgument);
    EXPECT_EQ(call(*admin, m::Read, {Variant(UInt32{12345}), Variant(Int32{10})}).status,
              status::BadInvalidArgument);
    const UInt32 reading = output<UInt32>(call(*admin, m::Open, {Variant(Byte{1})}));
    EXPECT_EQ(call(*admin, m::Read, {Variant(reading), Variant(Int32{-1})}).status,
              status::BadInvalidArgument);
    EXPECT_EQ(call(*admin, m::Write, {Variant(reading), Variant(ByteString("x"))}).status,
              status::BadInvalidState);
    EXPECT_EQ(call(*admin, m::CloseAndUpdate, {Variant(reading)}).status, status::BadInvalidState);
    EXPECT_EQ(call(*admin, m::Open, {Variant(Byte{6})}).status,
              status::BadInvalidState);  // being read
    EXPECT_EQ(
        call(*admin, m::AddCertificate, {Variant(derOf(other.certificate)), Variant(Boolean{true})})
            .status,
        status::BadInvalidState);  // the file is open
    // Read past the end: an empty ByteString.
    ASSERT_TRUE(call(*admin, m::SetPosition, {Variant(reading), Variant(UInt64{1} << 40)}).ok());
    EXPECT_TRUE(
        output<ByteString>(call(*admin, m::Read, {Variant(reading), Variant(Int32{100})})).empty());
    // Another session cannot use the handle.
    auto admin2 = connectAdmin(s, "admin2", "keys2");
    EXPECT_EQ(call(*admin2, m::Read, {Variant(reading), Variant(Int32{10})}).status,
              status::BadInvalidArgument);
    EXPECT_EQ(call(*admin2, m::Close, {Variant(reading)}).status, status::BadInvalidArgument);
    // Handles per session are bounded.
    const UInt32 second = output<UInt32>(call(*admin, m::Open, {Variant(Byte{1})}));
    EXPECT_EQ(call(*admin, m::Open, {Variant(Byte{1})}).status, status::BadResourceUnavailable);
    ASSERT_TRUE(call(*admin, m::Close, {Variant(second)}).ok());
    ASSERT_TRUE(call(*admin, m::Close, {Variant(reading)}).ok());

    // Writing: bounded by MaxTrustListSize; garbage is refused and the file closed anyway.
    const UInt32 writing = output<UInt32>(call(*admin, m::Open, {Variant(Byte{6})}));
    EXPECT_EQ(call(*admin, m::Read, {Variant(writing), Variant(Int32{10})}).status,
              status::BadInvalidState);
    const std::string big(kMaxTrustListSize + 1, 'x');
    EXPECT_EQ(call(*admin, m::Write, {Variant(writing), Variant(ByteString(big))}).status,
              status::BadEncodingLimitsExceeded);
    ASSERT_TRUE(call(*admin, m::Write, {Variant(writing), Variant(ByteString("garbage"))}).ok());
    EXPECT_EQ(call(*admin, m::CloseAndUpdate, {Variant(writing)}).status, status::BadDecodingError);
    EXPECT_EQ(call(*admin, m::Close, {Variant(writing)}).status, status::BadInvalidArgument);
    // A well-formed list with a garbage certificate changes nothing.
    TrustListDataType bad;
    bad.specifiedLists = 1;
    bad.trustedCertificates = {garbage};
    const UInt32 again = output<UInt32>(call(*admin, m::Open, {Variant(Byte{6})}));
    ASSERT_TRUE(
        call(*admin, m::Write,
             {Variant(again), Variant(ByteString(encoded(bad).data(), encoded(bad).size()))})
            .ok());
    EXPECT_EQ(call(*admin, m::CloseAndUpdate, {Variant(again)}).status,
              status::BadCertificateInvalid);
    EXPECT_TRUE(storeHas(*s.store, pki::TrustState::Trusted, adminIdentity().certificate));

    // AddCertificate / RemoveCertificate.
    EXPECT_EQ(call(*admin, m::AddCertificate, {Variant(garbage), Variant(Boolean{true})}).status,
              status::BadCertificateInvalid);
    EXPECT_EQ(call(*admin, m::AddCertificate,
                   {Variant(derOf(other.certificate)), Variant(Boolean{false})})
                  .status,
              status::BadCertificateInvalid);  // issuers come with their CRLs, through the file
    EXPECT_EQ(call(*admin, m::AddCertificate,
                   {Variant(derOf(testCa().certificate)), Variant(Boolean{true})})
                  .status,
              status::BadCertificateUseNotAllowed);
    pki::CertificateRequest orphanRequest;
    orphanRequest.applicationUri = "urn:pnp:test:signed-by-unknown-ca";
    orphanRequest.commonName = "orphan";
    const pki::Identity orphan =
        pki::createSigned(orphanRequest, makeIdentity("urn:pnp:test:unknown-ca", true));
    EXPECT_EQ(call(*admin, m::AddCertificate,
                   {Variant(derOf(orphan.certificate)), Variant(Boolean{true})})
                  .status,
              status::BadCertificateChainIncomplete);  // its CA is not in the trust list
    EXPECT_EQ(
        call(*admin, m::RemoveCertificate, {Variant(String("not-hex")), Variant(Boolean{true})})
            .status,
        status::BadInvalidArgument);

    // Still serving, nothing left open.
    EXPECT_EQ(admin->readValue(NodeId(0, ns0::Server_ServerStatus_State)), Variant(Int32{0}));
    EXPECT_EQ(
        admin->readValue(NodeId(
            0,
            ns0::
                ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_OpenCount)),
        Variant(UInt16{0}));
}

TEST(CertificateManagement, HandlesEndWithTheirSession) {
    PushServer s;
    const NodeId openCount(
        0, ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_OpenCount);
    auto admin = connectAdmin(s);
    {
        auto other = connectAdmin(s, "admin2", "keys2");
        output<UInt32>(call(*other, m::Open, {Variant(Byte{6})}));
        EXPECT_EQ(admin->readValue(openCount), Variant(UInt16{1}));
        // Locked for everyone else while it is open for writing.
        EXPECT_EQ(call(*admin, m::Open, {Variant(Byte{1})}).status, status::BadInvalidState);
    }  // CloseSession
    Variant count;
    for (int i = 0; i < 100; ++i) {
        count = admin->readValue(openCount);
        if (count == Variant(UInt16{0})) break;
        std::this_thread::sleep_for(20ms);
    }
    EXPECT_EQ(count, Variant(UInt16{0}));
    const UInt32 handle = output<UInt32>(call(*admin, m::Open, {Variant(Byte{1})}));
    EXPECT_TRUE(call(*admin, m::Close, {Variant(handle)}).ok());
}

TEST(CertificateManagement, SubjectNameRoundTrip) {
    const pki::Identity id = makeIdentity("urn:pnp:test:subject");
    EXPECT_EQ(pki::subjectNameOf(id.certificate), "CN=urn:pnp:test:subject/O=pnp");
    pki::CertificateRequest r;
    r.applicationUri = "urn:pnp:test:subject";
    const crypto::Bytes csr =
        pki::createSigningRequest(id.key, r, "/CN=\"a/b=c\"/O=pnp/DC=host.example/S=Bavaria/C=DE");
    const pki::Certificate cert = signRequest(bytesOf(csr), testCa());
    EXPECT_EQ(pki::subjectNameOf(cert), "CN=\"a/b=c\"/O=pnp/DC=host.example/ST=Bavaria/C=DE");
    EXPECT_EQ(cert.uris(), std::vector<std::string>{"urn:pnp:test:subject"});
    // Commas separate when no slash does.
    EXPECT_EQ(pki::subjectNameOf(signRequest(
                  bytesOf(pki::createSigningRequest(id.key, r, "CN=x, O=y")), testCa())),
              "CN=x/O=y");
    for (const char* bad : {"CN", "CN=", "XX=1", "CN=\"open", "CN=a=b"})
        EXPECT_THROW(pki::createSigningRequest(id.key, r, bad), pki::PkiError) << bad;
    EXPECT_THROW(pki::createSigningRequest(id.key, r, std::string(2000, 'a')), pki::PkiError);
}

// node-opcua as the managing tool: the methods over SignAndEncrypt, refused over Sign.
TEST(CertificateManagement, NodeOpcuaManagesOnlyOverAnEncryptedChannel) {
    const std::string node = pnp::testing::findInPath("node");
    const std::string source = PNP_SOURCE_DIR;
    const std::string script = source + "/tests/certificate_management/node_push_client.js";
    if (node.empty() || !fs::exists(source + "/node_modules/node-opcua"))
        GTEST_SKIP() << "node or node-opcua (npm install in " << source << ") missing";
    PushServer s;
    TempDir dir;
    const std::string pki = (dir.path / "node-pki").string();
    const std::string uri = "urn:pnp:test:push-node";
    const std::string der = (dir.path / "node-client.der").string();
    auto log = [](const fs::path& file) {
        std::ifstream in(file);
        return std::string(std::istreambuf_iterator<char>(in), {});
    };
    std::string error;
    {
        pnp::testing::ChildProcess init;
        ASSERT_TRUE(init.start(
            {node, script, "--init", "--pki", pki, "--export-cert", der, "--application-uri", uri},
            (dir.path / "init.log").string(), error))
            << error;
        ASSERT_TRUE(init.waitForPrefix("CERT ", 60s, error)) << error << log(dir.path / "init.log");
        EXPECT_EQ(init.waitExit(10s), std::optional<int>(0));
    }
    s.store->addTrusted(pki::Certificate::load(der));
    fs::create_directories(fs::path(pki) / "trusted" / "certs");
    {
        std::ofstream f(fs::path(pki) / "trusted" / "certs" / "pnp-server.der", std::ios::binary);
        const auto& d = s.identity.certificate.der();
        f.write(reinterpret_cast<const char*>(d.data()), static_cast<std::streamsize>(d.size()));
    }
    const fs::path results = dir.path / "results.txt";
    pnp::testing::ChildProcess client;
    ASSERT_TRUE(client.start({node, script, s.url(), "--pki", pki, "--application-uri", uri,
                              "--user", "admin:keys", "--results", results.string()},
                             (dir.path / "run.log").string(), error))
        << error;
    ASSERT_TRUE(client.waitForLine("DONE", 60s, error)) << error << "\n"
                                                        << log(dir.path / "run.log");
    EXPECT_EQ(client.waitExit(10s), std::optional<int>(0));
    const std::string text = log(results);
    std::size_t bytes = 0;
    EXPECT_NE(text.find("RESULT SignAndEncrypt GetRejectedList Good\n"), std::string::npos) << text;
    EXPECT_NE(text.find("RESULT SignAndEncrypt OpenWithMasks Good\n"), std::string::npos) << text;
    const auto read = text.find("RESULT SignAndEncrypt Read Good ");
    ASSERT_NE(read, std::string::npos) << text;
    bytes = std::stoul(text.substr(read + std::string("RESULT SignAndEncrypt Read Good ").size()));
    EXPECT_GT(bytes, s.identity.certificate.der().size());  // the trust list: admin + node client
    EXPECT_NE(text.find("RESULT SignAndEncrypt Close Good\n"), std::string::npos) << text;
    EXPECT_NE(text.find("RESULT Sign GetRejectedList BadUserAccessDenied\n"), std::string::npos)
        << text;
}

}  // namespace pnp::ua::certificate_management_test
