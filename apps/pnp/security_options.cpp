#include "security_options.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <cctype>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <mutex>
#include <set>
#include <sstream>
#include <utility>
#include <vector>

#include "output.hpp"
#include "ua/certificate_management/certificate_management.hpp"
#include "ua/server/access_control.hpp"
#include "ua/server/roles.hpp"
#include "ua/server/user_store.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::cli {

namespace {
std::string readFile(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw UsageError("cannot read " + path);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

// Tells the operator, once per certificate, which client was refused and how to approve it:
// `pnp pki list` shows the same, but a device that plugs in and fails should say so where the
// integrator looks. At most 256 distinct certificates are told about (a flood of made-up
// certificates must not flood the log).
std::function<void(const ua::pki::Certificate&, ua::StatusCode)> tellRefused(std::string who) {
    struct Told {
        std::mutex mutex;
        std::set<std::string> thumbprints;
    };
    return [who = std::move(who), told = std::make_shared<Told>()](const ua::pki::Certificate& c,
                                                                   ua::StatusCode st) {
        const std::string thumbprint = c.thumbprintHex();
        {
            std::lock_guard lock(told->mutex);
            if (told->thumbprints.size() >= 256 || !told->thumbprints.insert(thumbprint).second)
                return;
        }
        const auto uris = c.uris();
        std::string line = who + ": refused the certificate of " +
                           (uris.empty() ? c.subject() : uris.front()) + " (" +
                           std::string(st.name()) + ")";
        if (st == ua::status::BadCertificateUntrusted)
            line += "; approve it with `pnp pki trust " + thumbprint.substr(0, 16) + "`";
        std::cerr << line + "\n" << std::flush;
    };
}

// The file name of an application's own certificate: its URI with anything but letters,
// digits, '_' and '-' replaced, so that applications sharing a PKI folder keep their own.
std::string certificateName(const std::string& uri) {
    std::string n;
    for (char c : uri.starts_with("urn:") ? uri.substr(4) : uri)
        n += (std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-') ? c : '-';
    return n.substr(0, 100);
}

// "Basic256Sha256" or the whole URI.
std::string policyUri(const std::string& text) {
    if (text.empty() || text.find("://") != std::string::npos) return text;
    return "http://opcfoundation.org/UA/SecurityPolicy#" + text;
}
}  // namespace

void addServerSecurityOptions(CLI::App* cmd, SecurityOptions& o) {
    cmd->add_option("--pki", o.pki,
                    "the PKI folder with this server's certificate and its trust list (default: "
                    "the machine's, $PNP_PKI or ~/.local/share/pnp/pki; see `pnp pki`)");
    cmd->add_flag("--insecure", o.insecure,
                  "SecurityPolicy None only, no certificate (default: SignAndEncrypt and Sign "
                  "endpoints; None serves discovery only)");
    cmd->add_flag("--allow-none", o.allowNone,
                  "also offer a SecurityPolicy None endpoint for sessions and accept "
                  "registrations over None (an LDS-ME); the server's own connections accept "
                  "servers without security");
    cmd->add_option("--users", o.users,
                    "password and certificate users with their roles (see `pnp user`); a "
                    "SecurityAdmin among them manages the certificates remotely (Part 12)");
}

void addConnectionSecurityOptions(CLI::App* cmd, SecurityOptions& o) {
    cmd->add_option("--pki", o.pki,
                    "the PKI folder with this client's certificate and the servers it trusts "
                    "(default: the machine's, $PNP_PKI or ~/.local/share/pnp/pki)");
    cmd->add_flag("--insecure", o.insecure, "connect with SecurityPolicy None, no certificate");
    cmd->add_flag("--allow-none", o.allowNone,
                  "accept a server that offers SecurityPolicy None only");
}

void addClientSecurityOptions(CLI::App* cmd, SecurityOptions& o) {
    addConnectionSecurityOptions(cmd, o);
    cmd->add_option("--policy", o.policy, "only this security policy (e.g. Basic256Sha256)");
    cmd->add_option("--mode", o.mode, "the least mode accepted: sign or encrypt (default)")
        ->check(CLI::IsMember({"sign", "encrypt"}));
    cmd->add_option("--user-cert", o.userCert,
                    "X.509 user certificate (DER or PEM), with --user-key");
    cmd->add_option("--user-key", o.userKey, "the user certificate's private key (PEM)");
}

std::string pkiFolder(const SecurityOptions& o) {
    return o.pki.empty() ? ua::pki::defaultFolder().string() : o.pki;
}

namespace {

std::string hostName() {
    char buf[256] = {};
    if (::gethostname(buf, sizeof buf - 1) != 0 || !buf[0]) return "localhost";
    return buf;
}

bool isAddress(const std::string& host) {
    unsigned char b[sizeof(in6_addr)];
    return inet_pton(AF_INET, host.c_str(), b) == 1 || inet_pton(AF_INET6, host.c_str(), b) == 1;
}

// The certificates of ephemeral identities, removed from own/ when the process exits.
struct EphemeralCertificates {
    std::mutex mutex;
    std::vector<std::pair<std::shared_ptr<ua::pki::CertificateStore>, std::string>> made;
    ~EphemeralCertificates() {
        for (auto& [store, name] : made) {
            try {
                store->removeEphemeral(name);
            } catch (...) {
                // exiting: a file left behind is removed by the next start
            }
        }
    }
};
EphemeralCertificates ephemeralCertificates;

std::shared_ptr<ua::pki::CertificateStore> openStore(const SecurityOptions& o) {
    auto store = std::make_shared<ua::pki::CertificateStore>(pkiFolder(o));
    store->ensureLayout();
    return store;
}

void checkInsecure(const SecurityOptions& o) {
    if (o.insecure && (!o.pki.empty() || !o.policy.empty() || !o.mode.empty() || o.allowNone))
        throw UsageError("--insecure excludes --pki, --policy, --mode and --allow-none");
}

}  // namespace

void secureServer(ua::server::ServerConfig& config, const SecurityOptions& o, bool ephemeral) {
    checkInsecure(o);
    if (o.insecure) {
        config.security.reset();
        ua::client::setDefaultSecurity(std::nullopt);
        return;
    }
    auto store = openStore(o);
    ua::pki::CertificateRequest request;
    request.applicationUri = config.applicationUri;
    request.commonName = config.applicationName;
    const std::string host = config.publicHost.empty() ? hostName() : config.publicHost;
    (isAddress(host) ? request.ipAddresses : request.dnsNames).push_back(host);
    if (host != "localhost") request.dnsNames.push_back("localhost");
    ua::server::ServerSecurity security;
    if (ephemeral) {
        const std::string name = certificateName(config.applicationName).substr(0, 40);
        security.identity = store->createEphemeral(request, name);
        security.certificateName = ua::pki::CertificateStore::ephemeralName(name);
        std::lock_guard lock(ephemeralCertificates.mutex);
        ephemeralCertificates.made.emplace_back(store, name);
    } else {
        security.certificateName = certificateName(config.applicationUri).substr(0, 64);
        security.identity = store->loadOrCreateOwn(request, security.certificateName);
    }
    security.trust = store;
    security.onClientRefused = tellRefused(config.applicationName);
    security.offerNone = o.allowNone;
    config.discovery.allowInsecureRegistration = o.allowNone;
    ua::client::ClientSecurity client;
    client.identity = security.identity;
    client.trust = store;
    client.allowNone = o.allowNone;
    config.security = std::move(security);
    ua::client::setDefaultSecurity(
        ua::client::DefaultSecurity{client, config.applicationUri, config.applicationName});
}

bool applyUsers(ua::server::ServerConfig& config, const SecurityOptions& o, bool allowAnonymous) {
    if (o.users.empty()) return false;
    ua::server::UserAccessConfig access;
    access.allowAnonymous = allowAnonymous;
    try {
        access.users =
            std::make_shared<const ua::server::UserStore>(ua::server::UserStore::load(o.users));
    } catch (const std::exception& e) {
        throw UsageError(std::string("--users: ") + e.what());
    }
    if (config.security && config.security->trust) {
        // X.509 users: their certificates are validated against the same trust list.
        access.validateUserCertificate = [trust =
                                              config.security->trust](const ua::ByteString& der) {
            try {
                return trust->validate(ua::pki::Certificate::chainFromDer(
                                           ua::crypto::ByteView(der.data(), der.size())),
                                       ua::pki::ValidationOptions{});
            } catch (const std::exception&) {
                return ua::StatusCode(ua::status::BadCertificateInvalid);
            }
        };
    }
    config.accessControl = std::make_shared<ua::server::UserAccessControl>(std::move(access));
    return true;
}

void finishServerSecurity(ua::server::Server& server, const SecurityOptions& o) {
    if (!o.users.empty()) server.addressSpace().applyPermissions(ua::server::pnpRolePolicy());
    const auto& security = server.config().security;
    if (security && security->trust)
        ua::certificate_management::enableCertificateManagement(server);
}

std::string cliApplicationUri() { return "urn:pnp:" + hostName() + ":cli"; }

std::optional<ua::client::ClientSecurity> clientSecurity(const SecurityOptions& o) {
    checkInsecure(o);
    if (o.insecure) return std::nullopt;
    auto store = openStore(o);
    ua::pki::CertificateRequest request;
    request.applicationUri = cliApplicationUri();
    request.commonName = kCliApplicationName;
    ua::client::ClientSecurity security;
    security.identity = store->loadOrCreateOwn(request, "pnp-cli");
    security.trust = std::move(store);
    security.policyUri = policyUri(o.policy);
    if (!security.policyUri.empty() && !ua::crypto::findPolicy(security.policyUri))
        throw UsageError("--policy " + o.policy +
                         ": not a supported security policy (Basic256Sha256, "
                         "Aes128_Sha256_RsaOaep, Aes256_Sha256_RsaPss)");
    security.minimumMode =
        o.mode == "sign" ? ua::MessageSecurityMode::Sign : ua::MessageSecurityMode::SignAndEncrypt;
    security.allowNone = o.allowNone;
    return security;
}

void secureClients(const SecurityOptions& o) {
    auto security = clientSecurity(o);
    if (!security) {
        ua::client::setDefaultSecurity(std::nullopt);
        return;
    }
    ua::client::setDefaultSecurity(
        ua::client::DefaultSecurity{*security, cliApplicationUri(), kCliApplicationName});
}

std::optional<ua::client::UserCertificate> userCertificate(const SecurityOptions& o) {
    if (o.userCert.empty() && o.userKey.empty()) return std::nullopt;
    if (o.userCert.empty() || o.userKey.empty())
        throw UsageError("--user-cert and --user-key go together");
    ua::client::UserCertificate user;
    try {
        user.identity.certificate = ua::pki::Certificate::load(o.userCert);
        user.identity.key = ua::crypto::PrivateKey::fromPem(readFile(o.userKey));
    } catch (const std::exception& e) {
        throw UsageError(std::string("--user-cert / --user-key: ") + e.what());
    }
    return user;
}

}  // namespace pnp::cli
