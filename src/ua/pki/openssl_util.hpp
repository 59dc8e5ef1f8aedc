// Internal: RAII for the OpenSSL objects pnp_ua_pki uses, and small shared helpers.
#pragma once

#include <openssl/asn1.h>
#include <openssl/bio.h>
#include <openssl/bn.h>
#include <openssl/evp.h>
#include <openssl/x509.h>
#include <openssl/x509v3.h>

#include <chrono>
#include <memory>
#include <string>

#include "ua/pki/pki.hpp"

namespace pnp::ua::pki::detail {

template <auto Free>
struct Deleter {
    template <typename T>
    void operator()(T* p) const {
        Free(p);
    }
};
template <typename T, auto Free>
using Owned = std::unique_ptr<T, Deleter<Free>>;

using BioPtr = Owned<BIO, BIO_free_all>;
using X509Ptr = Owned<X509, X509_free>;
using X509CrlPtr = Owned<X509_CRL, X509_CRL_free>;
using X509StorePtr = Owned<X509_STORE, X509_STORE_free>;
using X509StoreCtxPtr = Owned<X509_STORE_CTX, X509_STORE_CTX_free>;
using EvpPkeyPtr = Owned<EVP_PKEY, EVP_PKEY_free>;
using BignumPtr = Owned<BIGNUM, BN_free>;
using Asn1IntegerPtr = Owned<ASN1_INTEGER, ASN1_INTEGER_free>;
using Asn1TimePtr = Owned<ASN1_TIME, ASN1_TIME_free>;
using GeneralNamesPtr = Owned<GENERAL_NAMES, GENERAL_NAMES_free>;
using ExtendedKeyUsagePtr = Owned<EXTENDED_KEY_USAGE, EXTENDED_KEY_USAGE_free>;
using X509ExtensionPtr = Owned<X509_EXTENSION, X509_EXTENSION_free>;
using X509RevokedPtr = Owned<X509_REVOKED, X509_REVOKED_free>;
inline void freeX509Stack(STACK_OF(X509) * s) { sk_X509_pop_free(s, X509_free); }
using X509StackPtr = Owned<STACK_OF(X509), freeX509Stack>;

// The SubjectAltName entries of an application instance certificate (certificates and
// signing requests): the ApplicationUri, DNS names, IP addresses. Throws PkiError.
GeneralNamesPtr subjectAltNames(const CertificateRequest& request);

// The message of the last OpenSSL error (and clears the queue), for PkiError texts.
std::string opensslError();

// Throws PkiError("<what>: <OpenSSL error>") when !ok.
void check(bool ok, const char* what);

std::chrono::system_clock::time_point toTimePoint(const ASN1_TIME* t);

std::string hexLower(const unsigned char* data, std::size_t size);

// A shared_ptr owning one reference of `key`.
std::shared_ptr<EVP_PKEY> sharePkey(EVP_PKEY* key);

// Reads at most `maxBytes` of a file; throws PkiError when it is larger or unreadable.
std::string readFileBounded(const std::filesystem::path& file, std::size_t maxBytes);

}  // namespace pnp::ua::pki::detail
