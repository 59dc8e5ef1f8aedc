// User identity (tokens, user store) and roles / permissions: the identity tokens checked by
// UserAccessControl directly (encrypted forms built here as a client builds them), the user
// store file, and the permissions enforced by a real server on loopback against our client.
#include "ua/server/roles.hpp"

#include <gtest/gtest.h>
#include <openssl/evp.h>
#include <openssl/x509.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>
#include <vector>

#include "support/inbox.hpp"
#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"
#include "ua/crypto/crypto.hpp"
#include "ua/server/access_control.hpp"
#include "ua/server/server.hpp"
#include "ua/server/user_store.hpp"
#include "ua/types/binary.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp::ua;
using namespace std::chrono_literals;
using pnp::testing::errorOf;
using pnp::testing::url;
namespace crypto = pnp::ua::crypto;

namespace {

constexpr unsigned kFastIterations = server::UserStore::kMinIterations;
const char* kBasic256Sha256 = "http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256";

std::shared_ptr<server::UserStore> testUsers() {
    auto s = std::make_shared<server::UserStore>();
    s->addUser("observer", "watch", {server::role::observer()}, kFastIterations);
    s->addUser("operator", "secret", {server::role::operator_()}, kFastIterations);
    s->addUser("admin", "keys", {server::role::securityAdmin()}, kFastIterations);
    return s;
}

// A self-signed certificate for `key` (DER), made with OpenSSL.
crypto::Bytes selfSigned(const crypto::PrivateKey& key, const char* cn) {
    std::unique_ptr<X509, decltype(&X509_free)> x(X509_new(), X509_free);
    X509_set_version(x.get(), 2);
    ASN1_INTEGER_set(X509_get_serialNumber(x.get()), 1);
    X509_gmtime_adj(X509_getm_notBefore(x.get()), -3600);
    X509_gmtime_adj(X509_getm_notAfter(x.get()), 3600L * 24);
    X509_set_pubkey(x.get(), key.native());
    X509_NAME* name = X509_get_subject_name(x.get());
    X509_NAME_add_entry_by_txt(name, "CN", MBSTRING_ASC, reinterpret_cast<const unsigned char*>(cn),
                               -1, -1, 0);
    X509_set_issuer_name(x.get(), name);
    X509_sign(x.get(), key.native(), EVP_sha256());
    unsigned char* der = nullptr;
    int n = i2d_X509(x.get(), &der);
    crypto::Bytes out(der, der + n);
    OPENSSL_free(der);
    return out;
}

ByteString toByteString(const crypto::Bytes& b) {
    return ByteString(std::string(b.begin(), b.end()));
}

// What a server has for ActivateSession: key, certificate, the last nonce.
struct ServerSide {
    crypto::PrivateKey key = crypto::PrivateKey::generateRsa(2048);
    crypto::Bytes certificate = selfSigned(key, "server");
    crypto::Bytes nonce = crypto::randomBytes(32);
    server::ActivationContext context(MessageSecurityMode mode = MessageSecurityMode::None,
                                      const SignatureData* sig = nullptr) const {
        server::ActivationContext c;
        c.channelPolicyUri = crypto::kNoneUri;
        c.channelMode = mode;
        c.serverKey = &key;
        c.serverCertificate = certificate;
        c.serverNonce = nonce;
        c.userTokenSignature = sig;
        return c;
    }
};

ExtensionObject userToken(std::string policyId, std::string user, ByteString password,
                          std::string algorithm = {}) {
    UserNameIdentityToken t;
    t.policyId = String(std::move(policyId));
    t.userName = String(std::move(user));
    t.password = std::move(password);
    t.encryptionAlgorithm = String(std::move(algorithm));
    return toExtensionObject(t);
}

// The legacy encrypted password (OPC 10000-4 §7.41.2.2) as a client builds it.
ByteString legacySecret(const ServerSide& s, std::string_view password, crypto::ByteView nonce) {
    const auto* policy = crypto::findPolicy(kBasic256Sha256);
    crypto::Bytes plain;
    const auto length = static_cast<UInt32>(password.size() + nonce.size());
    for (int k = 0; k < 4; ++k) plain.push_back(static_cast<std::uint8_t>(length >> (8 * k)));
    plain.insert(plain.end(), password.begin(), password.end());
    plain.insert(plain.end(), nonce.begin(), nonce.end());
    return toByteString(
        crypto::encrypt(s.key.publicKey(), policy->asymmetricEncryption, crypto::ByteView(plain)));
}

// The RsaEncryptedSecret (OPC 10000-4 §7.41.2.3/.4) as a client builds it.
ByteString encryptedSecret(const ServerSide& s, std::string_view password, bool tamper = false) {
    const auto* policy = crypto::findPolicy(kBasic256Sha256);
    const auto signingKey = crypto::randomBytes(policy->signingKeyLength);
    const auto encryptingKey = crypto::randomBytes(policy->encryptingKeyLength);
    const auto iv = crypto::randomBytes(policy->blockSize);
    Buffer keyData;
    {
        BinaryEncoder e(keyData);
        encode(e, toByteString(signingKey));
        encode(e, toByteString(encryptingKey));
        encode(e, toByteString(iv));
    }
    const auto encryptedKeys = crypto::encrypt(s.key.publicKey(), policy->asymmetricEncryption,
                                               crypto::ByteView(keyData.data(), keyData.size()));
    Buffer payload;
    {
        BinaryEncoder e(payload);
        encode(e, toByteString(s.nonce));
        encode(e, ByteString(std::string(password)));
        const std::size_t dataLength = payload.size() + 2;
        std::size_t padding = dataLength % 16 == 0 ? 0 : 16 - dataLength % 16;
        if (padding + password.size() < 16) padding += 16;
        for (std::size_t k = 0; k < padding; ++k) payload.push_back(static_cast<Byte>(padding));
        encode(e, static_cast<UInt16>(padding));
    }
    crypto::SymmetricCipher cipher(*policy, crypto::SymmetricKeys{signingKey, encryptingKey, iv});
    cipher.encrypt(std::span<std::uint8_t>(payload.data(), payload.size()));
    Buffer out;
    BinaryEncoder e(out);
    encode(e, NodeId(0, 17545));
    encode(e, Byte{1});
    const std::size_t lengthAt = out.size();
    encode(e, UInt32{0});
    encode(e, String(kBasic256Sha256));
    encode(e, toByteString(crypto::sha1(s.certificate)));
    encode(e, DateTime::now());
    encode(e, static_cast<UInt16>(encryptedKeys.size()));
    out.insert(out.end(), encryptedKeys.begin(), encryptedKeys.end());
    out.insert(out.end(), payload.begin(), payload.end());
    const auto length = static_cast<UInt32>(out.size() - lengthAt - 4 + cipher.signatureSize());
    for (int k = 0; k < 4; ++k) out[lengthAt + k] = static_cast<Byte>(length >> (8 * k));
    std::vector<std::uint8_t> sig(cipher.signatureSize());
    cipher.sign(crypto::ByteView(out.data(), out.size()), sig.data());
    out.insert(out.end(), sig.begin(), sig.end());
    if (tamper) out[out.size() - 40] ^= 1;  // a payload byte
    return ByteString(std::string(out.begin(), out.end()));
}

server::UserAccessControl accessControl(bool anonymous = true) {
    server::UserAccessConfig c;
    c.allowAnonymous = anonymous;
    c.users = testUsers();
    return server::UserAccessControl(c);
}

}  // namespace

// ---- identity tokens ----------------------------------------------------------------------------
TEST(IdentityTokens, AnonymousCanBeTurnedOff) {
    ServerSide s;
    server::SessionIdentity id;
    auto on = accessControl(true);
    EXPECT_EQ(on.activateSession(ExtensionObject(), s.context(), id), status::Good);
    EXPECT_TRUE(id.anonymous);
    EXPECT_TRUE(id.hasRole(server::role::anonymous()));
    EXPECT_FALSE(id.hasRole(server::role::authenticatedUser()));
    auto off = accessControl(false);
    EXPECT_EQ(off.activateSession(toExtensionObject(AnonymousIdentityToken{}), s.context(), id),
              status::BadIdentityTokenRejected);
    for (const auto& p : off.userTokenPolicies(crypto::kNoneUri, MessageSecurityMode::None))
        EXPECT_NE(p.tokenType, UserTokenType::Anonymous);
}

TEST(IdentityTokens, PlainPasswordOnlyInsideEncryptionOrWhenAllowed) {
    ServerSide s;
    auto ac = accessControl();
    server::SessionIdentity id;
    auto token = userToken("username", "operator", ByteString("secret"));
    EXPECT_EQ(ac.activateSession(token, s.context(MessageSecurityMode::None), id),
              status::BadIdentityTokenRejected);
    EXPECT_EQ(ac.activateSession(token, s.context(MessageSecurityMode::SignAndEncrypt), id),
              status::Good);
    EXPECT_FALSE(id.anonymous);
    EXPECT_EQ(id.userName, "operator");
    EXPECT_TRUE(id.hasRole(server::role::operator_()));
    EXPECT_TRUE(id.hasRole(server::role::authenticatedUser()));
    EXPECT_TRUE(id.hasRole(server::role::anonymous()));
}

TEST(IdentityTokens, WrongPasswordAndUnknownUserLookTheSame) {
    ServerSide s;
    auto ac = accessControl();
    server::SessionIdentity id;
    const auto ctx = s.context(MessageSecurityMode::SignAndEncrypt);
    // Interleaved, each call timed, medians compared: a machine busy with other work slows
    // both alike instead of whichever ran second.
    auto timeOf = [&](const char* user, const char* password, StatusCode& st) {
        const auto begin = std::chrono::steady_clock::now();
        st = ac.activateSession(userToken("username", user, ByteString(password)), ctx, id);
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count();
    };
    StatusCode wrong, unknown;
    std::vector<double> tWrong, tUnknown;
    for (int k = 0; k < 21; ++k) {
        tWrong.push_back(timeOf("operator", "nope", wrong));
        tUnknown.push_back(timeOf("nobody", "secret", unknown));
    }
    auto median = [](std::vector<double> v) {
        std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
        return v[v.size() / 2];
    };
    EXPECT_EQ(wrong, status::BadUserAccessDenied);
    EXPECT_EQ(unknown, status::BadUserAccessDenied);
    // Both compute one PBKDF2 hash: no difference of the order of a hash.
    const double ratio = median(tWrong) / median(tUnknown);
    EXPECT_GT(ratio, 0.5);
    EXPECT_LT(ratio, 2.0);
}

TEST(IdentityTokens, LegacyEncryptedPassword) {
    ServerSide s;
    auto ac = accessControl();
    const auto* policy = crypto::findPolicy(kBasic256Sha256);
    const std::string alg(policy->asymmetricEncryptionUri);
    server::SessionIdentity id;
    EXPECT_EQ(ac.activateSession(userToken("username_basic256sha256", "operator",
                                           legacySecret(s, "secret", s.nonce), alg),
                                 s.context(), id),
              status::Good);
    EXPECT_EQ(id.userName, "operator");
    // Another nonce (a replayed token): invalid.
    const auto other = crypto::randomBytes(32);
    EXPECT_EQ(ac.activateSession(userToken("username_basic256sha256", "operator",
                                           legacySecret(s, "secret", other), alg),
                                 s.context(), id),
              status::BadIdentityTokenInvalid);
    // The algorithm must be the policy's.
    EXPECT_EQ(ac.activateSession(userToken("username_basic256sha256", "operator",
                                           legacySecret(s, "secret", s.nonce),
                                           "http://www.w3.org/2001/04/xmlenc#rsa-1_5"),
                                 s.context(), id),
              status::BadIdentityTokenInvalid);
    // Right encryption, wrong password: access denied like a plain one.
    EXPECT_EQ(ac.activateSession(userToken("username_basic256sha256", "operator",
                                           legacySecret(s, "wrong", s.nonce), alg),
                                 s.context(), id),
              status::BadUserAccessDenied);
}

TEST(IdentityTokens, EncryptedSecretPassword) {
    ServerSide s;
    auto ac = accessControl();
    const std::string alg(crypto::findPolicy(kBasic256Sha256)->asymmetricEncryptionUri);
    server::SessionIdentity id;
    EXPECT_EQ(ac.activateSession(userToken("username_basic256sha256", "operator",
                                           encryptedSecret(s, "secret"), alg),
                                 s.context(), id),
              status::Good);
    EXPECT_EQ(id.userName, "operator");
    EXPECT_EQ(ac.activateSession(userToken("username_basic256sha256", "operator",
                                           encryptedSecret(s, "secret", true), alg),
                                 s.context(), id),
              status::BadIdentityTokenInvalid);
}

TEST(IdentityTokens, X509UserTokenSignature) {
    ServerSide s;
    const auto userKey = crypto::PrivateKey::generateRsa(2048);
    const auto userCert = selfSigned(userKey, "robot operator");
    auto store = testUsers();
    store->addCertificateUser("certop",
                              [&] {
                                  std::string hex;
                                  for (auto b : crypto::sha1(userCert)) {
                                      static const char* d = "0123456789abcdef";
                                      hex += d[b >> 4];
                                      hex += d[b & 15];
                                  }
                                  return hex;
                              }(),
                              {server::role::operator_()});
    server::UserAccessConfig c;
    c.users = store;
    int validated = 0;
    c.validateUserCertificate = [&](const ByteString&) {
        ++validated;
        return StatusCode(status::Good);
    };
    server::UserAccessControl ac(c);
    const auto* policy = crypto::findPolicy(kBasic256Sha256);
    X509IdentityToken t;
    t.policyId = "x509_basic256sha256";
    t.certificateData = toByteString(userCert);
    crypto::Bytes signedData = s.certificate;
    signedData.insert(signedData.end(), s.nonce.begin(), s.nonce.end());
    SignatureData sig;
    sig.algorithm = String(policy->asymmetricSignatureUri);
    sig.signature = toByteString(
        crypto::sign(userKey, policy->asymmetricSignature, crypto::ByteView(signedData)));
    server::SessionIdentity id;
    EXPECT_EQ(
        ac.activateSession(toExtensionObject(t), s.context(MessageSecurityMode::None, &sig), id),
        status::Good);
    EXPECT_EQ(id.userName, "certop");
    EXPECT_TRUE(id.hasRole(server::role::operator_()));
    EXPECT_EQ(validated, 1);
    // Signed by another key: refused.
    SignatureData wrong = sig;
    wrong.signature = toByteString(
        crypto::sign(s.key, policy->asymmetricSignature, crypto::ByteView(signedData)));
    EXPECT_EQ(
        ac.activateSession(toExtensionObject(t), s.context(MessageSecurityMode::None, &wrong), id),
        status::BadUserSignatureInvalid);
    // A certificate the validator refuses.
    c.validateUserCertificate = [](const ByteString&) {
        return StatusCode(status::BadCertificateUntrusted);
    };
    server::UserAccessControl strict(c);
    EXPECT_EQ(strict.activateSession(toExtensionObject(t),
                                     s.context(MessageSecurityMode::None, &sig), id),
              status::BadIdentityTokenRejected);
}

TEST(IdentityTokens, PoliciesPerEndpoint) {
    server::UserAccessConfig c;
    c.users = testUsers();
    c.validateUserCertificate = [](const ByteString&) { return StatusCode(status::Good); };
    server::UserAccessControl ac(c);
    auto ids = [](const std::vector<UserTokenPolicy>& ps) {
        std::vector<std::string> out;
        for (const auto& p : ps) out.push_back(p.policyId + "|" + p.securityPolicyUri);
        return out;
    };
    // None endpoint: secrets not offered by default.
    EXPECT_EQ(ids(ac.userTokenPolicies(crypto::kNoneUri, MessageSecurityMode::None)),
              std::vector<std::string>{"anonymous|"});
    EXPECT_EQ(ids(ac.userTokenPolicies(kBasic256Sha256, MessageSecurityMode::SignAndEncrypt)),
              (std::vector<std::string>{"anonymous|", "username_basic256sha256|",
                                        "x509_basic256sha256|"}));
    EXPECT_EQ(ids(ac.userTokenPolicies(kBasic256Sha256, MessageSecurityMode::Sign)),
              (std::vector<std::string>{"anonymous|",
                                        std::string("username_basic256sha256|") + kBasic256Sha256,
                                        std::string("x509_basic256sha256|") + kBasic256Sha256}));
    c.offerSecretTokensOnNone = true;
    server::UserAccessControl onNone(c);
    EXPECT_EQ(ids(onNone.userTokenPolicies(crypto::kNoneUri, MessageSecurityMode::None)),
              (std::vector<std::string>{"anonymous|",
                                        std::string("username_basic256sha256|") + kBasic256Sha256,
                                        std::string("x509_basic256sha256|") + kBasic256Sha256}));
}

// ---- the user store
// ------------------------------------------------------------------------------
TEST(UserStore, FileRoundTripWithMode0600) {
    const auto dir =
        std::filesystem::temp_directory_path() / ("pnp-users-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    const std::string file = (dir / "sub" / "users").string();
    server::UserStore s;
    s.addUser("alice", "pw1", {server::role::operator_(), server::role::engineer()},
              kFastIterations);
    s.addCertificateUser("robot", std::string(40, 'a'), {server::role::observer()});
    s.save(file);
    struct stat st {};
    ASSERT_EQ(::stat(file.c_str(), &st), 0);
    EXPECT_EQ(st.st_mode & 0777, 0600u);
    std::ifstream in(file);
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(text.find("pw1"), std::string::npos) << "no plain password in the file";
    auto loaded = server::UserStore::load(file);
    ASSERT_EQ(loaded.users().size(), 2u);
    EXPECT_EQ(loaded.users()[0].roles,
              (std::vector<NodeId>{server::role::operator_(), server::role::engineer()}));
    EXPECT_NE(loaded.verifyPassword("alice", "pw1"), nullptr);
    EXPECT_EQ(loaded.verifyPassword("alice", "pw2"), nullptr);
    EXPECT_EQ(loaded.verifyPassword("robot", ""), nullptr);
    EXPECT_NE(loaded.findByThumbprint(std::string(40, 'a')), nullptr);
    std::filesystem::remove_all(dir);
}

TEST(UserStore, BadLineNamesFileAndLine) {
    server::UserStore ok;
    ok.addUser("alice", "pw", {}, kFastIterations);
    std::string text = ok.serialize() + "\n# comment\nbob:Operator:pbkdf2-sha256:1000:AAAA:BBBB\n";
    try {
        server::UserStore::parse(text, "users.txt");
        FAIL() << "accepted a bad salt";
    } catch (const server::UserStoreError& e) {
        EXPECT_EQ(std::string(e.what()).rfind("users.txt:5: ", 0), 0u) << e.what();
    }
    EXPECT_THROW(server::UserStore::parse("carl:Boss:x509-sha1:" + std::string(40, 'b'), "f"),
                 server::UserStoreError);  // unknown role
    EXPECT_THROW(server::UserStore::parse("a b:Operator:x509-sha1:" + std::string(40, 'b'), "f"),
                 server::UserStoreError);  // bad name
}

// ---- permissions on a real server --------------------------------------------------------------
namespace {

// A server with the pnp role policy: a skill-like object in ns 2 with a parameter and a
// method, a hidden node, and an event notifier without ReceiveEvents for Observer.
struct RoleServer {
    server::Server server;
    UInt16 ns = 0;
    NodeId skill, parameter, start, hidden, quiet;

    static server::ServerConfig config() {
        auto c = pnp::testing::loopbackConfig();
        server::UserAccessConfig a;
        a.users = testUsers();
        a.allowUnencryptedPasswords = true;  // loopback None channel in this test
        c.accessControl = std::make_shared<server::UserAccessControl>(a);
        return c;
    }

    RoleServer() : server(config()) {
        auto& as = server.addressSpace();
        ns = server.addNamespace("urn:pnp:test:roles");
        skill = as.addObject(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Skill"),
                             QualifiedName{ns, "Skill"});
        server::VariableAttributes v;
        v.dataType = NodeId(0, ns0::Int32);
        v.value = DataValue(Variant(Int32{1}));
        v.accessLevel = server::access_level::CurrentRead | server::access_level::CurrentWrite;
        parameter = as.addVariable(skill, NodeId(ns, "Speed"), QualifiedName{ns, "Speed"}, v);
        start = as.addMethod(skill, NodeId(ns, "Start"), QualifiedName{ns, "Start"}, {}, {},
                             [](const server::MethodCallContext&, std::vector<Variant>,
                                server::MethodCompletion d) { d.succeed({}); });
        hidden = as.addVariable(skill, NodeId(ns, "Hidden"), QualifiedName{ns, "Hidden"}, v);
        server::ObjectAttributes quietAttributes;
        quietAttributes.eventNotifier = 1;
        quiet = as.addObject(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Quiet"),
                             QualifiedName{ns, "Quiet"}, quietAttributes);
        as.applyPermissions(server::pnpRolePolicy());
        // Hidden: only Operator may see it. Quiet: Operator receives its events, no one else.
        using namespace server::permission;
        as.setRolePermissions(
            hidden, std::vector<RolePermissionType>{{server::role::operator_(), Browse | Read}});
        as.setRolePermissions(quiet, std::vector<RolePermissionType>{
                                         {server::role::anonymous(), Browse | Read},
                                         {server::role::operator_(), Browse | ReceiveEvents}});
        server.start();
    }
};

bool hasReference(const std::vector<ReferenceDescription>& refs, const NodeId& id) {
    for (const auto& r : refs)
        if (r.nodeId.nodeId == id) return true;
    return false;
}

}  // namespace

TEST(RolePermissions, DefaultAllowsEverything) {
    server::Server s(pnp::testing::loopbackConfig());
    EXPECT_FALSE(s.addressSpace().enforcesPermissions());
    server::SessionIdentity nobody;  // no role at all
    EXPECT_EQ(s.addressSpace().userPermissions(NodeId(0, ns0::Server), nobody),
              server::permission::All);
}

TEST(RolePermissions, ObserverCannotWriteOrCallOperatorCan) {
    RoleServer f;
    client::Client observer, op;
    observer.connect(url(f.server), client::UserName{"observer", "watch"});
    op.connect(url(f.server), client::UserName{"operator", "secret"});

    EXPECT_EQ(*observer.readValue(f.parameter).scalar<Int32>(), 1);
    EXPECT_EQ(observer.writeValue(f.parameter, Int32(5)), status::BadUserAccessDenied);
    EXPECT_EQ(observer.call(f.skill, f.start, {}).status, status::BadUserAccessDenied);
    EXPECT_EQ(op.writeValue(f.parameter, Int32(5)), status::Good);
    EXPECT_EQ(op.call(f.skill, f.start, {}).status, status::Good);
    // Configuration (other attributes) is the Engineer's: the Operator may not.
    WriteValue dn;
    dn.nodeId = f.parameter;
    dn.attributeId = static_cast<UInt32>(AttributeId::DisplayName);
    dn.value = DataValue(Variant(LocalizedText("", "fast")));
    EXPECT_EQ(op.write({dn}).at(0), status::BadUserAccessDenied);

    // The User* attributes follow the session.
    auto level = [](client::Client& c, const NodeId& n) {
        return *c.readAttribute(n, AttributeId::UserAccessLevel).value->scalar<Byte>();
    };
    EXPECT_EQ(level(observer, f.parameter), server::access_level::CurrentRead);
    EXPECT_EQ(level(op, f.parameter),
              server::access_level::CurrentRead | server::access_level::CurrentWrite);
    auto executable = [](client::Client& c, const NodeId& n) {
        return *c.readAttribute(n, AttributeId::UserExecutable).value->scalar<Boolean>();
    };
    EXPECT_FALSE(executable(observer, f.start));
    EXPECT_TRUE(executable(op, f.start));
    // UserRolePermissions: the entries of the session's roles only.
    auto urp = op.readAttribute(f.parameter, AttributeId::UserRolePermissions);
    ASSERT_TRUE(urp.value);
    const auto* list = urp.value->array<ExtensionObject>();
    ASSERT_NE(list, nullptr);
    EXPECT_EQ(list->size(), 3u);  // Anonymous, AuthenticatedUser, Operator
}

TEST(RolePermissions, BrowseHidesNodesWithoutBrowsePermission) {
    RoleServer f;
    client::Client observer, op;
    observer.connect(url(f.server), client::UserName{"observer", "watch"});
    op.connect(url(f.server), client::UserName{"operator", "secret"});
    EXPECT_FALSE(hasReference(observer.browse(f.skill), f.hidden));
    EXPECT_TRUE(hasReference(observer.browse(f.skill), f.parameter));
    EXPECT_TRUE(hasReference(op.browse(f.skill), f.hidden));
    BrowseDescription d;
    d.nodeId = f.hidden;
    d.browseDirection = BrowseDirection::Both;
    EXPECT_EQ(observer.browse(d).statusCode, status::BadNodeIdUnknown);
    EXPECT_EQ(observer.readAttribute(f.hidden, AttributeId::Value).statusOrGood(),
              status::BadUserAccessDenied);
    // TranslateBrowsePaths does not find it either.
    BrowsePath path;
    path.startingNode = f.skill;
    RelativePathElement e;
    e.referenceTypeId = NodeId(0, ns0::HierarchicalReferences);
    e.includeSubtypes = true;
    e.targetName = QualifiedName{f.ns, "Hidden"};
    path.relativePath.elements.push_back(e);
    TranslateBrowsePathsToNodeIdsRequest tr;
    tr.browsePaths.push_back(path);
    EXPECT_EQ(observer.request(tr).results.at(0).statusCode, status::BadNoMatch);
    EXPECT_EQ(op.request(tr).results.at(0).statusCode, status::Good);
}

TEST(RolePermissions, EventsOnlyWithReceiveEvents) {
    RoleServer f;
    client::Client observer, op;
    observer.connect(url(f.server), client::UserName{"observer", "watch"});
    op.connect(url(f.server), client::UserName{"operator", "secret"});
    observer.startBackgroundThread();
    op.startBackgroundThread();
    pnp::testing::Inbox<int> seenByObserver, seenByOperator;
    client::Subscription so(observer, {.publishingInterval = 10});
    client::Subscription sp(op, {.publishingInterval = 10});
    auto io = so.monitorEvents(f.quiet, {.select = {"Message"}},
                               [&](client::EventFields&) { seenByObserver.put(1); });
    auto ip = sp.monitorEvents(f.quiet, {.select = {"Message"}},
                               [&](client::EventFields&) { seenByOperator.put(1); });
    server::Event ev;
    ev.sourceNode = f.quiet;
    ev.message = LocalizedText("", "tool changed");
    f.server.fireEvent(ev);
    EXPECT_TRUE(seenByOperator.waitFor([](auto& v) { return !v.empty(); }));
    std::this_thread::sleep_for(200ms);  // several publishing intervals
    EXPECT_TRUE(seenByObserver.items().empty());
}

TEST(RolePermissions, SecurityAdminNeedsAnEncryptedChannel) {
    RoleServer f;
    auto& as = f.server.addressSpace();
    server::SessionIdentity admin;
    admin.anonymous = false;
    admin.grant(server::role::anonymous());
    admin.grant(server::role::authenticatedUser());
    admin.grant(server::role::securityAdmin());
    const NodeId update(0, ns0::ServerConfiguration_UpdateCertificate);
    EXPECT_EQ(as.userPermissions(update, admin) & server::permission::Call, 0u);
    admin.encryptedChannel = true;
    EXPECT_NE(as.userPermissions(update, admin) & server::permission::Call, 0u);

    // Over our (None) channel the server refuses the call before the method runs.
    client::Client c;
    c.connect(url(f.server), client::UserName{"admin", "keys"});
    auto r = c.call(NodeId(0, ns0::ServerConfiguration), update, {});
    EXPECT_EQ(r.status, status::BadUserAccessDenied);
}

// A password's salted hash takes long by design; it runs off the network thread, so other
// clients are served meanwhile and the login still completes.
TEST(IdentityTokens, APasswordCheckDoesNotHoldUpOtherClients) {
    auto c = pnp::testing::loopbackConfig();
    auto users = std::make_shared<server::UserStore>();
    users->addUser("slow", "pw", {server::role::operator_()}, 2'000'000);  // ~0.5 s of hashing
    server::UserAccessConfig a;
    a.users = users;
    a.allowUnencryptedPasswords = true;  // loopback None channel in this test
    c.accessControl = std::make_shared<server::UserAccessControl>(a);
    server::Server s(c);
    s.start();
    client::Client reader;
    reader.connect(s.endpointUrl());
    std::atomic<bool> loggedIn{false};
    std::thread login([&] {
        client::Client slow;
        slow.connect(s.endpointUrl(), client::UserName{"slow", "pw"},
                     std::chrono::milliseconds(20'000));
        loggedIn = true;
    });
    // Reads while the hash runs: none waits for it.
    double worstMs = 0;
    int reads = 0;
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (!loggedIn && std::chrono::steady_clock::now() < until) {
        const auto t0 = std::chrono::steady_clock::now();
        reader.readValue(NodeId(0, ns0::Server_ServerStatus_State));
        worstMs = std::max(worstMs, std::chrono::duration<double, std::milli>(
                                        std::chrono::steady_clock::now() - t0)
                                        .count());
        ++reads;
    }
    login.join();
    EXPECT_TRUE(loggedIn);
    EXPECT_GT(reads, 10);
    EXPECT_LT(worstMs, 100.0) << reads << " reads during the login";
}
