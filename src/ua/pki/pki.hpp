// Application instance certificates and trust (OPC 10000-4 §6.1, OPC 10000-12 Annex F):
// X.509 certificates (parsed with OpenSSL, bounded), creation of a self-signed application
// instance certificate, and the certificate store folder that node-opcua and Part 12 use:
//
//   <root>/own/certs/<name>.der       own certificate      own/private/<name>.pem  its key (0600)
//   <root>/trusted/certs/*.der        trusted certificates trusted/crl/*.crl (or .der / .pem)
//   <root>/issuers/certs/*.der        issuer CAs (not trusted by themselves)   issuers/crl/*.crl
//   <root>/rejected/certs/*.der       certificates seen and not trusted (bounded; oldest dropped)
//
// Validation follows OPC 10000-4 §6.1.3 (chain, signature, validity, revocation, trust,
// host name / URI, key usage) and answers with the status code the peer gets.
#pragma once

#include <chrono>
#include <cstddef>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "ua/crypto/crypto.hpp"
#include "ua/types/builtin.hpp"

typedef struct x509_st X509;

namespace pnp::ua::pki {

using crypto::Bytes;
using crypto::ByteView;

class PkiError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

inline constexpr std::size_t kMaxCertificateSize = 32 * 1024;  // DER bytes accepted from outside

// An X.509 certificate (immutable; copies share it).
class Certificate {
  public:
    // Throws PkiError for anything that is not one well-formed DER certificate of at most
    // kMaxCertificateSize bytes (no trailing bytes).
    static Certificate fromDer(ByteView der);
    // A chain as OPC UA sends it (concatenated DER certificates, leaf first); at most 8.
    static std::vector<Certificate> chainFromDer(ByteView der);
    static Certificate fromPem(std::string_view pem);
    static Certificate load(const std::filesystem::path& file);  // .der or .pem

    const Bytes& der() const;
    std::string toPem() const;
    Bytes thumbprint() const;           // SHA-1 of the DER (20 bytes)
    std::string thumbprintHex() const;  // lower-case hex, the store's file name stem
    crypto::PublicKey publicKey() const;
    int keyBits() const;

    std::string subject() const;  // one line, e.g. "CN=pnp device ur, O=pnp"
    std::string commonName() const;
    std::string issuer() const;
    std::string serialHex() const;
    std::chrono::system_clock::time_point notBefore() const;
    std::chrono::system_clock::time_point notAfter() const;
    std::vector<std::string> uris() const;         // SubjectAltName URIs
    std::vector<std::string> dnsNames() const;     // SubjectAltName DNS names
    std::vector<std::string> ipAddresses() const;  // SubjectAltName IP addresses (text)
    bool isCa() const;
    bool isSelfSigned() const;               // subject == issuer and its own key verifies it
    std::string signatureAlgorithm() const;  // e.g. "sha256WithRSAEncryption"

    X509* native() const { return cert_.get(); }
    friend bool operator==(const Certificate& a, const Certificate& b) {
        return a.der() == b.der();
    }

    Certificate() = default;

  private:
    std::shared_ptr<X509> cert_;
    std::shared_ptr<const Bytes> der_;
    friend struct CertificateAccess;
};

// What the application instance certificate says (OPC 10000-6 §6.2.2).
struct CertificateRequest {
    std::string applicationUri;            // SubjectAltName URI (required)
    std::string commonName;                // CN (the application name)
    std::string organization = "pnp";      // O
    std::vector<std::string> dnsNames;     // SubjectAltName DNS (host names)
    std::vector<std::string> ipAddresses;  // SubjectAltName IP
    int keyBits = 2048;
    std::chrono::hours validity{24 * 365 * 5};
    bool ca = false;  // a CA (for tests and `pnp pki create --ca`)
    // Start of the validity period (notAfter = notBefore + validity); default: now - 1 h, so
    // that a peer whose clock is slightly behind accepts it. Tests set it in the past or the
    // future for expired / not yet valid certificates.
    std::optional<std::chrono::system_clock::time_point> notBefore;
    // The key to certify; empty: a new RSA key of keyBits (1024 .. 4096) is generated.
    crypto::PrivateKey key;
};

struct Identity {
    Certificate certificate;
    crypto::PrivateKey key;
};

// A self-signed application instance certificate: SHA-256 with RSA, serial random, key usage
// digitalSignature, nonRepudiation, keyEncipherment, dataEncipherment, keyCertSign; extended
// key usage serverAuth + clientAuth; basicConstraints CA:FALSE (CA:TRUE for ca); subject and
// authority key identifiers.
Identity createSelfSigned(const CertificateRequest& request);
// The same, signed by `issuer` (tests: chains, CAs, revocation).
Identity createSigned(const CertificateRequest& request, const Identity& issuer);
// A CRL of `issuer` revoking the given serials (hex), valid for `validity`.
Bytes createCrl(const Identity& issuer, const std::vector<std::string>& revokedSerialsHex,
                std::chrono::hours validity = std::chrono::hours(24 * 30));

// What to check besides chain and trust (OPC 10000-4 §6.1.3).
struct ValidationOptions {
    std::string
        applicationUri;    // non-empty: a SAN URI must equal it exactly (BadCertificateUriInvalid)
    std::string hostName;  // non-empty: a SAN DNS / IP must match (BadCertificateHostNameInvalid)
    bool requireServerAuth = false;  // the peer is a server
    bool requireClientAuth = false;  // the peer is a client
    int minKeyBits = 2048;           // outside [min, max]: BadCertificatePolicyCheckFailed
    int maxKeyBits = 4096;
};

struct StoreConfig {
    std::size_t maxRejected = 100;  // rejected/ keeps at most this many (oldest removed)
    // The certificates in own/ are trusted: the applications that share a folder (those of
    // one machine, or one cell) trust each other without an operator's decision.
    bool trustOwn = true;
};

// The machine's PKI folder, shared by its pnp applications: $PNP_PKI, else
// $XDG_DATA_HOME/pnp/pki, else $HOME/.local/share/pnp/pki.
std::filesystem::path defaultFolder();

enum class TrustState { Trusted, Rejected, Issuer, Unknown, Own };
std::string_view toString(TrustState state);  // "trusted", "rejected", "issuer", "unknown", "own"

struct StoreEntry {
    Certificate certificate;
    TrustState state = TrustState::Unknown;
    std::filesystem::path file;
};

// The PKI folder. Thread-safe (one mutex); validation reads the folder's state cached in
// memory and re-reads it when a file changed (so `pnp pki trust` in another process takes
// effect without restarting the server).
class CertificateStore {
  public:
    explicit CertificateStore(std::filesystem::path root, StoreConfig config = {});
    ~CertificateStore();
    const std::filesystem::path& root() const;

    // Creates the folder layout (0700) if missing.
    void ensureLayout();
    // own/: loads the certificate and key; creates them at first start. A certificate whose
    // ApplicationUri differs from request.applicationUri (then with the same key), or that
    // expired, is replaced (the old pair kept as own/certs/<name>.<date>.der). Processes
    // starting at the same time agree on one certificate (a file lock on own/).
    Identity loadOrCreateOwn(const CertificateRequest& request, std::string_view name = "pnp");
    // For an application whose ApplicationUri lives only as long as its process (a server on
    // an ephemeral port): a self-signed certificate of the folder's one ephemeral key (made
    // once: no key generation per start), in own/certs/<name>-pid<PID>.der so that the
    // folder's applications trust it. removeEphemeral() deletes it when the process ends;
    // the files of processes that no longer run are deleted here.
    Identity createEphemeral(const CertificateRequest& request, std::string_view name);
    void removeEphemeral(std::string_view name);
    // The own/ name of this process's ephemeral certificate `name` (<name>-pid<PID>).
    static std::string ephemeralName(std::string_view name);
    // Replaces the own certificate (and key when given): Part 12 UpdateCertificate.
    void setOwn(const Identity& identity, std::string_view name = "pnp");

    // Good, or the status the peer gets: BadCertificateInvalid (malformed, bad signature),
    // BadCertificateTimeInvalid, BadCertificateIssuerTimeInvalid, BadCertificateRevoked,
    // BadCertificateIssuerRevoked, BadCertificateRevocationUnknown (issuer without a CRL),
    // BadCertificateChainIncomplete, BadCertificateUntrusted (then copied to rejected/),
    // BadCertificateUriInvalid, BadCertificateHostNameInvalid, BadCertificateUseNotAllowed,
    // BadCertificatePolicyCheckFailed. `chain` is leaf first (extra issuers may follow).
    StatusCode validate(const std::vector<Certificate>& chain, const ValidationOptions& options);

    // The operator's decisions (`pnp pki`). `thumbprintHex` may be a unique prefix (≥ 8).
    // list(): own/, trusted/, issuers/ and rejected/ (files that do not parse are skipped).
    std::vector<StoreEntry> list() const;
    // trusted/ and issuers/ only (a Part 12 TrustList), without reading own/ or rejected/.
    std::vector<StoreEntry> trustList() const;
    std::optional<StoreEntry> find(std::string_view thumbprintHex) const;
    void trust(std::string_view thumbprintHex);   // rejected/ -> trusted/ (throws PkiError)
    void reject(std::string_view thumbprintHex);  // trusted/ -> rejected/
    void remove(std::string_view thumbprintHex);  // deleted from wherever it is
    void addTrusted(const Certificate& cert);
    void addIssuer(const Certificate& cert);
    void addCrl(ByteView crlDer, bool forIssuers = false);
    // own/certs/<name>.der (nullopt when there is none).
    std::optional<Certificate> ownCertificate(std::string_view name = "pnp") const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

// Part 12 CreateSigningRequest (OPC 10000-12 §7.10.10): a PKCS#10 certification request (DER)
// for `key`, signed with it (SHA-256), asking for an application instance certificate: the
// SubjectAltName of `request` (ApplicationUri, required; DNS names; IP addresses), key usage,
// extended key usage serverAuth + clientAuth and basicConstraints CA:FALSE as requested
// extensions. The subject is `subjectName` when given, in the form Part 12 uses
// ("CN=pnp server/O=pnp/DC=host": attribute names CN, O, OU, DC, L, ST (or S), C or any
// other OpenSSL short name; a value containing '/', '=' or ',' in double quotes; ',' also
// separates when no '/' does), else CN = request.commonName, O = request.organization.
// Throws PkiError for a malformed subject name (at most 1024 characters, 16 attributes) or
// request. The key fields of `request` (key, keyBits) are not used.
Bytes createSigningRequest(const crypto::PrivateKey& key, const CertificateRequest& request,
                           std::string_view subjectName = {});
// The subject of `cert` in that form (what CreateSigningRequest keeps when none is given).
std::string subjectNameOf(const Certificate& cert);

}  // namespace pnp::ua::pki
