// Client configuration and user identities.
#pragma once

#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "ua/crypto/crypto.hpp"
#include "ua/pki/pki.hpp"
#include "ua/transport/client_connection.hpp"
#include "ua/types/binary.hpp"

namespace pnp::ua::client {

using std::chrono::milliseconds;

// Anonymous user identity (AnonymousIdentityToken).
struct Anonymous {
    bool operator==(const Anonymous&) const = default;
};

// User name and password (UserNameIdentityToken). With SecurityPolicy None and a token
// policy without its own security policy the password travels unencrypted.
struct UserName {
    std::string user;
    std::string password;
    bool operator==(const UserName&) const = default;
};

// An X.509 user certificate and its key (X509IdentityToken): the key signs the server's
// certificate and nonce; it never leaves the client.
struct UserCertificate {
    pki::Identity identity;
    bool operator==(const UserCertificate& o) const {
        return identity.certificate == o.identity.certificate;
    }
};

using Identity = std::variant<Anonymous, UserName, UserCertificate>;

// A client's security (docs/security.md). With it, connect() asks the server for its
// endpoints, takes the most secure one it supports and trusts, opens a secured channel and
// proves its identity in the session; user passwords are encrypted for the server.
struct ClientSecurity {
    pki::Identity identity;  // the client's application instance certificate and key
    // Validates server certificates (untrusted ones land in its rejected/ folder). Null:
    // every server certificate is accepted — for tests only.
    std::shared_ptr<pki::CertificateStore> trust;
    // Restricts the choice: a policy URI (empty: any supported) and the least mode accepted.
    std::string policyUri;
    MessageSecurityMode minimumMode = MessageSecurityMode::SignAndEncrypt;
    // Accept an endpoint with SecurityPolicy None when the server offers nothing better
    // (e.g. an old server). Off: such a server is refused with BadSecurityPolicyRejected.
    bool allowNone = false;
};

// What happens when the connection drops (see Client for the whole story).
struct ReconnectPolicy {
    // Re-establish the connection (new secure channel, then ActivateSession on the existing
    // session, or a new session when the server forgot it) at the next call, or in the
    // background thread if one runs. When false, calls after a drop throw
    // Error(BadNotConnected) until connect() is called again.
    bool enabled = true;
    // Retry a request once after reconnecting when its response was lost with the
    // connection and the service is idempotent (Read, Browse, TranslateBrowsePaths,
    // GetEndpoints, FindServers, ...). A request that could not even be sent is always
    // retried once, whatever the service.
    bool retryIdempotent = true;
    // Background reconnect attempts: first after initialDelay, then doubling up to maxDelay.
    milliseconds initialDelay{100};
    milliseconds maxDelay{5000};
};

struct ClientConfig {
    // ApplicationDescription sent in CreateSession.
    std::string applicationName = "pnp client";
    std::string applicationUri = "urn:pnp:client";
    std::string productUri = "urn:pnp";
    // Session name; empty: "<applicationName> session".
    std::string sessionName;
    std::vector<std::string> localeIds;

    // RequestedSessionTimeout of CreateSession (the server may revise it).
    milliseconds requestedSessionTimeout{60'000};
    // Default deadline of every service call.
    milliseconds requestTimeout{10'000};
    // Default deadline of connect() (TCP, HEL/ACK, OpenSecureChannel, CreateSession,
    // ActivateSession) and of reconnect attempts.
    milliseconds connectTimeout{10'000};
    // Deadline of the CloseSession sent by disconnect() / the destructor.
    milliseconds closeTimeout{1'000};
    // Requested lifetime of a secure channel token (the transport renews it at 75 %).
    milliseconds secureChannelLifetime{600'000};
    // Session keep-alive: while the background thread runs (or runIterate() is called) and
    // no request was sent for this long, read Server_ServerStatus_CurrentTime so that the
    // session does not time out. 0: a third of the revised session timeout.
    milliseconds keepAliveInterval{0};
    // Before a request is sent on a connection that received nothing for this long, the
    // socket is checked (one poll) so that a connection the server closed while we were idle
    // is re-established first instead of failing the request. 0 disables the check.
    milliseconds idleCheckAfter{500};

    ReconnectPolicy reconnect;

    // The connection discoveryRequest() / getEndpoints() open to a URL other than the
    // session's stays open for the next request to the same URL, instead of a new
    // (secure) channel each time: for a registrar renewing every few hundred ms. One caller
    // at a time uses it.
    bool keepDiscoveryConnection = false;

    // Secured connections; absent: the process's default security (below) if it has one and
    // useDefaultSecurity is on, else SecurityPolicy None.
    std::optional<ClientSecurity> security;
    bool useDefaultSecurity = true;

    // Buffer sizes and message limits of the transport (HEL/ACK negotiation), send timeout.
    // Its requestedLifetime is replaced by secureChannelLifetime above.
    transport::ClientConfig transport;
    // Limits applied when decoding responses.
    DecodeLimits decodeLimits;
};

// The process's default security: pnp's applications set it once at start-up from the
// machine's PKI folder (docs/security.md), so that every client they make — the skill
// detector's, a component's, the registrar's — connects securely without being told.
// Libraries and unit tests leave it unset. The application description goes with the
// identity: CreateSession's ApplicationUri must be the one in the certificate.
struct DefaultSecurity {
    ClientSecurity security;
    std::string applicationUri;
    std::string applicationName;
};
void setDefaultSecurity(std::optional<DefaultSecurity> security);
std::optional<DefaultSecurity> defaultSecurity();

}  // namespace pnp::ua::client
