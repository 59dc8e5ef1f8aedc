// X.509 certificates: bounded parsing (DER, chains, PEM), accessors, and the creation of
// application instance certificates and CRLs (OPC 10000-6 §6.2.2).
#include <arpa/inet.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/rand.h>
#include <openssl/rsa.h>

#include <algorithm>
#include <cstring>
#include <ctime>
#include <fstream>

#include "openssl_util.hpp"
#include "ua/crypto/openssl_support.hpp"
#include "ua/pki/pki.hpp"

namespace pnp::ua::pki {

namespace detail {

std::string opensslError() { return crypto::detail::openSslErrorText(); }

void check(bool ok, const char* what) {
    if (!ok) throw PkiError(std::string(what) + ": " + opensslError());
}

std::chrono::system_clock::time_point toTimePoint(const ASN1_TIME* t) {
    std::tm tm{};
    if (t == nullptr || ASN1_TIME_to_tm(t, &tm) != 1) return {};
    return std::chrono::system_clock::from_time_t(timegm(&tm));
}

std::string hexLower(const unsigned char* data, std::size_t size) {
    static constexpr char kDigits[] = "0123456789abcdef";
    std::string out;
    out.reserve(size * 2);
    for (std::size_t i = 0; i < size; ++i) {
        out += kDigits[data[i] >> 4];
        out += kDigits[data[i] & 0xF];
    }
    return out;
}

std::shared_ptr<EVP_PKEY> sharePkey(EVP_PKEY* key) {
    if (key == nullptr) return {};
    EVP_PKEY_up_ref(key);
    return std::shared_ptr<EVP_PKEY>(key, EVP_PKEY_free);
}

std::string readFileBounded(const std::filesystem::path& file, std::size_t maxBytes) {
    std::ifstream in(file, std::ios::binary);
    if (!in) throw PkiError("cannot read " + file.string());
    std::string data;
    data.resize(maxBytes + 1);
    in.read(data.data(), static_cast<std::streamsize>(data.size()));
    data.resize(static_cast<std::size_t>(in.gcount()));
    if (data.size() > maxBytes) {
        throw PkiError(file.string() + " is larger than " + std::to_string(maxBytes) + " bytes");
    }
    return data;
}

}  // namespace detail

using namespace detail;

// Builds Certificate objects from an owned X509 (the friend of Certificate).
struct CertificateAccess {
    static Certificate make(X509Ptr cert, Bytes der) {
        Certificate c;
        c.der_ = std::make_shared<const Bytes>(std::move(der));
        c.cert_ = std::shared_ptr<X509>(cert.release(), X509_free);
        return c;
    }
};

namespace {

constexpr std::size_t kMaxChainLength = 8;
constexpr std::size_t kMaxPemSize = 4 * kMaxCertificateSize;  // base64 + headers + comments
constexpr std::size_t kMaxFileSize = 4 * kMaxCertificateSize;

// One certificate from the start of `der`; `consumed` gets its length. Throws PkiError.
Certificate parseOne(ByteView der, std::size_t& consumed) {
    if (der.empty()) throw PkiError("empty certificate");
    const std::size_t limit = std::min(der.size(), kMaxCertificateSize);
    const unsigned char* p = der.data();
    X509Ptr cert(d2i_X509(nullptr, &p, static_cast<long>(limit)));
    if (!cert) {
        ERR_clear_error();
        throw PkiError(der.size() > kMaxCertificateSize
                           ? "certificate larger than " + std::to_string(kMaxCertificateSize) +
                                 " bytes or malformed"
                           : "malformed DER certificate");
    }
    consumed = static_cast<std::size_t>(p - der.data());
    // Extensions that do not decode (or repeat) make the certificate unusable for checks.
    if ((X509_get_extension_flags(cert.get()) & EXFLAG_INVALID) != 0) {
        ERR_clear_error();
        throw PkiError("certificate with malformed extensions");
    }
    if (X509_get0_pubkey(cert.get()) == nullptr) {
        ERR_clear_error();
        throw PkiError("certificate with an unreadable public key");
    }
    return CertificateAccess::make(std::move(cert), Bytes(der.begin(), der.begin() + consumed));
}

std::string asn1ToUtf8(const ASN1_STRING* s) {
    if (s == nullptr) return {};
    unsigned char* out = nullptr;
    const int n = ASN1_STRING_to_UTF8(&out, s);
    if (n < 0) {
        ERR_clear_error();
        return {};
    }
    std::string text(reinterpret_cast<const char*>(out), static_cast<std::size_t>(n));
    OPENSSL_free(out);
    return text;
}

std::string nameToString(const X509_NAME* name) {
    BioPtr bio(BIO_new(BIO_s_mem()));
    if (!bio || name == nullptr) return {};
    // "CN=a, O=b" in the certificate's order, UTF-8 kept as it is.
    const unsigned long flags =
        (XN_FLAG_ONELINE & ~XN_FLAG_SPC_EQ & ~ASN1_STRFLGS_ESC_MSB) | ASN1_STRFLGS_UTF8_CONVERT;
    if (X509_NAME_print_ex(bio.get(), name, 0, flags) < 0) {
        ERR_clear_error();
        return {};
    }
    char* data = nullptr;
    const long n = BIO_get_mem_data(bio.get(), &data);
    return std::string(data, static_cast<std::size_t>(std::max(0L, n)));
}

// SubjectAltName entries of one type, as text.
std::vector<std::string> altNames(X509* cert, int type) {
    std::vector<std::string> out;
    if (cert == nullptr) return out;
    GeneralNamesPtr names(static_cast<GENERAL_NAMES*>(
        X509_get_ext_d2i(cert, NID_subject_alt_name, nullptr, nullptr)));
    if (!names) {
        ERR_clear_error();
        return out;
    }
    for (int i = 0; i < sk_GENERAL_NAME_num(names.get()); ++i) {
        const GENERAL_NAME* n = sk_GENERAL_NAME_value(names.get(), i);
        if (n->type != type) continue;
        if (type == GEN_URI || type == GEN_DNS) {
            const ASN1_IA5STRING* s =
                type == GEN_URI ? n->d.uniformResourceIdentifier : n->d.dNSName;
            out.emplace_back(reinterpret_cast<const char*>(ASN1_STRING_get0_data(s)),
                             static_cast<std::size_t>(ASN1_STRING_length(s)));
        } else if (type == GEN_IPADD) {
            const ASN1_OCTET_STRING* s = n->d.iPAddress;
            const int len = ASN1_STRING_length(s);
            char text[INET6_ADDRSTRLEN] = {};
            const int family = len == 4 ? AF_INET : len == 16 ? AF_INET6 : 0;
            if (family != 0 && inet_ntop(family, ASN1_STRING_get0_data(s), text, sizeof text)) {
                out.emplace_back(text);
            }
        }
    }
    return out;
}

X509* need(const std::shared_ptr<X509>& cert) {
    if (!cert) throw PkiError("empty certificate");
    return cert.get();
}

}  // namespace

// ---------------------------------------------------------------------------------------
Certificate Certificate::fromDer(ByteView der) {
    if (der.size() > kMaxCertificateSize) {
        throw PkiError("certificate of " + std::to_string(der.size()) + " bytes (at most " +
                       std::to_string(kMaxCertificateSize) + ")");
    }
    std::size_t consumed = 0;
    Certificate cert = parseOne(der, consumed);
    if (consumed != der.size()) {
        throw PkiError(std::to_string(der.size() - consumed) + " bytes after the certificate");
    }
    return cert;
}

std::vector<Certificate> Certificate::chainFromDer(ByteView der) {
    if (der.empty()) throw PkiError("empty certificate chain");
    std::vector<Certificate> chain;
    while (!der.empty()) {
        if (chain.size() == kMaxChainLength) {
            throw PkiError("certificate chain longer than " + std::to_string(kMaxChainLength));
        }
        std::size_t consumed = 0;
        chain.push_back(parseOne(der, consumed));
        der = der.subspan(consumed);
    }
    return chain;
}

Certificate Certificate::fromPem(std::string_view pem) {
    if (pem.size() > kMaxPemSize) throw PkiError("PEM text too large");
    BioPtr bio(BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size())));
    check(bio != nullptr, "BIO_new_mem_buf");
    X509Ptr cert(PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr));
    if (!cert) {
        ERR_clear_error();
        throw PkiError("no PEM certificate (-----BEGIN CERTIFICATE-----) found");
    }
    unsigned char* out = nullptr;
    const int n = i2d_X509(cert.get(), &out);
    check(n > 0, "i2d_X509");
    Bytes der(out, out + n);
    OPENSSL_free(out);
    return fromDer(der);
}

Certificate Certificate::load(const std::filesystem::path& file) {
    const std::string data = readFileBounded(file, kMaxFileSize);
    try {
        if (data.find("-----BEGIN") != std::string::npos) return fromPem(data);
        return fromDer(crypto::view(data));
    } catch (const PkiError& e) {
        throw PkiError(file.string() + ": " + e.what());
    }
}

const Bytes& Certificate::der() const {
    static const Bytes kEmpty;
    return der_ ? *der_ : kEmpty;
}

std::string Certificate::toPem() const {
    BioPtr bio(BIO_new(BIO_s_mem()));
    check(bio && PEM_write_bio_X509(bio.get(), need(cert_)) == 1, "PEM_write_bio_X509");
    char* data = nullptr;
    const long n = BIO_get_mem_data(bio.get(), &data);
    return std::string(data, static_cast<std::size_t>(n));
}

Bytes Certificate::thumbprint() const {
    unsigned char md[EVP_MAX_MD_SIZE];
    unsigned int len = 0;
    const Bytes& d = der();
    check(EVP_Digest(d.data(), d.size(), md, &len, EVP_sha1(), nullptr) == 1, "SHA-1");
    return Bytes(md, md + len);
}

std::string Certificate::thumbprintHex() const {
    const Bytes t = thumbprint();
    return hexLower(t.data(), t.size());
}

crypto::PublicKey Certificate::publicKey() const {
    return crypto::PublicKey(sharePkey(X509_get0_pubkey(need(cert_))));
}

int Certificate::keyBits() const {
    EVP_PKEY* key = X509_get0_pubkey(need(cert_));
    return key ? EVP_PKEY_get_bits(key) : 0;
}

std::string Certificate::subject() const {
    return nameToString(X509_get_subject_name(need(cert_)));
}
std::string Certificate::issuer() const { return nameToString(X509_get_issuer_name(need(cert_))); }

std::string Certificate::commonName() const {
    const X509_NAME* name = X509_get_subject_name(need(cert_));
    const int i = X509_NAME_get_index_by_NID(name, NID_commonName, -1);
    if (i < 0) return {};
    return asn1ToUtf8(X509_NAME_ENTRY_get_data(X509_NAME_get_entry(name, i)));
}

std::string Certificate::serialHex() const {
    BignumPtr bn(ASN1_INTEGER_to_BN(X509_get0_serialNumber(need(cert_)), nullptr));
    if (!bn) {
        ERR_clear_error();
        return {};
    }
    char* hex = BN_bn2hex(bn.get());
    std::string s(hex ? hex : "");
    OPENSSL_free(hex);
    std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
    return s;
}

std::chrono::system_clock::time_point Certificate::notBefore() const {
    return toTimePoint(X509_get0_notBefore(need(cert_)));
}
std::chrono::system_clock::time_point Certificate::notAfter() const {
    return toTimePoint(X509_get0_notAfter(need(cert_)));
}

std::vector<std::string> Certificate::uris() const { return altNames(need(cert_), GEN_URI); }
std::vector<std::string> Certificate::dnsNames() const { return altNames(need(cert_), GEN_DNS); }
std::vector<std::string> Certificate::ipAddresses() const {
    return altNames(need(cert_), GEN_IPADD);
}

bool Certificate::isCa() const { return (X509_get_extension_flags(need(cert_)) & EXFLAG_CA) != 0; }

bool Certificate::isSelfSigned() const {
    const int r = X509_self_signed(need(cert_), 1);
    ERR_clear_error();
    return r == 1;
}

std::string Certificate::signatureAlgorithm() const {
    const int nid = X509_get_signature_nid(need(cert_));
    const char* name = nid == NID_undef ? nullptr : OBJ_nid2ln(nid);
    return name ? name : "unknown";
}

// ---------------------------------------------------------------------------------------
namespace {

EvpPkeyPtr ownedKey(const crypto::PrivateKey& key) {
    EVP_PKEY* k = key.native();
    EVP_PKEY_up_ref(k);
    return EvpPkeyPtr(k);
}

crypto::PrivateKey keyFor(const CertificateRequest& request) {
    if (request.key) return request.key;
    if (request.keyBits < 1024 || request.keyBits > 4096) {
        throw PkiError("key size " + std::to_string(request.keyBits) + " bits (1024 .. 4096)");
    }
    EVP_PKEY* key = EVP_RSA_gen(static_cast<unsigned>(request.keyBits));
    check(key != nullptr, "RSA key generation");
    return crypto::PrivateKey(std::shared_ptr<EVP_PKEY>(key, EVP_PKEY_free));
}

void setTime(ASN1_TIME* field, std::chrono::system_clock::time_point t) {
    check(ASN1_TIME_set(field, std::chrono::system_clock::to_time_t(t)) != nullptr,
          "certificate time");
}

// 16 random bytes, positive and without a leading zero byte (so always 16 bytes long).
Asn1IntegerPtr randomSerial() {
    unsigned char bytes[16];
    check(RAND_bytes(bytes, sizeof bytes) == 1, "RAND_bytes");
    bytes[0] = static_cast<unsigned char>((bytes[0] & 0x7F) | 0x40);
    BignumPtr bn(BN_bin2bn(bytes, sizeof bytes, nullptr));
    check(bn != nullptr, "BN_bin2bn");
    Asn1IntegerPtr serial(BN_to_ASN1_INTEGER(bn.get(), nullptr));
    check(serial != nullptr, "BN_to_ASN1_INTEGER");
    return serial;
}

void addExtension(X509* cert, X509V3_CTX* ctx, int nid, const char* value) {
    X509ExtensionPtr ext(X509V3_EXT_conf_nid(nullptr, ctx, nid, value));
    check(ext != nullptr, OBJ_nid2sn(nid));
    check(X509_add_ext(cert, ext.get(), -1) == 1, OBJ_nid2sn(nid));
}

void pushIa5(GENERAL_NAMES* names, int type, const std::string& value) {
    GENERAL_NAME* name = GENERAL_NAME_new();
    ASN1_IA5STRING* s = ASN1_IA5STRING_new();
    if (name == nullptr || s == nullptr ||
        ASN1_STRING_set(s, value.data(), static_cast<int>(value.size())) != 1) {
        GENERAL_NAME_free(name);
        ASN1_IA5STRING_free(s);
        check(false, "SubjectAltName");
    }
    GENERAL_NAME_set0_value(name, type, s);
    if (sk_GENERAL_NAME_push(names, name) == 0) {
        GENERAL_NAME_free(name);
        check(false, "SubjectAltName");
    }
}

void addSubjectAltName(X509* cert, const CertificateRequest& r) {
    GeneralNamesPtr names = subjectAltNames(r);
    if (sk_GENERAL_NAME_num(names.get()) == 0) return;
    check(X509_add1_ext_i2d(cert, NID_subject_alt_name, names.get(), 0, X509V3_ADD_DEFAULT) == 1,
          "SubjectAltName");
}

X509_NAME* makeName(const CertificateRequest& r) {
    X509_NAME* name = X509_NAME_new();
    check(name != nullptr, "X509_NAME_new");
    auto add = [&](const char* field, const std::string& value) {
        if (value.empty()) return;
        if (X509_NAME_add_entry_by_txt(name, field, MBSTRING_UTF8,
                                       reinterpret_cast<const unsigned char*>(value.data()),
                                       static_cast<int>(value.size()), -1, 0) != 1) {
            X509_NAME_free(name);
            throw PkiError(std::string("invalid ") + field + " '" + value +
                           "' (at most 64 characters): " + opensslError());
        }
    };
    add("CN", r.commonName);
    add("O", r.organization);
    return name;
}

Identity create(const CertificateRequest& r, const Identity* issuer) {
    if (r.commonName.empty()) throw PkiError("the certificate needs a common name");
    if (!r.ca && r.applicationUri.empty()) {
        throw PkiError("an application instance certificate needs an ApplicationUri");
    }
    if (r.validity.count() <= 0) throw PkiError("validity must be positive");
    if (issuer != nullptr && (!issuer->certificate.native() || !issuer->key)) {
        throw PkiError("the issuer needs a certificate and its key");
    }
    crypto::PrivateKey key = keyFor(r);

    X509Ptr cert(X509_new());
    check(cert != nullptr, "X509_new");
    check(X509_set_version(cert.get(), X509_VERSION_3) == 1, "X509_set_version");
    check(X509_set_serialNumber(cert.get(), randomSerial().get()) == 1, "serial");
    const auto notBefore =
        r.notBefore.value_or(std::chrono::system_clock::now() - std::chrono::hours(1));
    setTime(X509_getm_notBefore(cert.get()), notBefore);
    setTime(X509_getm_notAfter(cert.get()), notBefore + r.validity);
    {
        X509_NAME* subject = makeName(r);
        const int ok = X509_set_subject_name(cert.get(), subject);
        X509_NAME_free(subject);
        check(ok == 1, "subject");
    }
    X509* issuerCert = issuer ? issuer->certificate.native() : cert.get();
    check(X509_set_issuer_name(cert.get(), X509_get_subject_name(issuerCert)) == 1, "issuer");
    check(X509_set_pubkey(cert.get(), key.native()) == 1, "public key");

    X509V3_CTX ctx;
    X509V3_set_ctx(&ctx, issuerCert, cert.get(), nullptr, nullptr, 0);
    addExtension(cert.get(), &ctx, NID_basic_constraints,
                 r.ca ? "critical,CA:TRUE" : "critical,CA:FALSE");
    // Part 6 Table 50: keyCertSign only for a self-signed application certificate.
    const char* usage = r.ca ? "critical,digitalSignature,keyCertSign,cRLSign"
                        : issuer == nullptr
                            ? "critical,digitalSignature,nonRepudiation,keyEncipherment,"
                              "dataEncipherment,keyCertSign"
                            : "critical,digitalSignature,nonRepudiation,keyEncipherment,"
                              "dataEncipherment";
    addExtension(cert.get(), &ctx, NID_key_usage, usage);
    if (!r.ca) addExtension(cert.get(), &ctx, NID_ext_key_usage, "serverAuth,clientAuth");
    addExtension(cert.get(), &ctx, NID_subject_key_identifier, "hash");
    addExtension(cert.get(), &ctx, NID_authority_key_identifier, "keyid:always");
    addSubjectAltName(cert.get(), r);

    const EvpPkeyPtr signer = ownedKey(issuer ? issuer->key : key);
    check(X509_sign(cert.get(), signer.get(), EVP_sha256()) > 0, "X509_sign");

    unsigned char* out = nullptr;
    const int n = i2d_X509(cert.get(), &out);
    check(n > 0, "i2d_X509");
    Bytes der(out, out + n);
    OPENSSL_free(out);
    return Identity{Certificate::fromDer(der), std::move(key)};
}

}  // namespace

Identity createSelfSigned(const CertificateRequest& request) { return create(request, nullptr); }

Identity createSigned(const CertificateRequest& request, const Identity& issuer) {
    return create(request, &issuer);
}

Bytes createCrl(const Identity& issuer, const std::vector<std::string>& revokedSerialsHex,
                std::chrono::hours validity) {
    if (!issuer.certificate.native() || !issuer.key) {
        throw PkiError("the CRL issuer needs a certificate and its key");
    }
    X509CrlPtr crl(X509_CRL_new());
    check(crl != nullptr, "X509_CRL_new");
    check(X509_CRL_set_version(crl.get(), X509_CRL_VERSION_2) == 1, "CRL version");
    check(X509_CRL_set_issuer_name(crl.get(), X509_get_subject_name(issuer.certificate.native())) ==
              1,
          "CRL issuer");
    const auto now = std::chrono::system_clock::now();
    Asn1TimePtr last(ASN1_TIME_set(
        nullptr, std::chrono::system_clock::to_time_t(now - std::chrono::minutes(5))));
    Asn1TimePtr next(ASN1_TIME_set(nullptr, std::chrono::system_clock::to_time_t(now + validity)));
    check(last && next, "CRL times");
    check(X509_CRL_set1_lastUpdate(crl.get(), last.get()) == 1, "CRL lastUpdate");
    check(X509_CRL_set1_nextUpdate(crl.get(), next.get()) == 1, "CRL nextUpdate");
    for (const std::string& hex : revokedSerialsHex) {
        BIGNUM* raw = nullptr;
        if (hex.empty() || hex.size() > 64 ||
            BN_hex2bn(&raw, hex.c_str()) != static_cast<int>(hex.size())) {
            BN_free(raw);
            throw PkiError("invalid serial number '" + hex + "' (hex)");
        }
        BignumPtr bn(raw);
        Asn1IntegerPtr serial(BN_to_ASN1_INTEGER(bn.get(), nullptr));
        X509RevokedPtr revoked(X509_REVOKED_new());
        check(serial && revoked, "X509_REVOKED_new");
        check(X509_REVOKED_set_serialNumber(revoked.get(), serial.get()) == 1, "revoked serial");
        check(X509_REVOKED_set_revocationDate(revoked.get(), last.get()) == 1, "revocation date");
        check(X509_CRL_add0_revoked(crl.get(), revoked.get()) == 1, "X509_CRL_add0_revoked");
        revoked.release();
    }
    check(X509_CRL_sort(crl.get()) == 1, "X509_CRL_sort");
    X509V3_CTX ctx;
    X509V3_set_ctx(&ctx, issuer.certificate.native(), nullptr, nullptr, crl.get(), 0);
    X509ExtensionPtr aki(
        X509V3_EXT_conf_nid(nullptr, &ctx, NID_authority_key_identifier, "keyid:always"));
    check(aki && X509_CRL_add_ext(crl.get(), aki.get(), -1) == 1, "CRL authorityKeyIdentifier");
    // CRL number: seconds since the epoch, so a later CRL has a larger number.
    Asn1IntegerPtr number(ASN1_INTEGER_new());
    check(number &&
              ASN1_INTEGER_set_int64(number.get(), std::chrono::system_clock::to_time_t(now)) == 1,
          "CRL number");
    check(X509_CRL_add1_ext_i2d(crl.get(), NID_crl_number, number.get(), 0, 0) == 1, "CRL number");
    const EvpPkeyPtr signer = ownedKey(issuer.key);
    check(X509_CRL_sign(crl.get(), signer.get(), EVP_sha256()) > 0, "X509_CRL_sign");
    unsigned char* out = nullptr;
    const int n = i2d_X509_CRL(crl.get(), &out);
    check(n > 0, "i2d_X509_CRL");
    Bytes der(out, out + n);
    OPENSSL_free(out);
    return der;
}

std::string_view toString(TrustState state) {
    switch (state) {
        case TrustState::Trusted:
            return "trusted";
        case TrustState::Rejected:
            return "rejected";
        case TrustState::Issuer:
            return "issuer";
        case TrustState::Own:
            return "own";
        case TrustState::Unknown:
            break;
    }
    return "unknown";
}

namespace detail {

// Built as a structure (no config string: a URI may contain commas).
GeneralNamesPtr subjectAltNames(const CertificateRequest& r) {
    GeneralNamesPtr names(sk_GENERAL_NAME_new_null());
    check(names != nullptr, "SubjectAltName");
    if (!r.applicationUri.empty()) {
        if (r.applicationUri.size() > 4096 || r.applicationUri.find('\0') != std::string::npos)
            throw PkiError("invalid ApplicationUri");
        pushIa5(names.get(), GEN_URI, r.applicationUri);
    }
    for (const std::string& dns : r.dnsNames) {
        if (dns.empty() || dns.size() > 253 || dns.find('\0') != std::string::npos)
            throw PkiError("invalid DNS name '" + dns + "'");
        pushIa5(names.get(), GEN_DNS, dns);
    }
    for (const std::string& ip : r.ipAddresses) {
        ASN1_OCTET_STRING* addr = a2i_IPADDRESS(ip.c_str());
        if (addr == nullptr) {
            ERR_clear_error();
            throw PkiError("invalid IP address '" + ip + "'");
        }
        GENERAL_NAME* name = GENERAL_NAME_new();
        if (name == nullptr) {
            ASN1_OCTET_STRING_free(addr);
            check(false, "SubjectAltName");
        }
        GENERAL_NAME_set0_value(name, GEN_IPADD, addr);
        if (sk_GENERAL_NAME_push(names.get(), name) == 0) {
            GENERAL_NAME_free(name);
            check(false, "SubjectAltName");
        }
    }
    return names;
}

}  // namespace detail

}  // namespace pnp::ua::pki
