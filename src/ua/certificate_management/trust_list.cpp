#include "ua/certificate_management/trust_list.hpp"

#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/x509.h>
#include <openssl/x509v3.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <set>
#include <string_view>

#include "ua/types/binary.hpp"
#include "ua/types/buffer.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::certificate_management::detail {

namespace fs = std::filesystem;

namespace {

constexpr std::size_t kMaxFilesPerDirectory = 4096;  // a folder scan stops there
constexpr int kMinKeyBits = 2048;                    // the policies' bounds (Part 7)
constexpr int kMaxKeyBits = 4096;

struct CrlFree {
    void operator()(X509_CRL* c) const { X509_CRL_free(c); }
};
using CrlPtr = std::unique_ptr<X509_CRL, CrlFree>;

crypto::ByteView view(const ByteString& b) { return crypto::ByteView(b.data(), b.size()); }

// One DER CRL, nothing after it; null otherwise.
CrlPtr parseDerCrl(const Byte* p, std::size_t n) {
    const unsigned char* q = p;
    CrlPtr crl(d2i_X509_CRL(nullptr, &q, static_cast<long>(n)));
    ERR_clear_error();
    if (crl && q != p + n) crl.reset();
    return crl;
}

// A CRL file of the store (DER or PEM, as the store accepts them).
CrlPtr loadCrlFile(const fs::path& file, std::size_t maxBytes) {
    std::error_code ec;
    const auto size = fs::file_size(file, ec);
    if (ec || size > maxBytes) return nullptr;
    std::ifstream in(file, std::ios::binary);
    std::string data(size, '\0');
    if (!in.read(data.data(), static_cast<std::streamsize>(size))) return nullptr;
    if (data.find("-----BEGIN") != std::string::npos) {
        BIO* bio = BIO_new_mem_buf(data.data(), static_cast<int>(data.size()));
        CrlPtr crl(bio ? PEM_read_bio_X509_CRL(bio, nullptr, nullptr, nullptr) : nullptr);
        BIO_free(bio);
        ERR_clear_error();
        return crl;
    }
    return parseDerCrl(reinterpret_cast<const Byte*>(data.data()), data.size());
}

ByteString crlDer(X509_CRL* crl) {
    unsigned char* out = nullptr;
    const int n = i2d_X509_CRL(crl, &out);
    if (n <= 0) {
        ERR_clear_error();
        return {};
    }
    ByteString b(out, static_cast<std::size_t>(n));
    OPENSSL_free(out);
    return b;
}

bool isCrlFile(const fs::path& p) {
    const auto ext = p.extension().string();
    return (ext == ".crl" || ext == ".der" || ext == ".pem") &&
           p.filename().string().find(".tmp.") == std::string::npos;
}

// The CRL files of a folder (bounded), sorted.
std::vector<fs::path> crlFiles(const fs::path& dir) {
    std::vector<fs::path> out;
    std::error_code ec;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
        if (out.size() == kMaxFilesPerDirectory) break;
        std::error_code fec;
        if (it->is_regular_file(fec) && isCrlFile(it->path())) out.push_back(it->path());
    }
    std::sort(out.begin(), out.end());
    return out;
}

fs::path crlDir(const pki::CertificateStore& store, bool issuers) {
    return store.root() / (issuers ? "issuers" : "trusted") / "crl";
}

// Whether `issuer` issued `cert` and its signature verifies.
bool issuedBy(X509* cert, X509* issuer) {
    const bool ok = X509_check_issued(issuer, cert) == X509_V_OK &&
                    X509_verify(cert, X509_get0_pubkey(issuer)) == 1;
    ERR_clear_error();
    return ok;
}

bool selfSignatureVerifies(X509* cert) {
    const bool ok = X509_verify(cert, X509_get0_pubkey(cert)) == 1;
    ERR_clear_error();
    return ok;
}

bool weakSignature(const pki::Certificate& cert) {
    const std::string alg = cert.signatureAlgorithm();
    return alg.find("sha1") != std::string::npos || alg.find("SHA1") != std::string::npos ||
           alg.find("md5") != std::string::npos || alg.find("MD5") != std::string::npos;
}

bool keySizeOk(const pki::Certificate& cert) {
    const int bits = cert.keyBits();
    return bits >= kMinKeyBits && bits <= kMaxKeyBits;
}

// Structure and policy of a certificate of a new trust list.
StatusCode checkListed(const pki::Certificate& cert) {
    if (X509_get_version(cert.native()) != X509_VERSION_3) return status::BadCertificateInvalid;
    if (cert.isSelfSigned() && !selfSignatureVerifies(cert.native()))
        return status::BadCertificateInvalid;
    if (!keySizeOk(cert) || weakSignature(cert)) return status::BadCertificatePolicyCheckFailed;
    return StatusCode{};
}

std::set<std::string> thumbprintsOf(const std::vector<pki::Certificate>& certs) {
    std::set<std::string> out;
    for (const auto& c : certs) out.insert(c.thumbprintHex());
    return out;
}

// Certificates of one list: the new ones in, then the ones no longer listed out.
void replaceCertificates(pki::CertificateStore& store, const std::vector<pki::Certificate>& certs,
                         bool issuers) {
    for (const auto& c : certs) {
        if (issuers)
            store.addIssuer(c);
        else
            store.addTrusted(c);
    }
    const auto keep = thumbprintsOf(certs);
    const auto state = issuers ? pki::TrustState::Issuer : pki::TrustState::Trusted;
    for (const pki::StoreEntry& e : store.list()) {
        if (e.state != state || keep.count(e.certificate.thumbprintHex()) != 0) continue;
        std::error_code ec;
        fs::remove(e.file, ec);
    }
}

void replaceCrls(pki::CertificateStore& store, const std::vector<ByteString>& crls, bool issuers,
                 std::size_t maxBytes) {
    std::set<ByteString> keep(crls.begin(), crls.end());
    for (const ByteString& crl : crls) store.addCrl(view(crl), issuers);
    for (const fs::path& file : crlFiles(crlDir(store, issuers))) {
        CrlPtr crl = loadCrlFile(file, maxBytes);
        if (crl && keep.count(crlDer(crl.get())) != 0) continue;
        std::error_code ec;
        fs::remove(file, ec);
    }
}

}  // namespace

TrustListDataType readTrustList(const pki::CertificateStore& store, UInt32 masks,
                                std::size_t maxFileBytes) {
    TrustListDataType out;
    out.specifiedLists = masks & mask::All;
    if (masks & (mask::TrustedCertificates | mask::IssuerCertificates)) {
        for (const pki::StoreEntry& e : store.trustList()) {
            const auto& der = e.certificate.der();
            if (e.state == pki::TrustState::Trusted && (masks & mask::TrustedCertificates))
                out.trustedCertificates.emplace_back(der.data(), der.size());
            if (e.state == pki::TrustState::Issuer && (masks & mask::IssuerCertificates))
                out.issuerCertificates.emplace_back(der.data(), der.size());
        }
    }
    for (const bool issuers : {false, true}) {
        if (!(masks & (issuers ? mask::IssuerCrls : mask::TrustedCrls))) continue;
        auto& list = issuers ? out.issuerCrls : out.trustedCrls;
        for (const fs::path& file : crlFiles(crlDir(store, issuers))) {
            if (CrlPtr crl = loadCrlFile(file, maxFileBytes)) {
                ByteString der = crlDer(crl.get());
                if (!der.empty()) list.push_back(std::move(der));
            }
        }
    }
    return out;
}

std::vector<Byte> encodeTrustList(const TrustListDataType& list) {
    Buffer buffer;
    BinaryEncoder e(buffer);
    encode(e, list);
    return std::vector<Byte>(buffer.begin(), buffer.end());
}

StatusCode decodeTrustList(const std::vector<Byte>& bytes, std::size_t maxBytes,
                           std::size_t maxElements, TrustListDataType& out) {
    DecodeLimits limits;
    limits.maxStringLength = maxBytes;
    limits.maxArrayLength = maxElements;
    try {
        BinaryDecoder d(bytes.data(), bytes.size(), limits);
        decode(d, out);
        if (d.remaining() != 0) return status::BadDecodingError;
    } catch (const DecodeError&) {
        return status::BadDecodingError;
    }
    if (out.specifiedLists > mask::All) return status::BadInvalidArgument;
    return StatusCode{};
}

StatusCode replaceTrustList(pki::CertificateStore& store, const TrustListDataType& list) {
    // Everything is checked before anything changes.
    std::vector<pki::Certificate> trusted, issuers;
    for (const bool isIssuer : {false, true}) {
        const auto& in = isIssuer ? list.issuerCertificates : list.trustedCertificates;
        auto& out = isIssuer ? issuers : trusted;
        for (const ByteString& der : in) {
            try {
                out.push_back(pki::Certificate::fromDer(view(der)));
            } catch (const std::exception&) {
                return status::BadCertificateInvalid;
            }
            if (StatusCode st = checkListed(out.back()); st.isBad()) return st;
        }
    }
    for (const auto* crls : {&list.trustedCrls, &list.issuerCrls}) {
        for (const ByteString& der : *crls)
            if (!parseDerCrl(der.data(), der.size())) return status::BadCertificateInvalid;
    }
    const std::size_t maxCrl = 1u << 20;
    if (list.specifiedLists & mask::TrustedCertificates) replaceCertificates(store, trusted, false);
    if (list.specifiedLists & mask::IssuerCertificates) replaceCertificates(store, issuers, true);
    if (list.specifiedLists & mask::TrustedCrls)
        replaceCrls(store, list.trustedCrls, false, maxCrl);
    if (list.specifiedLists & mask::IssuerCrls) replaceCrls(store, list.issuerCrls, true, maxCrl);
    return StatusCode{};
}

StatusCode addTrustedCertificate(pki::CertificateStore& store, const ByteString& der) {
    pki::Certificate cert;
    try {
        cert = pki::Certificate::fromDer(view(der));
    } catch (const std::exception&) {
        return status::BadCertificateInvalid;
    }
    if (StatusCode st = checkListed(cert); st.isBad()) return st;
    if (cert.isCa()) return status::BadCertificateUseNotAllowed;
    if (!cert.isSelfSigned()) {
        // Issued by a CA: the CA must be in the trust list already (with its CRL).
        const auto entries = store.list();
        const bool known = std::any_of(entries.begin(), entries.end(), [&](const auto& e) {
            return (e.state == pki::TrustState::Trusted || e.state == pki::TrustState::Issuer) &&
                   issuedBy(cert.native(), e.certificate.native());
        });
        if (!known) return status::BadCertificateChainIncomplete;
    }
    store.addTrusted(cert);
    return StatusCode{};
}

StatusCode removeCertificate(pki::CertificateStore& store, const std::string& thumbprint,
                             bool trustedList) {
    std::string t = thumbprint;
    std::transform(t.begin(), t.end(), t.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (t.size() != 40 || t.find_first_not_of("0123456789abcdef") != std::string::npos)
        return status::BadInvalidArgument;
    const auto state = trustedList ? pki::TrustState::Trusted : pki::TrustState::Issuer;
    const auto entries = store.list();
    std::vector<const pki::StoreEntry*> matches;
    for (const auto& e : entries)
        if (e.state == state && e.certificate.thumbprintHex() == t) matches.push_back(&e);
    if (matches.empty()) return status::BadInvalidArgument;
    const pki::Certificate& cert = matches.front()->certificate;
    if (cert.isCa()) {
        // Still needed by a certificate it issued (that is not itself)?
        for (const auto& e : entries) {
            if ((e.state != pki::TrustState::Trusted && e.state != pki::TrustState::Issuer) ||
                e.certificate == cert)
                continue;
            if (issuedBy(e.certificate.native(), cert.native()))
                return status::BadCertificateChainIncomplete;
        }
    }
    for (const auto* e : matches) {
        std::error_code ec;
        fs::remove(e->file, ec);
    }
    if (cert.isCa()) {
        // Its CRLs (issuer name = the CA's subject) go with it.
        for (const fs::path& file : crlFiles(crlDir(store, !trustedList))) {
            CrlPtr crl = loadCrlFile(file, 1u << 20);
            if (crl && X509_NAME_cmp(X509_CRL_get_issuer(crl.get()),
                                     X509_get_subject_name(cert.native())) == 0) {
                std::error_code ec;
                fs::remove(file, ec);
            }
        }
    }
    return StatusCode{};
}

StatusCode checkApplicationCertificate(const pki::Certificate& leaf,
                                       const std::vector<pki::Certificate>& issuers,
                                       const std::string& applicationUri) {
    X509* x = leaf.native();
    if (x == nullptr || X509_get_version(x) != X509_VERSION_3) return status::BadCertificateInvalid;
    if (!keySizeOk(leaf) || weakSignature(leaf)) return status::BadCertificatePolicyCheckFailed;
    const auto now = std::chrono::system_clock::now();
    if (now < leaf.notBefore() || now > leaf.notAfter()) return status::BadCertificateTimeInvalid;
    const auto uris = leaf.uris();
    if (std::find(uris.begin(), uris.end(), applicationUri) == uris.end())
        return status::BadCertificateUriInvalid;
    const std::uint32_t flags = X509_get_extension_flags(x);
    const std::uint32_t usage = X509_get_key_usage(x);
    constexpr std::uint32_t needed = KU_DIGITAL_SIGNATURE | KU_KEY_ENCIPHERMENT;
    if (leaf.isCa() || !(flags & EXFLAG_KUSAGE) || (usage & needed) != needed ||
        ((flags & EXFLAG_XKUSAGE) && !(X509_get_extended_key_usage(x) & XKU_SSL_SERVER)))
        return status::BadCertificateUseNotAllowed;
    // The chain as given: each certificate issued by the next, the issuers CAs in their
    // validity period; a self-signed leaf verifies itself.
    if (issuers.empty() && leaf.isSelfSigned() && !selfSignatureVerifies(x))
        return status::BadSecurityChecksFailed;
    const pki::Certificate* child = &leaf;
    for (const pki::Certificate& issuer : issuers) {
        if (!issuer.isCa() || !issuedBy(child->native(), issuer.native()))
            return status::BadSecurityChecksFailed;
        if (now < issuer.notBefore() || now > issuer.notAfter())
            return status::BadCertificateIssuerTimeInvalid;
        child = &issuer;
    }
    return StatusCode{};
}

bool sameKey(const pki::Certificate& cert, const crypto::PrivateKey& key) {
    if (!key || cert.native() == nullptr) return false;
    try {
        return cert.publicKey().toDer() == key.publicKey().toDer();
    } catch (const std::exception&) {
        return false;
    }
}

}  // namespace pnp::ua::certificate_management::detail
