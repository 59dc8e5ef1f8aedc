#include "ua/server/access_control.hpp"

#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {

namespace {
constexpr const char* kNonePolicy = "http://opcfoundation.org/UA/SecurityPolicy#None";
constexpr const char* kAnonymousPolicyId = "anonymous";
constexpr const char* kUserNamePolicyId = "username";
}  // namespace

DefaultAccessControl::DefaultAccessControl(bool allowAnonymous,
                                           std::map<std::string, std::string> users)
    : allowAnonymous_(allowAnonymous), users_(std::move(users)) {}

std::vector<UserTokenPolicy> DefaultAccessControl::userTokenPolicies() const {
    std::vector<UserTokenPolicy> out;
    if (allowAnonymous_) {
        UserTokenPolicy p;
        p.policyId = kAnonymousPolicyId;
        p.tokenType = UserTokenType::Anonymous;
        out.push_back(std::move(p));
    }
    if (!users_.empty()) {
        UserTokenPolicy p;
        p.policyId = kUserNamePolicyId;
        p.tokenType = UserTokenType::UserName;
        // Without channel security the password travels unencrypted; say so explicitly.
        p.securityPolicyUri = kNonePolicy;
        out.push_back(std::move(p));
    }
    return out;
}

StatusCode DefaultAccessControl::activateSession(const ExtensionObject& token,
                                                 SessionIdentity& identity) {
    try {
        // An empty token means anonymous (Part 4 §5.6.3.2).
        if (token.empty() || fromExtensionObject<AnonymousIdentityToken>(token)) {
            if (!allowAnonymous_) return status::BadIdentityTokenRejected;
            identity = SessionIdentity{};
            return status::Good;
        }
        if (auto user = fromExtensionObject<UserNameIdentityToken>(token)) {
            if (!user->encryptionAlgorithm.empty()) return status::BadIdentityTokenInvalid;
            auto it = users_.find(user->userName);
            if (it == users_.end() || it->second != user->password.view())
                return status::BadUserAccessDenied;
            identity = SessionIdentity{false, user->userName};
            return status::Good;
        }
    } catch (const DecodeError&) {
        return status::BadIdentityTokenInvalid;
    }
    return status::BadIdentityTokenInvalid;
}

}  // namespace pnp::ua::server
