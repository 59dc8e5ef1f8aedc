// Pluggable access control (like open62541's plugin): who may open a session and with which
// roles (OPC 10000-4 §5.6.3 ActivateSession, §7.41 UserIdentityToken). What a session may do
// with a node follows from its roles and the nodes' RolePermissions (ua/server/roles.hpp),
// checked by the address-space services. The server asks on the network thread, so
// implementations must be fast and must not block (a password check costs one PBKDF2 hash).
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "ua/crypto/crypto.hpp"
#include "ua/server/roles.hpp"
#include "ua/server/user_store.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

// Part 18 well-known roles (NodeIds in ns0: Anonymous i=15644, AuthenticatedUser i=15656,
// Observer i=15668, Operator i=15680, Engineer i=16036, Supervisor i=15692, ConfigureAdmin
// i=15716, SecurityAdmin i=15704): see roles.hpp, which also defines SessionIdentity:
//   struct SessionIdentity {
//       bool anonymous = true;
//       std::string userName;           // or the X.509 user certificate's subject
//       std::vector<NodeId> roles;      // granted roles (always Anonymous; AuthenticatedUser
//                                       // for every non-anonymous)
//       bool hasRole(const NodeId& role) const;
//       bool encryptedChannel = false;  // the session's channel is SignAndEncrypt (lead)
//       std::uint32_t roleBits;         // the well-known roles as bits (grant() keeps it)
//       void grant(const NodeId& role);
//   };

// What ActivateSession knows besides the token.
struct ActivationContext {
    std::string_view channelPolicyUri;  // the secure channel's policy (None possible)
    MessageSecurityMode channelMode = MessageSecurityMode::None;
    const crypto::PrivateKey* serverKey = nullptr;  // the server's key (null: no certificate)
    crypto::ByteView serverCertificate;             // DER, as the server sent it in CreateSession
    crypto::ByteView serverNonce;                   // the last nonce the server sent this session
    const SignatureData* userTokenSignature = nullptr;  // ActivateSessionRequest.userTokenSignature
};

class AccessControl {
  public:
    virtual ~AccessControl() = default;
    // The token policies of one endpoint (policy and mode of that endpoint).
    virtual std::vector<UserTokenPolicy> userTokenPolicies(std::string_view endpointPolicyUri,
                                                           MessageSecurityMode mode) const = 0;
    // Checks the identity token of ActivateSession (an AnonymousIdentityToken,
    // UserNameIdentityToken, X509IdentityToken ExtensionObject; empty: anonymous). Good:
    // `identity` is filled in (roles included; encryptedChannel is the caller's).
    virtual StatusCode activateSession(const ExtensionObject& userIdentityToken,
                                       const ActivationContext& context,
                                       SessionIdentity& identity) = 0;
    // Extra per-node hooks on top of the role permissions (default: allowed).
    virtual bool allowWrite(const SessionIdentity&, const NodeId&) { return true; }
    virtual bool allowCall(const SessionIdentity&, const NodeId& /*method*/) { return true; }
};

struct UserAccessConfig {
    bool allowAnonymous = true;
    // Password and certificate users (null or empty: no UserName / X.509 tokens offered).
    std::shared_ptr<const UserStore> users;
    // Plain (unencrypted) passwords are accepted on SignAndEncrypt channels; elsewhere only
    // with this set (tests, a VPN). On None endpoints it also offers a UserName policy with
    // SecurityPolicy None.
    bool allowUnencryptedPasswords = false;
    // Offer UserName (and X.509) on None endpoints with a token policy that names
    // `secretPolicyOnNone`, so that the password is encrypted with the server's certificate
    // even there (needs the server's key). Default: not offered on None endpoints.
    bool offerSecretTokensOnNone = false;
    std::string secretPolicyOnNone = "http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256";
    // Validates an X.509 user certificate (chain, trust, validity: the PKI module). Null: X.509
    // user tokens are not offered. A Bad result rejects the token.
    std::function<StatusCode(const ByteString& certDer)> validateUserCertificate;
};

// Anonymous (configurable), UserName tokens checked against a UserStore (plain, legacy
// encrypted and EncryptedSecret passwords) and X.509 user tokens mapped to users by their
// certificate's thumbprint. Every session gets the Anonymous role; authenticated ones also
// AuthenticatedUser and the roles the store gives them.
//
// Token policy ids (stable; one per token type and token security policy):
//   "anonymous"; "username" (plain, SecurityPolicy None); "username_<policy>" and
//   "x509_<policy>" with <policy> the lower-case policy name (e.g. basic256sha256).
// Status codes: a token of an unknown policy, malformed, badly encrypted or with a wrong
// nonce: Bad_IdentityTokenInvalid; anonymous when disabled, a plain password where not
// allowed, a certificate the validator refuses: Bad_IdentityTokenRejected; a wrong user name
// or password, an unknown certificate: Bad_UserAccessDenied (the same for both, in the same
// time); a wrong X.509 token signature: Bad_UserSignatureInvalid.
class UserAccessControl : public AccessControl {
  public:
    explicit UserAccessControl(UserAccessConfig config);
    std::vector<UserTokenPolicy> userTokenPolicies(std::string_view endpointPolicyUri,
                                                   MessageSecurityMode mode) const override;
    StatusCode activateSession(const ExtensionObject& userIdentityToken,
                               const ActivationContext& context,
                               SessionIdentity& identity) override;
    const UserAccessConfig& config() const { return config_; }

  private:
    StatusCode userName(const UserNameIdentityToken& token, const ActivationContext& context,
                        SessionIdentity& identity) const;
    StatusCode x509(const X509IdentityToken& token, const ActivationContext& context,
                    SessionIdentity& identity) const;
    UserAccessConfig config_;
};

// Anonymous access (optional) plus a fixed table of user names and passwords (hashed at
// construction), plain passwords allowed on any channel: the behaviour before issue 24, for
// tests and `pnp serve --user`. Users get the Operator role.
class DefaultAccessControl : public UserAccessControl {
  public:
    explicit DefaultAccessControl(bool allowAnonymous = true,
                                  std::map<std::string, std::string> users = {});
};

// The token policy id suffix of a security policy URI ("basic256sha256").
std::string tokenPolicySuffix(std::string_view policyUri);

}  // namespace pnp::ua::server
