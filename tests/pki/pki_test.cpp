// pnp_ua_pki: certificates (parsing, creation), the PKI folder and validation outcomes of
// OPC 10000-4 §6.1.3 with real chains (root CA -> intermediate -> leaf) built by
// createSigned, real CRLs and real files.
#include "ua/pki/pki.hpp"

#include <gtest/gtest.h>
#include <openssl/evp.h>
#include <openssl/rsa.h>
#include <openssl/x509v3.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <thread>

#include "ua/types/status_codes.hpp"

namespace pnp::ua::pki {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

// RSA keys are slow to generate: a few, shared by the tests (distinct ones per role).
crypto::PrivateKey testKey(int index, int bits = 2048) {
    static std::map<std::pair<int, int>, crypto::PrivateKey> keys;
    auto& k = keys[{index, bits}];
    if (!k) {
        EVP_PKEY* raw = EVP_RSA_gen(static_cast<unsigned>(bits));
        if (raw == nullptr) throw std::runtime_error("EVP_RSA_gen");
        k = crypto::PrivateKey(std::shared_ptr<EVP_PKEY>(raw, EVP_PKEY_free));
    }
    return k;
}

CertificateRequest appRequest(const std::string& uri, int key) {
    CertificateRequest r;
    r.applicationUri = uri;
    r.commonName = "pnp test " + std::to_string(key);
    r.dnsNames = {"robot-1.local", "Robot-1"};
    r.ipAddresses = {"127.0.0.1", "::1"};
    r.key = testKey(key);
    return r;
}

CertificateRequest caRequest(const std::string& name, int key) {
    CertificateRequest r;
    r.commonName = name;
    r.ca = true;
    r.key = testKey(key);
    return r;
}

class TempDir {
  public:
    TempDir() {
        path_ = fs::path(::testing::TempDir()) /
                ("pnp_pki_" + std::to_string(::getpid()) + "_" + std::to_string(counter_++));
        fs::remove_all(path_);
    }
    ~TempDir() {
        std::error_code ec;
        fs::remove_all(path_, ec);
    }
    const fs::path& path() const { return path_; }

  private:
    static inline int counter_ = 0;
    fs::path path_;
};

std::size_t filesIn(const fs::path& dir) {
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) return 0;
    return static_cast<std::size_t>(
        std::distance(fs::directory_iterator(dir), fs::directory_iterator()));
}

// ---------------------------------------------------------------------------------------
TEST(Certificate, SelfSignedHasTheFieldsOfPart6) {
    const Identity id = createSelfSigned(appRequest("urn:pnp:test:a", 0));
    const Certificate& c = id.certificate;
    EXPECT_EQ(c.commonName(), "pnp test 0");
    EXPECT_EQ(c.subject(), "CN=pnp test 0, O=pnp");
    EXPECT_EQ(c.issuer(), c.subject());
    EXPECT_EQ(c.uris(), std::vector<std::string>{"urn:pnp:test:a"});
    EXPECT_EQ(c.dnsNames(), (std::vector<std::string>{"robot-1.local", "Robot-1"}));
    EXPECT_EQ(c.ipAddresses(), (std::vector<std::string>{"127.0.0.1", "::1"}));
    EXPECT_EQ(c.keyBits(), 2048);
    EXPECT_EQ(c.signatureAlgorithm(), "sha256WithRSAEncryption");
    EXPECT_TRUE(c.isSelfSigned());
    EXPECT_FALSE(c.isCa());
    EXPECT_EQ(c.serialHex().size(), 32u);  // 16 bytes, positive, no leading zero
    EXPECT_EQ(c.thumbprint().size(), 20u);
    EXPECT_EQ(c.thumbprintHex().size(), 40u);
    const auto now = std::chrono::system_clock::now();
    EXPECT_LT(c.notBefore(), now);
    EXPECT_GT(c.notAfter(), now + std::chrono::hours(24 * 365 * 4));
    EXPECT_TRUE(c.publicKey());
    // Two certificates: two serials.
    EXPECT_NE(createSelfSigned(appRequest("urn:pnp:test:a", 0)).certificate.serialHex(),
              c.serialHex());
}

TEST(Certificate, DerPemAndChainsRoundTrip) {
    const Identity id = createSelfSigned(appRequest("urn:pnp:test:b", 0));
    const Certificate& c = id.certificate;
    EXPECT_EQ(Certificate::fromDer(c.der()), c);
    EXPECT_EQ(Certificate::fromPem(c.toPem()), c);
    const Identity root = createSelfSigned(caRequest("root", 1));
    Bytes chain = c.der();
    chain.insert(chain.end(), root.certificate.der().begin(), root.certificate.der().end());
    const auto parsed = Certificate::chainFromDer(chain);
    ASSERT_EQ(parsed.size(), 2u);
    EXPECT_EQ(parsed[0], c);
    EXPECT_EQ(parsed[1], root.certificate);
    EXPECT_TRUE(parsed[1].isCa());
}

TEST(Certificate, MalformedInputIsAPkiErrorNeverACrash) {
    const Identity id = createSelfSigned(appRequest("urn:pnp:test:c", 0));
    const Bytes& der = id.certificate.der();
    EXPECT_THROW(Certificate::fromDer({}), PkiError);
    Bytes trailing = der;
    trailing.push_back(0);
    EXPECT_THROW(Certificate::fromDer(trailing), PkiError);
    EXPECT_THROW(Certificate::fromDer(Bytes(kMaxCertificateSize + 1, 0x30)), PkiError);
    EXPECT_THROW(Certificate::fromPem("-----BEGIN CERTIFICATE-----\nAAAA\n"), PkiError);
    EXPECT_THROW(Certificate::chainFromDer({}), PkiError);
    Bytes nine;
    for (int i = 0; i < 9; ++i) nine.insert(nine.end(), der.begin(), der.end());
    EXPECT_THROW(Certificate::chainFromDer(nine), PkiError);
    // Every truncation and a byte flipped at every position: an error or a certificate.
    for (std::size_t n = 0; n < der.size(); ++n) {
        EXPECT_THROW(Certificate::fromDer(ByteView(der.data(), n)), PkiError) << n;
    }
    int parsed = 0;
    for (std::size_t i = 0; i < der.size(); ++i) {
        Bytes bad = der;
        bad[i] ^= 0xFF;
        try {
            const Certificate c = Certificate::fromDer(bad);
            (void)c.subject();
            (void)c.uris();
            (void)c.isSelfSigned();
            ++parsed;
        } catch (const PkiError&) {
        }
    }
    EXPECT_GT(parsed, 0);  // e.g. bytes of the signature: parse, then fail validation
}

TEST(Certificate, CreateRefusesIncompleteRequests) {
    CertificateRequest r = appRequest("", 0);
    EXPECT_THROW(createSelfSigned(r), PkiError);  // an application certificate needs its URI
    r = appRequest("urn:x", 0);
    r.commonName.clear();
    EXPECT_THROW(createSelfSigned(r), PkiError);
    r = appRequest("urn:x", 0);
    r.ipAddresses = {"300.1.1.1"};
    EXPECT_THROW(createSelfSigned(r), PkiError);
    r = appRequest("urn:x", 0);
    r.key = {};
    r.keyBits = 512;
    EXPECT_THROW(createSelfSigned(r), PkiError);
}

// ---------------------------------------------------------------------------------------
// Root CA -> intermediate CA -> leaf, with CRLs for both CAs.
struct Pki {
    TempDir dir;
    Identity root = createSelfSigned(caRequest("pnp test root", 1));
    Identity intermediate = createSigned(caRequest("pnp test intermediate", 2), root);
    Identity leaf = createSigned(appRequest("urn:pnp:test:leaf", 3), intermediate);
    CertificateStore store{dir.path()};

    Pki() {
        store.ensureLayout();
        store.addTrusted(root.certificate);
        store.addIssuer(intermediate.certificate);
        store.addCrl(createCrl(root, {}));
        store.addCrl(createCrl(intermediate, {}), true);
    }
};

ValidationOptions leafOptions() {
    ValidationOptions o;
    o.applicationUri = "urn:pnp:test:leaf";
    o.hostName = "robot-1.local";
    o.requireClientAuth = true;
    return o;
}

TEST(Validate, ChainThroughIssuersToATrustedRootIsGood) {
    Pki pki;
    EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, leafOptions()), StatusCode{});
    // The intermediate sent along instead of in issuers/.
    TempDir other;
    CertificateStore store(other.path());
    store.addTrusted(pki.root.certificate);
    store.addCrl(createCrl(pki.root, {}));
    store.addCrl(createCrl(pki.intermediate, {}), true);
    EXPECT_EQ(store.validate({pki.leaf.certificate, pki.intermediate.certificate}, leafOptions()),
              StatusCode{});
}

TEST(Validate, TrustedSelfSignedIsGoodUnknownIsUntrustedAndRejected) {
    TempDir dir;
    CertificateStore store(dir.path());
    store.ensureLayout();
    const Identity peer = createSelfSigned(appRequest("urn:pnp:test:peer", 4));
    ValidationOptions o;
    o.applicationUri = "urn:pnp:test:peer";
    EXPECT_EQ(store.validate({peer.certificate}, o), status::BadCertificateUntrusted);
    const fs::path rejected =
        dir.path() / "rejected" / "certs" / (peer.certificate.thumbprintHex() + ".der");
    ASSERT_TRUE(fs::exists(rejected));
    EXPECT_EQ(Certificate::load(rejected), peer.certificate);
    auto entry = store.find(peer.certificate.thumbprintHex().substr(0, 8));
    ASSERT_TRUE(entry);
    EXPECT_EQ(entry->state, TrustState::Rejected);

    store.trust(peer.certificate.thumbprintHex().substr(0, 10));
    EXPECT_FALSE(fs::exists(rejected));
    EXPECT_EQ(store.validate({peer.certificate}, o), StatusCode{});
    EXPECT_EQ(store.find(peer.certificate.thumbprintHex())->state, TrustState::Trusted);

    // Another self-signed certificate with the same name and key is not that certificate.
    const Identity twin = createSelfSigned(appRequest("urn:pnp:test:peer", 4));
    EXPECT_EQ(store.validate({twin.certificate}, o), status::BadCertificateUntrusted);

    store.reject(peer.certificate.thumbprintHex());
    EXPECT_EQ(store.validate({peer.certificate}, o), status::BadCertificateUntrusted);
    store.remove(peer.certificate.thumbprintHex());
    EXPECT_FALSE(store.find(peer.certificate.thumbprintHex()));
}

TEST(Validate, ExpiredAndNotYetValid) {
    TempDir dir;
    CertificateStore store(dir.path());
    CertificateRequest r = appRequest("urn:pnp:test:time", 4);
    r.notBefore = std::chrono::system_clock::now() - 48h;
    r.validity = 24h;
    const Identity expired = createSelfSigned(r);
    r.notBefore = std::chrono::system_clock::now() + 24h;
    const Identity future = createSelfSigned(r);
    store.addTrusted(expired.certificate);
    store.addTrusted(future.certificate);
    EXPECT_EQ(store.validate({expired.certificate}, {}), status::BadCertificateTimeInvalid);
    EXPECT_EQ(store.validate({future.certificate}, {}), status::BadCertificateTimeInvalid);
}

TEST(Validate, IssuerExpired) {
    Pki pki;
    CertificateRequest r = caRequest("expired intermediate", 5);
    r.notBefore = std::chrono::system_clock::now() - 72h;
    r.validity = 48h;
    const Identity old = createSigned(r, pki.root);
    const Identity leaf = createSigned(appRequest("urn:pnp:test:leaf", 3), old);
    pki.store.addIssuer(old.certificate);
    pki.store.addCrl(createCrl(old, {}), true);
    EXPECT_EQ(pki.store.validate({leaf.certificate}, leafOptions()),
              status::BadCertificateIssuerTimeInvalid);
}

TEST(Validate, RevokedLeafAndRevokedIssuer) {
    Pki pki;
    pki.store.addCrl(createCrl(pki.intermediate, {pki.leaf.certificate.serialHex()}), true);
    EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, leafOptions()),
              status::BadCertificateRevoked);
    pki.store.addCrl(createCrl(pki.intermediate, {}), true);  // replaces the previous CRL
    EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, leafOptions()), StatusCode{});
    pki.store.addCrl(createCrl(pki.root, {pki.intermediate.certificate.serialHex()}));
    EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, leafOptions()),
              status::BadCertificateIssuerRevoked);
}

TEST(Validate, CaWithoutCrlIsRevocationUnknown) {
    Pki pki;
    for (const auto& f : fs::directory_iterator(pki.dir.path() / "issuers" / "crl")) {
        fs::remove(f.path());
    }
    EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, leafOptions()),
              status::BadCertificateRevocationUnknown);
    pki.store.addCrl(createCrl(pki.intermediate, {}), true);
    for (const auto& f : fs::directory_iterator(pki.dir.path() / "trusted" / "crl")) {
        fs::remove(f.path());
    }
    EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, leafOptions()),
              status::BadCertificateIssuerRevocationUnknown);
}

TEST(Validate, MissingIntermediateIsChainIncomplete) {
    Pki pki;
    for (const auto& f : fs::directory_iterator(pki.dir.path() / "issuers" / "certs")) {
        fs::remove(f.path());
    }
    EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, leafOptions()),
              status::BadCertificateChainIncomplete);
    // An issuer that is not trusted (only in issuers/, root too): untrusted.
    TempDir other;
    CertificateStore store(other.path());
    store.addIssuer(pki.root.certificate);
    store.addIssuer(pki.intermediate.certificate);
    store.addCrl(createCrl(pki.root, {}), true);
    store.addCrl(createCrl(pki.intermediate, {}), true);
    EXPECT_EQ(store.validate({pki.leaf.certificate}, leafOptions()),
              status::BadCertificateUntrusted);
}

TEST(Validate, UriMustMatchExactly) {
    Pki pki;
    ValidationOptions o = leafOptions();
    o.applicationUri = "urn:pnp:test:other";
    EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, o), status::BadCertificateUriInvalid);
    // The SAN URI only contains the expected one: not a match.
    const Identity longer = createSigned(appRequest("urn:pnp:test:leaf:evil", 3), pki.intermediate);
    EXPECT_EQ(pki.store.validate({longer.certificate}, leafOptions()),
              status::BadCertificateUriInvalid);
    o.applicationUri = "urn:pnp:test:lea";
    EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, o), status::BadCertificateUriInvalid);
}

TEST(Validate, HostName) {
    Pki pki;
    ValidationOptions o = leafOptions();
    for (const char* ok : {"robot-1.local", "ROBOT-1.LOCAL", "robot-1", "127.0.0.1", "::1", "[::1]",
                           "robot-1.local."}) {
        o.hostName = ok;
        EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, o), StatusCode{}) << ok;
    }
    for (const char* bad : {"robot-2.local", "robot-1.local.evil", "10.0.0.1", "obot-1"}) {
        o.hostName = bad;
        EXPECT_EQ(pki.store.validate({pki.leaf.certificate}, o),
                  status::BadCertificateHostNameInvalid)
            << bad;
    }
}

TEST(Validate, ClientCertificateWithoutClientAuth) {
    Pki pki;
    // A certificate made by hand with extendedKeyUsage serverAuth only (OpenSSL directly).
    const Identity base = createSigned(appRequest("urn:pnp:test:leaf", 3), pki.intermediate);
    X509* copy = X509_dup(base.certificate.native());
    ASSERT_NE(copy, nullptr);
    const int at = X509_get_ext_by_NID(copy, NID_ext_key_usage, -1);
    ASSERT_GE(at, 0);
    X509_EXTENSION_free(X509_delete_ext(copy, at));
    X509V3_CTX ctx;
    X509V3_set_ctx(&ctx, pki.intermediate.certificate.native(), copy, nullptr, nullptr, 0);
    X509_EXTENSION* eku = X509V3_EXT_conf_nid(nullptr, &ctx, NID_ext_key_usage, "serverAuth");
    ASSERT_NE(eku, nullptr);
    X509_add_ext(copy, eku, -1);
    X509_EXTENSION_free(eku);
    ASSERT_GT(X509_sign(copy, pki.intermediate.key.native(), EVP_sha256()), 0);
    unsigned char* out = nullptr;
    const int n = i2d_X509(copy, &out);
    Bytes der(out, out + n);
    OPENSSL_free(out);
    X509_free(copy);
    const Certificate serverOnly = Certificate::fromDer(der);

    ValidationOptions o = leafOptions();
    EXPECT_EQ(pki.store.validate({serverOnly}, o), status::BadCertificateUseNotAllowed);
    o.requireClientAuth = false;
    o.requireServerAuth = true;
    EXPECT_EQ(pki.store.validate({serverOnly}, o), StatusCode{});
}

TEST(Validate, SmallKeyFailsThePolicyCheck) {
    TempDir dir;
    CertificateStore store(dir.path());
    CertificateRequest r = appRequest("urn:pnp:test:small", 0);
    r.key = testKey(9, 1024);
    const Identity small = createSelfSigned(r);
    EXPECT_EQ(small.certificate.keyBits(), 1024);
    store.addTrusted(small.certificate);
    EXPECT_EQ(store.validate({small.certificate}, {}), status::BadCertificatePolicyCheckFailed);
    ValidationOptions o;
    o.minKeyBits = 1024;
    EXPECT_EQ(store.validate({small.certificate}, o), StatusCode{});
}

TEST(Validate, TamperedSignatureIsInvalid) {
    Pki pki;
    Bytes der = pki.leaf.certificate.der();
    der[der.size() - 10] ^= 0x01;  // inside the signature
    EXPECT_EQ(pki.store.validate({Certificate::fromDer(der)}, leafOptions()),
              status::BadCertificateInvalid);
    // A self-signed one (trusted in its original form).
    TempDir dir;
    CertificateStore store(dir.path());
    const Identity peer = createSelfSigned(appRequest("urn:pnp:test:peer", 4));
    store.addTrusted(peer.certificate);
    Bytes bad = peer.certificate.der();
    bad[bad.size() - 10] ^= 0x01;
    EXPECT_EQ(store.validate({Certificate::fromDer(bad)}, {}), status::BadCertificateInvalid);
    EXPECT_EQ(filesIn(dir.path() / "rejected" / "certs"), 0u);  // not kept: not a certificate
}

TEST(Validate, NonCaIssuerIsIssuerUseNotAllowed) {
    Pki pki;
    // A leaf signed by an application certificate (CA:FALSE) that the trusted root issued.
    const Identity app = createSigned(appRequest("urn:pnp:test:app", 4), pki.root);
    const Identity leaf = createSigned(appRequest("urn:pnp:test:leaf", 3), app);
    pki.store.addIssuer(app.certificate);
    EXPECT_EQ(pki.store.validate({leaf.certificate}, leafOptions()),
              status::BadCertificateIssuerUseNotAllowed);
}

TEST(Store, FilesThatAreNotCertificatesAreSkipped) {
    TempDir dir;
    CertificateStore store(dir.path());
    store.ensureLayout();
    const Identity peer = createSelfSigned(appRequest("urn:pnp:test:peer", 4));
    store.addTrusted(peer.certificate);
    std::ofstream(dir.path() / "trusted" / "certs" / "junk.der") << "not a certificate";
    std::ofstream(dir.path() / "trusted" / "crl" / "junk.crl") << "not a CRL";
    Bytes truncated = peer.certificate.der();
    truncated.resize(truncated.size() / 2);
    std::ofstream(dir.path() / "trusted" / "certs" / "half.der", std::ios::binary)
        .write(reinterpret_cast<const char*>(truncated.data()),
               static_cast<std::streamsize>(truncated.size()));
    EXPECT_EQ(store.validate({peer.certificate}, {}), StatusCode{});
    ASSERT_EQ(store.list().size(), 1u);
    EXPECT_THROW(store.addCrl(crypto::view("not a CRL")), PkiError);
}

TEST(Validate, EmptyChainIsInvalid) {
    TempDir dir;
    CertificateStore store(dir.path());
    EXPECT_EQ(store.validate({}, {}), status::BadCertificateInvalid);
    EXPECT_EQ(store.validate({Certificate()}, {}), status::BadCertificateInvalid);
}

TEST(Store, RejectedIsBoundedOldestFirst) {
    TempDir dir;
    StoreConfig config;
    config.maxRejected = 3;
    CertificateStore store(dir.path(), config);
    std::vector<Certificate> certs;
    for (int i = 0; i < 5; ++i) {
        certs.push_back(
            createSelfSigned(appRequest("urn:pnp:test:r" + std::to_string(i), 4)).certificate);
        EXPECT_EQ(store.validate({certs.back()}, {}), status::BadCertificateUntrusted);
        std::this_thread::sleep_for(15ms);  // distinct modification times
    }
    const fs::path rejected = dir.path() / "rejected" / "certs";
    EXPECT_EQ(filesIn(rejected), 3u);
    for (int i = 0; i < 5; ++i) {
        EXPECT_EQ(fs::exists(rejected / (certs[i].thumbprintHex() + ".der")), i >= 2) << i;
    }
}

TEST(Store, LayoutModesAndOwnCertificate) {
    TempDir dir;
    CertificateStore store(dir.path());
    CertificateRequest r = appRequest("urn:pnp:test:own", 0);
    r.key = {};  // generated
    const Identity first = store.loadOrCreateOwn(r);
    for (const char* d : {"own/certs", "own/private", "trusted/certs", "trusted/crl",
                          "issuers/certs", "issuers/crl", "rejected/certs"}) {
        struct stat st {};
        ASSERT_EQ(::stat((dir.path() / d).c_str(), &st), 0) << d;
        EXPECT_EQ(st.st_mode & 0777, 0700u) << d;
    }
    struct stat st {};
    ASSERT_EQ(::stat((dir.path() / "own/private/pnp.pem").c_str(), &st), 0);
    EXPECT_EQ(st.st_mode & 0777, 0600u);
    EXPECT_EQ(Certificate::load(dir.path() / "own/certs/pnp.der"), first.certificate);

    // Second start: the same pair.
    CertificateStore again(dir.path());
    const Identity second = again.loadOrCreateOwn(r);
    EXPECT_EQ(second.certificate, first.certificate);
    EXPECT_EQ(EVP_PKEY_eq(second.key.native(), first.key.native()), 1);
    ASSERT_TRUE(again.ownCertificate());
    EXPECT_EQ(*again.ownCertificate(), first.certificate);

    // Another ApplicationUri: a new pair, the old one kept with a date.
    r.applicationUri = "urn:pnp:test:own2";
    const Identity third = again.loadOrCreateOwn(r);
    EXPECT_NE(third.certificate, first.certificate);
    EXPECT_EQ(third.certificate.uris(), std::vector<std::string>{"urn:pnp:test:own2"});
    EXPECT_EQ(filesIn(dir.path() / "own" / "certs"), 2u);
    // ... with the same key (a new URI is not a compromised key; no key generation).
    EXPECT_EQ(EVP_PKEY_eq(third.key.native(), first.key.native()), 1);

    // Expired: replaced.
    CertificateRequest old = r;
    old.notBefore = std::chrono::system_clock::now() - 48h;
    old.validity = 24h;
    again.setOwn(createSelfSigned(old));
    const Identity renewed = again.loadOrCreateOwn(r);
    EXPECT_GT(renewed.certificate.notAfter(), std::chrono::system_clock::now());

    // The own certificate is listed, and cannot be rejected.
    const auto entries = again.list();
    std::string listed;
    for (const auto& e : entries) listed += e.file.string() + " ";
    ASSERT_EQ(entries.size(), 1u) << listed;
    EXPECT_EQ(entries[0].state, TrustState::Own);
    EXPECT_THROW(again.reject(renewed.certificate.thumbprintHex()), PkiError);
}

TEST(Store, ApplicationsOfOneFolderTrustEachOther) {
    TempDir dir;
    CertificateStore a(dir.path()), b(dir.path());
    const Identity ida = a.loadOrCreateOwn(appRequest("urn:pnp:test:a", 0), "app-a");
    const Identity idb = b.loadOrCreateOwn(appRequest("urn:pnp:test:b", 1), "app-b");
    EXPECT_EQ(a.validate({idb.certificate}, {}), StatusCode{});
    EXPECT_EQ(b.validate({ida.certificate}, {}), StatusCode{});
    // A stranger is not trusted for sharing a name or a key with nobody.
    const Identity stranger = createSelfSigned(appRequest("urn:pnp:test:c", 2));
    EXPECT_EQ(a.validate({stranger.certificate}, {}), status::BadCertificateUntrusted);
    // Off: own/ is not a trust list.
    CertificateStore strict(dir.path(), StoreConfig{.maxRejected = 100, .trustOwn = false});
    EXPECT_EQ(strict.validate({idb.certificate}, {}), status::BadCertificateUntrusted);
}

TEST(Store, EphemeralIdentitiesShareOneKeyAndGoAwayWithTheirProcess) {
    TempDir dir;
    CertificateStore store(dir.path());
    CertificateRequest r = appRequest("urn:pnp:test:pid1", 0);
    r.key = {};
    const Identity one = store.createEphemeral(r, "device");
    r.applicationUri = "urn:pnp:test:pid2";
    const Identity two = store.createEphemeral(r, "tool");
    EXPECT_EQ(EVP_PKEY_eq(one.key.native(), two.key.native()), 1);
    EXPECT_EQ(two.certificate.uris(), std::vector<std::string>{"urn:pnp:test:pid2"});
    const fs::path file =
        dir.path() / "own" / "certs" / ("device-pid" + std::to_string(::getpid()) + ".der");
    ASSERT_TRUE(fs::exists(file));
    CertificateStore peer(dir.path());
    EXPECT_EQ(peer.validate({one.certificate}, {}), StatusCode{});
    store.removeEphemeral("device");
    EXPECT_FALSE(fs::exists(file));
    EXPECT_EQ(peer.validate({one.certificate}, {}), status::BadCertificateUntrusted);
    // The certificate of a process that ended without removing it is removed by the next one.
    const pid_t child = ::fork();
    if (child == 0) ::_exit(0);
    ASSERT_GT(child, 0);
    ::waitpid(child, nullptr, 0);
    const fs::path stale =
        dir.path() / "own" / "certs" / ("crashed-pid" + std::to_string(child) + ".der");
    fs::copy_file(dir.path() / "own" / "certs" / ("tool-pid" + std::to_string(::getpid()) + ".der"),
                  stale);
    store.createEphemeral(r, "tool");
    EXPECT_FALSE(fs::exists(stale));
    EXPECT_TRUE(fs::exists(dir.path() / "own" / "certs" /
                           ("tool-pid" + std::to_string(::getpid()) + ".der")));
}

TEST(Store, ProcessesStartingTogetherAgreeOnOneCertificate) {
    TempDir dir;
    CertificateRequest r = appRequest("urn:pnp:test:together", 0);
    r.key = {};  // generated: slow enough for the starts to overlap
    constexpr int kProcesses = 3;
    int fds[2];
    ASSERT_EQ(::pipe(fds), 0);
    std::vector<pid_t> children;
    for (int i = 0; i < kProcesses; ++i) {
        const pid_t pid = ::fork();
        if (pid == 0) {
            std::string t;
            try {
                CertificateStore store(dir.path());
                t = store.loadOrCreateOwn(r, "together").certificate.thumbprintHex();
            } catch (...) {
                t = "error";
            }
            t += "\n";
            (void)!::write(fds[1], t.data(), t.size());
            ::_exit(0);
        }
        children.push_back(pid);
    }
    ::close(fds[1]);
    for (pid_t pid : children) ::waitpid(pid, nullptr, 0);
    std::string all;
    char buf[512];
    for (ssize_t n; (n = ::read(fds[0], buf, sizeof buf)) > 0;) all.append(buf, n);
    ::close(fds[0]);
    std::set<std::string> thumbs;
    std::istringstream lines(all);
    for (std::string l; std::getline(lines, l);) thumbs.insert(l);
    ASSERT_EQ(thumbs.size(), 1u) << all;
    EXPECT_NE(*thumbs.begin(), "error");
    EXPECT_EQ(filesIn(dir.path() / "own" / "certs"), 1u);
}

TEST(Store, PrefixesMustBeLongAndUnique) {
    TempDir dir;
    CertificateStore store(dir.path());
    const Identity a = createSelfSigned(appRequest("urn:a", 0));
    store.addTrusted(a.certificate);
    EXPECT_THROW(store.find("abc"), PkiError);
    EXPECT_THROW(store.find("not-hex!"), PkiError);
    EXPECT_THROW(store.trust("00000000"), PkiError);
    EXPECT_FALSE(store.find("0000000000"));
    EXPECT_TRUE(store.find(a.certificate.thumbprintHex().substr(0, 8)));
}

TEST(Store, ChangesByAnotherProcessAreSeen) {
    TempDir dir;
    CertificateStore store(dir.path());
    store.ensureLayout();
    const Identity peer = createSelfSigned(appRequest("urn:pnp:test:peer", 4));
    EXPECT_EQ(store.validate({peer.certificate}, {}), status::BadCertificateUntrusted);
    // What `pnp pki trust` does from another process: a file appears in trusted/certs.
    CertificateStore other(dir.path());
    other.trust(peer.certificate.thumbprintHex());
    EXPECT_EQ(store.validate({peer.certificate}, {}), StatusCode{});
    fs::remove(dir.path() / "trusted" / "certs" / (peer.certificate.thumbprintHex() + ".der"));
    EXPECT_EQ(store.validate({peer.certificate}, {}), status::BadCertificateUntrusted);
}

TEST(Store, ConcurrentValidations) {
    TempDir dir;
    CertificateStore store(dir.path());
    const Identity peer = createSelfSigned(appRequest("urn:pnp:test:peer", 4));
    store.addTrusted(peer.certificate);
    std::atomic<int> good{0};
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t) {
        threads.emplace_back([&] {
            for (int i = 0; i < 50; ++i) {
                if (store.validate({peer.certificate}, {}) == StatusCode{}) ++good;
            }
        });
    }
    for (auto& t : threads) t.join();
    EXPECT_EQ(good.load(), 200);
}

// validate() runs per connection: the median of a trusted self-signed certificate.
TEST(Store, ValidateIsFast) {
    TempDir dir;
    CertificateStore store(dir.path());
    const Identity peer = createSelfSigned(appRequest("urn:pnp:test:peer", 4));
    store.addTrusted(peer.certificate);
    for (int i = 0; i < 5; ++i)
        store.addTrusted(createSelfSigned(appRequest("urn:x", 0)).certificate);
    std::this_thread::sleep_for(100ms);  // past the window in which the folder is re-read
    ValidationOptions o;
    o.applicationUri = "urn:pnp:test:peer";
    o.hostName = "127.0.0.1";
    std::vector<double> us;
    for (int i = 0; i < 400; ++i) {
        const auto t0 = std::chrono::steady_clock::now();
        const StatusCode s = store.validate({peer.certificate}, o);
        const auto t1 = std::chrono::steady_clock::now();
        ASSERT_EQ(s, StatusCode{});
        us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    }
    std::sort(us.begin(), us.end());
    const double median = us[us.size() / 2];
    std::printf("validate() of a trusted self-signed certificate: median %.1f us, p90 %.1f us\n",
                median, us[us.size() * 9 / 10]);
    RecordProperty("validate_median_us", std::to_string(median));
    EXPECT_LT(median, 2000.0);  // generous bound for a loaded CI machine
}

}  // namespace
}  // namespace pnp::ua::pki
