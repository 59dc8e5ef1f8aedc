// Remote certificate management of a secured server: the push model of OPC 10000-12 (§7.10
// ServerConfiguration, §7.8 TrustList), so that a GDS or a tool can renew the server's
// application instance certificate and manage its trust list.
//
// Namespace 0 already holds the nodes (Server/ServerConfiguration i=12637 and its
// CertificateGroups/DefaultApplicationGroup/TrustList i=12642); enableCertificateManagement()
// attaches the handlers and keeps the variables true:
//   UpdateCertificate     a new certificate (RSA, RsaSha256ApplicationCertificateType) with
//                         its issuers and optionally its key (PEM); checked, kept pending
//   CreateSigningRequest  a PKCS#10 request with the server's ApplicationUri, for the current
//                         key or a new one (kept for UpdateCertificate)
//   ApplyChanges          the pending certificate becomes the server's (new secure channels,
//                         GetEndpoints, CreateSession) and is written to the store's own/
//   GetRejectedList       the certificates in rejected/
//   TrustList             Open (Read, or Write + EraseExisting), OpenWithMasks, Read, Write,
//                         GetPosition, SetPosition, Close, CloseAndUpdate (replaces trusted/
//                         and issuers/ with a TrustListDataType), AddCertificate,
//                         RemoveCertificate; handles belong to the session that opened them
// Access: every one of these methods needs the SecurityAdmin role, which counts only on a
// SignAndEncrypt channel (role permissions on the method nodes; anyone else gets
// Bad_UserAccessDenied). AddressSpace::applyPermissions() replaces every rule: call this after
// it (pnpRolePolicy() has the same rules, so with it the order does not matter).
// Slow work (an RSA key, files of the store) runs after the network lock is released, on the
// calling connection's thread, so other clients are served meanwhile.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "ua/pki/pki.hpp"
#include "ua/server/server.hpp"

namespace pnp::ua::certificate_management {

struct Options {
    // MaxTrustListSize: the largest TrustListDataType (encoded bytes) written or read through
    // the TrustList file; a Write beyond it gets Bad_EncodingLimitsExceeded.
    std::size_t maxTrustListSize = 1u << 20;
    std::size_t maxOpenFilesPerSession = 4;  // TrustList handles (Bad_ResourceUnavailable)
    std::size_t maxOpenFiles = 32;           // handles of all sessions together
    std::size_t maxReadLength = 64u * 1024;  // bytes one Read returns at most
    std::size_t maxRejectedListed = 100;     // certificates GetRejectedList returns at most
    // The own certificate's name in the store (own/certs/<name>.der) that ApplyChanges
    // replaces. Empty: the file that holds the server's current certificate, else one named
    // after the ApplicationUri.
    std::string ownCertificateName;
    // ServerConfiguration.ServerCapabilities (OPC 10000-12 Annex D); empty: those of
    // config.discovery, else {"NA"}.
    std::vector<std::string> serverCapabilities;
};

// Installs the handlers on `server` (before or after start(); the server must have
// config.security, and `store` is its trust list, normally config.security->trust).
// Throws std::invalid_argument otherwise. The state lives as long as the server's address
// space.
void enableCertificateManagement(server::Server& server,
                                 std::shared_ptr<pki::CertificateStore> store,
                                 Options options = {});
// The same with the server's own trust list (config.security->trust, which must be set).
void enableCertificateManagement(server::Server& server, Options options = {});

}  // namespace pnp::ua::certificate_management
