// Pluggable access control (like open62541's plugin): who may open a session, and what a
// session may do. The server asks it on the network thread, so implementations must be fast
// and must not block.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

// Who a session belongs to, as decided by AccessControl::activateSession.
struct SessionIdentity {
    bool anonymous = true;
    std::string userName;
};

class AccessControl {
  public:
    virtual ~AccessControl() = default;
    // The token policies advertised in every EndpointDescription.
    virtual std::vector<UserTokenPolicy> userTokenPolicies() const = 0;
    // Checks the identity token of ActivateSession (an AnonymousIdentityToken,
    // UserNameIdentityToken, ... ExtensionObject). Good: `identity` is filled in.
    virtual StatusCode activateSession(const ExtensionObject& userIdentityToken,
                                       SessionIdentity& identity) = 0;
    virtual bool allowWrite(const SessionIdentity&, const NodeId&) { return true; }
    virtual bool allowCall(const SessionIdentity&, const NodeId& /*method*/) { return true; }
};

// Anonymous access (optional) plus a fixed table of user names and passwords.
class DefaultAccessControl : public AccessControl {
  public:
    explicit DefaultAccessControl(bool allowAnonymous = true,
                                  std::map<std::string, std::string> users = {});
    std::vector<UserTokenPolicy> userTokenPolicies() const override;
    StatusCode activateSession(const ExtensionObject& userIdentityToken,
                               SessionIdentity& identity) override;

  private:
    bool allowAnonymous_;
    std::map<std::string, std::string> users_;
};

}  // namespace pnp::ua::server
