// The command line's security options (docs/security.md): where the PKI folder is, and what
// a server offers / a client accepts. One place, so that every command behaves the same.
#pragma once

#include <optional>
#include <string>

#include "ua/client/config.hpp"
#include "ua/server/server.hpp"

namespace CLI {
class App;
}

namespace pnp::cli {

struct SecurityOptions {
    // --pki DIR: certificates and trust in DIR; default: the machine's folder
    // ($PNP_PKI, else ${XDG_DATA_HOME:-~/.local/share}/pnp/pki), shared by its pnp applications
    std::string pki;
    bool insecure = false;   // --insecure: SecurityPolicy None only, no certificate
    std::string policy;      // client: --policy URI|NAME (default: the most secure offered)
    std::string mode;        // client: --mode sign|encrypt (the least accepted; default encrypt)
    bool allowNone = false;  // server: a None endpoint for sessions; client: accept None
    std::string users;       // server: --users FILE (password and certificate users)
    std::string userCert;    // client: --user-cert FILE (X.509 user token) ...
    std::string userKey;     // ... and its --user-key FILE
};

// --pki, --insecure, --allow-none: every server command (with its discovery options).
void addServerSecurityOptions(CLI::App* cmd, SecurityOptions& o);
// --pki, --insecure, --allow-none: commands whose clients connect to the cell's servers.
void addConnectionSecurityOptions(CLI::App* cmd, SecurityOptions& o);
// --pki, --insecure, --allow-none, --policy, --mode, --user-cert, --user-key.
void addClientSecurityOptions(CLI::App* cmd, SecurityOptions& o);

// The PKI folder the options name (--pki, else the machine's).
std::string pkiFolder(const SecurityOptions& o);

// Secure by default (docs/security.md): the server gets its certificate from the PKI folder
// (created at the first start, named after its ApplicationUri; for an ApplicationUri that
// lives only as long as the process — `ephemeral`, a server on port 0 — a certificate
// removed at exit), SignAndEncrypt and Sign endpoints, and the folder as its trust list. The
// process's clients (registration with the LDS-ME, the skill detector, a component's
// connections) connect with the same identity. --insecure: SecurityPolicy None only.
// Throws UsageError for options that do not fit, PkiError for an unusable folder.
void secureServer(ua::server::ServerConfig& config, const SecurityOptions& o, bool ephemeral);

// --users FILE: password and X.509 users with their roles (the X.509 ones validated against
// the server's trust list) as config.accessControl; anonymous sessions as allowAnonymous
// says. False (nothing set) without --users.
bool applyUsers(ua::server::ServerConfig& config, const SecurityOptions& o, bool allowAnonymous);

// After the server's address space is built: with --users the role permissions (everyone
// observes, Operator writes and calls, SecurityAdmin manages certificates); on every secured
// server the Part 12 push model (ServerConfiguration, TrustList) for a SecurityAdmin.
void finishServerSecurity(ua::server::Server& server, const SecurityOptions& o);

// A command that is only a client: its connections are secured with the CLI's certificate
// (urn:pnp:<host>:cli in the PKI folder), accepting servers the folder trusts.
void secureClients(const SecurityOptions& o);

// A client's security from the options (`pnp ua ...`): nullopt with --insecure.
std::optional<ua::client::ClientSecurity> clientSecurity(const SecurityOptions& o);
// The ApplicationUri and name a client presents with clientSecurity().
std::string cliApplicationUri();
inline constexpr const char* kCliApplicationName = "pnp cli";

// The X.509 user identity of --user-cert / --user-key; nullopt without them.
std::optional<ua::client::UserCertificate> userCertificate(const SecurityOptions& o);

}  // namespace pnp::cli
