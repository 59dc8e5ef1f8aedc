#include "ua/server/access_control.hpp"

#include <openssl/evp.h>
#include <openssl/x509.h>

#include <algorithm>
#include <cctype>
#include <cstring>

#include "ua/types/binary.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {

namespace {
constexpr std::string_view kAnonymousPolicyId = "anonymous";
constexpr std::string_view kPlainUserNamePolicyId = "username";
constexpr std::string_view kUserNamePrefix = "username_";
constexpr std::string_view kX509Prefix = "x509_";
constexpr UInt32 kRsaEncryptedSecretType = 17545;  // the RsaEncryptedSecret DataType
constexpr std::size_t kMaxSecretTokenSize = 16 * 1024;
constexpr std::size_t kMaxCertificateSize = 32 * 1024;

bool isNone(std::string_view uri) { return uri.empty() || uri == crypto::kNoneUri; }

crypto::ByteView bytes(const ByteString& b) { return {b.data(), b.size()}; }

std::string toHex(const crypto::Bytes& b) {
    static const char* digits = "0123456789abcdef";
    std::string s;
    for (auto c : b) {
        s += digits[c >> 4];
        s += digits[c & 15];
    }
    return s;
}

// The security policy a token policy id names ("username_basic256sha256" -> Basic256Sha256).
const crypto::SecurityPolicy* policyOfTokenId(std::string_view id, std::string_view prefix) {
    if (!id.starts_with(prefix)) return nullptr;
    id.remove_prefix(prefix.size());
    for (const auto& p : crypto::securityPolicies())
        if (tokenPolicySuffix(p.uri) == id) return &p;
    return nullptr;
}

// The password of a legacy encrypted token (OPC 10000-4 §7.41.2.2): RSA-OAEP of
// UInt32 length | password | serverNonce. nullopt: invalid (whatever was wrong).
std::optional<std::string> legacyPassword(const crypto::SecurityPolicy& policy,
                                          const crypto::PrivateKey& key, const ByteString& data,
                                          crypto::ByteView serverNonce) {
    auto plain = crypto::decrypt(key, policy.asymmetricEncryption, bytes(data));
    if (!plain || plain->size() < 4) return std::nullopt;
    UInt32 length = 0;
    for (int k = 3; k >= 0; --k) length = (length << 8) | (*plain)[static_cast<std::size_t>(k)];
    if (length != plain->size() - 4 || length < serverNonce.size()) return std::nullopt;
    const std::size_t passwordSize = length - serverNonce.size();
    crypto::ByteView nonce(plain->data() + 4 + passwordSize, serverNonce.size());
    if (!crypto::constantTimeEqual(nonce, serverNonce)) return std::nullopt;
    return std::string(reinterpret_cast<const char*>(plain->data() + 4), passwordSize);
}

bool looksLikeEncryptedSecret(const ByteString& data) {
    // TypeId ns=0;i=17545 in the four-byte NodeId encoding, then EncodingMask 1.
    const Byte* p = data.data();
    return data.size() > 9 && p[0] == 0x01 && p[1] == 0 &&
           p[2] == (kRsaEncryptedSecretType & 0xFF) && p[3] == (kRsaEncryptedSecretType >> 8) &&
           p[4] == 0x01;
}

// The secret of an RsaEncryptedSecret (OPC 10000-4 §7.41.2.3/.4): common header, KeyData
// (SigningKey, EncryptingKey, InitializationVector) RSA-encrypted for the server, payload
// (Nonce, Secret, padding, PaddingSize) AES-CBC encrypted, HMAC-SHA256 over all before it.
std::optional<std::string> encryptedSecretPassword(const crypto::SecurityPolicy& policy,
                                                   const crypto::PrivateKey& key,
                                                   const ByteString& data,
                                                   crypto::ByteView serverCertificate,
                                                   crypto::ByteView serverNonce) {
    if (data.size() > kMaxSecretTokenSize) return std::nullopt;
    try {
        DecodeLimits limits;
        limits.maxStringLength = kMaxSecretTokenSize;
        BinaryDecoder d(data.data(), data.size(), limits);
        NodeId typeId;
        decode(d, typeId);
        if (typeId != NodeId(0, kRsaEncryptedSecretType) || d.byte() != 0x01) return std::nullopt;
        const UInt32 length = d.number<UInt32>();
        if (length != d.remaining()) return std::nullopt;
        String policyUri;
        decode(d, policyUri);
        if (policyUri != policy.uri) return std::nullopt;
        ByteString thumbprint;
        decode(d, thumbprint);
        const auto expected = crypto::sha1(serverCertificate);
        if (!crypto::constantTimeEqual(bytes(thumbprint), expected)) return std::nullopt;
        DateTime signingTime;
        decode(d, signingTime);
        const std::size_t keyDataLength = d.number<UInt16>();
        if (keyDataLength == 0 || keyDataLength > d.remaining()) return std::nullopt;
        const Byte* keyData = d.position();
        d.skip(keyDataLength);
        const std::size_t signatureSize = policy.signatureSize;
        if (d.remaining() < signatureSize) return std::nullopt;
        const std::size_t payloadSize = d.remaining() - signatureSize;
        if (payloadSize == 0 || payloadSize % policy.blockSize != 0) return std::nullopt;
        const Byte* payload = d.position();

        auto keys = crypto::decrypt(key, policy.asymmetricEncryption, {keyData, keyDataLength});
        if (!keys) return std::nullopt;
        BinaryDecoder kd(keys->data(), keys->size(), limits);
        ByteString signingKey, encryptingKey, iv;
        decode(kd, signingKey);
        decode(kd, encryptingKey);
        decode(kd, iv);
        if (kd.remaining() != 0 || signingKey.size() != policy.signingKeyLength ||
            encryptingKey.size() != policy.encryptingKeyLength || iv.size() != policy.blockSize)
            return std::nullopt;
        crypto::SymmetricCipher cipher(
            policy, crypto::SymmetricKeys{{signingKey.begin(), signingKey.end()},
                                          {encryptingKey.begin(), encryptingKey.end()},
                                          {iv.begin(), iv.end()}});
        const std::size_t signedSize = data.size() - signatureSize;
        if (!cipher.verify({data.data(), signedSize}, {data.data() + signedSize, signatureSize}))
            return std::nullopt;
        std::vector<std::uint8_t> plain(payload, payload + payloadSize);
        cipher.decrypt(plain);
        // Nonce, Secret, PayloadPadding (each byte = low byte of its size), PayloadPaddingSize.
        const std::size_t paddingSize = plain[plain.size() - 2] | (plain[plain.size() - 1] << 8);
        if (paddingSize + 2 > plain.size()) return std::nullopt;
        const std::size_t bodySize = plain.size() - 2 - paddingSize;
        for (std::size_t k = bodySize; k < bodySize + paddingSize; ++k)
            if (plain[k] != static_cast<std::uint8_t>(paddingSize & 0xFF)) return std::nullopt;
        BinaryDecoder pd(plain.data(), bodySize, limits);
        ByteString nonce, secret;
        decode(pd, nonce);
        decode(pd, secret);
        if (pd.remaining() != 0) return std::nullopt;
        if (!crypto::constantTimeEqual(bytes(nonce), serverNonce)) return std::nullopt;
        return secret.str();
    } catch (const DecodeError&) {
        return std::nullopt;
    } catch (const crypto::CryptoError&) {
        return std::nullopt;
    }
}

struct UserCertificate {
    crypto::PublicKey key;
    std::string subject;
};

// The public key and subject of a DER certificate (the leaf of a chain); nullopt if it does
// not parse.
std::optional<UserCertificate> parseCertificate(const ByteString& der) {
    if (der.empty() || der.size() > kMaxCertificateSize) return std::nullopt;
    const unsigned char* p = der.data();
    X509* raw = d2i_X509(nullptr, &p, static_cast<long>(der.size()));
    if (raw == nullptr) return std::nullopt;
    std::unique_ptr<X509, decltype(&X509_free)> cert(raw, X509_free);
    EVP_PKEY* key = X509_get_pubkey(cert.get());
    if (key == nullptr) return std::nullopt;
    UserCertificate out;
    out.key = crypto::PublicKey(std::shared_ptr<EVP_PKEY>(key, EVP_PKEY_free));
    char buf[512] = {0};
    X509_NAME_oneline(X509_get_subject_name(cert.get()), buf, sizeof buf - 1);
    out.subject = buf;
    return out;
}

void grantUser(SessionIdentity& identity, const std::string& name,
               const std::vector<NodeId>& roles) {
    identity = SessionIdentity{};
    identity.anonymous = false;
    identity.userName = name;
    identity.grant(role::anonymous());
    identity.grant(role::authenticatedUser());
    for (const auto& r : roles) identity.grant(r);
}
}  // namespace

std::string tokenPolicySuffix(std::string_view policyUri) {
    auto hash = policyUri.rfind('#');
    std::string s(hash == std::string_view::npos ? policyUri : policyUri.substr(hash + 1));
    std::transform(s.begin(), s.end(), s.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return s;
}

UserAccessControl::UserAccessControl(UserAccessConfig config) : config_(std::move(config)) {}

std::vector<UserTokenPolicy> UserAccessControl::userTokenPolicies(
    std::string_view endpointPolicyUri, MessageSecurityMode mode) const {
    std::vector<UserTokenPolicy> out;
    auto add = [&](std::string id, UserTokenType type, std::string_view policyUri) {
        UserTokenPolicy p;
        p.policyId = String(std::move(id));
        p.tokenType = type;
        p.securityPolicyUri = String(policyUri);
        out.push_back(std::move(p));
    };
    if (config_.allowAnonymous) add(std::string(kAnonymousPolicyId), UserTokenType::Anonymous, "");
    const bool passwords = config_.users && config_.users->hasPasswordUsers();
    const bool certificates = static_cast<bool>(config_.validateUserCertificate);
    // The policy that protects the token: the channel's on secure endpoints (named explicitly
    // when the channel only signs, OPC 10000-4 §7.41.4), a configured one on None endpoints.
    const bool secureEndpoint = !isNone(endpointPolicyUri);
    std::string_view tokenPolicy;
    std::string_view advertised;
    if (secureEndpoint) {
        tokenPolicy = endpointPolicyUri;
        advertised = mode == MessageSecurityMode::SignAndEncrypt ? "" : endpointPolicyUri;
    } else if (config_.offerSecretTokensOnNone && crypto::findPolicy(config_.secretPolicyOnNone)) {
        tokenPolicy = advertised = config_.secretPolicyOnNone;
    }
    if (passwords) {
        if (!secureEndpoint && config_.allowUnencryptedPasswords)
            add(std::string(kPlainUserNamePolicyId), UserTokenType::UserName, crypto::kNoneUri);
        if (!tokenPolicy.empty())
            add(std::string(kUserNamePrefix) + tokenPolicySuffix(tokenPolicy),
                UserTokenType::UserName, advertised);
    }
    if (certificates && !tokenPolicy.empty())
        add(std::string(kX509Prefix) + tokenPolicySuffix(tokenPolicy), UserTokenType::Certificate,
            advertised);
    return out;
}

StatusCode UserAccessControl::activateSession(const ExtensionObject& token,
                                              const ActivationContext& context,
                                              SessionIdentity& identity) {
    try {
        // An empty token means anonymous (Part 4 §5.6.3.2).
        if (token.empty() || fromExtensionObject<AnonymousIdentityToken>(token)) {
            if (!config_.allowAnonymous) return status::BadIdentityTokenRejected;
            identity = SessionIdentity{};
            identity.grant(role::anonymous());
            return status::Good;
        }
        if (auto user = fromExtensionObject<UserNameIdentityToken>(token))
            return userName(*user, context, identity);
        if (auto cert = fromExtensionObject<X509IdentityToken>(token))
            return x509(*cert, context, identity);
    } catch (const DecodeError&) {
        return status::BadIdentityTokenInvalid;
    } catch (const crypto::CryptoError&) {
        return status::BadIdentityTokenInvalid;
    }
    return status::BadIdentityTokenInvalid;
}

StatusCode UserAccessControl::userName(const UserNameIdentityToken& token,
                                       const ActivationContext& context,
                                       SessionIdentity& identity) const {
    if (!config_.users || !config_.users->hasPasswordUsers())
        return status::BadIdentityTokenInvalid;
    std::optional<std::string> password;
    if (token.encryptionAlgorithm.empty()) {
        // A plain password: inside an encrypted channel, or where explicitly allowed.
        if (context.channelMode != MessageSecurityMode::SignAndEncrypt &&
            !config_.allowUnencryptedPasswords)
            return status::BadIdentityTokenRejected;
        password = token.password.str();
    } else {
        const crypto::SecurityPolicy* policy = policyOfTokenId(token.policyId, kUserNamePrefix);
        if (policy == nullptr || context.serverKey == nullptr || !*context.serverKey ||
            context.serverNonce.empty() ||
            token.encryptionAlgorithm != policy->asymmetricEncryptionUri)
            return status::BadIdentityTokenInvalid;
        if (token.password.size() > kMaxSecretTokenSize) return status::BadIdentityTokenInvalid;
        password =
            looksLikeEncryptedSecret(token.password)
                ? encryptedSecretPassword(*policy, *context.serverKey, token.password,
                                          context.serverCertificate, context.serverNonce)
                : legacyPassword(*policy, *context.serverKey, token.password, context.serverNonce);
        if (!password) return status::BadIdentityTokenInvalid;
    }
    const UserRecord* user = config_.users->verifyPassword(token.userName, *password);
    std::fill(password->begin(), password->end(), '\0');
    if (user == nullptr) return status::BadUserAccessDenied;
    grantUser(identity, user->name, user->roles);
    return status::Good;
}

StatusCode UserAccessControl::x509(const X509IdentityToken& token, const ActivationContext& context,
                                   SessionIdentity& identity) const {
    if (!config_.validateUserCertificate) return status::BadIdentityTokenInvalid;
    const crypto::SecurityPolicy* policy = policyOfTokenId(token.policyId, kX509Prefix);
    if (policy == nullptr || context.serverNonce.empty()) return status::BadIdentityTokenInvalid;
    auto cert = parseCertificate(token.certificateData);
    if (!cert) return status::BadIdentityTokenInvalid;
    // Proof of possession: the user's key signed serverCertificate | serverNonce with the
    // token policy's asymmetric signature (OPC 10000-4 §5.6.3.2).
    const SignatureData* sig = context.userTokenSignature;
    if (sig == nullptr || sig->algorithm != policy->asymmetricSignatureUri ||
        sig->signature.empty())
        return status::BadUserSignatureInvalid;
    crypto::Bytes signedData(context.serverCertificate.begin(), context.serverCertificate.end());
    signedData.insert(signedData.end(), context.serverNonce.begin(), context.serverNonce.end());
    if (!crypto::verify(cert->key, policy->asymmetricSignature, signedData, bytes(sig->signature)))
        return status::BadUserSignatureInvalid;
    StatusCode valid = config_.validateUserCertificate(token.certificateData);
    if (valid.isBad()) return status::BadIdentityTokenRejected;
    const UserRecord* user =
        config_.users
            ? config_.users->findByThumbprint(toHex(crypto::sha1(bytes(token.certificateData))))
            : nullptr;
    if (user == nullptr) return status::BadUserAccessDenied;
    grantUser(identity, user->name, user->roles);
    return status::Good;
}

DefaultAccessControl::DefaultAccessControl(bool allowAnonymous,
                                           std::map<std::string, std::string> users)
    : UserAccessControl([&] {
          UserAccessConfig c;
          c.allowAnonymous = allowAnonymous;
          c.allowUnencryptedPasswords = true;
          auto store = std::make_shared<UserStore>();
          // The passwords are in memory anyway: few iterations, the hash only makes the
          // comparison constant-time.
          for (const auto& [name, password] : users)
              store->addUser(name, password, {role::operator_()}, UserStore::kMinIterations);
          if (!store->empty()) c.users = std::move(store);
          return c;
      }()) {}

}  // namespace pnp::ua::server
