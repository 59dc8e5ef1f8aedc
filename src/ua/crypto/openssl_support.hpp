// OpenSSL helpers shared by the files of pnp_ua_crypto (internal; pnp_ua_pki uses the error
// text too).
#pragma once

#include <string>

typedef struct evp_md_st EVP_MD;
typedef struct evp_cipher_st EVP_CIPHER;
typedef struct evp_mac_st EVP_MAC;

namespace pnp::ua::crypto::detail {

// The algorithm objects, fetched from the default library context once per process: a fetch
// is a locked name lookup, far too slow for a message (and EVP_sha256() and friends would
// repeat it inside every *Init call).
struct Algorithms {
    EVP_MD* sha1;
    EVP_MD* sha256;
    EVP_CIPHER* aes128Cbc;
    EVP_CIPHER* aes256Cbc;
    EVP_MAC* hmac;
};
const Algorithms& algorithms();  // throws CryptoError if a provider lacks one

// The text of OpenSSL's first queued error ("unknown OpenSSL error" if none); empties the
// queue, so nothing of this failure is left for a later call to find.
std::string openSslErrorText();

// Throws CryptoError("<what>: <OpenSSL's first error>") and empties OpenSSL's error queue,
// so nothing of this failure is left for a later call to find.
[[noreturn]] void throwOpenSsl(const char* what);

}  // namespace pnp::ua::crypto::detail
