#include "ua/crypto/crypto.hpp"

#include <openssl/bio.h>
#include <openssl/core_names.h>
#include <openssl/crypto.h>
#include <openssl/err.h>
#include <openssl/evp.h>
#include <openssl/pem.h>
#include <openssl/rand.h>
#include <openssl/rsa.h>
#include <openssl/x509.h>

#include <algorithm>
#include <array>
#include <climits>
#include <cstring>

#include "ua/crypto/hmac_sha256.hpp"
#include "ua/crypto/openssl_support.hpp"

namespace pnp::ua::crypto {

// ---------------------------------------------------------------------------------------
// Shared helpers

namespace detail {

const Algorithms& algorithms() {
    static const Algorithms algs = [] {
        Algorithms a{};
        a.sha1 = EVP_MD_fetch(nullptr, "SHA1", nullptr);
        a.sha256 = EVP_MD_fetch(nullptr, "SHA256", nullptr);
        a.aes128Cbc = EVP_CIPHER_fetch(nullptr, "AES-128-CBC", nullptr);
        a.aes256Cbc = EVP_CIPHER_fetch(nullptr, "AES-256-CBC", nullptr);
        a.hmac = EVP_MAC_fetch(nullptr, "HMAC", nullptr);
        if (!a.sha1 || !a.sha256 || !a.aes128Cbc || !a.aes256Cbc || !a.hmac) {
            EVP_MD_free(a.sha1);
            EVP_MD_free(a.sha256);
            EVP_CIPHER_free(a.aes128Cbc);
            EVP_CIPHER_free(a.aes256Cbc);
            EVP_MAC_free(a.hmac);
            throwOpenSsl("fetching SHA-1, SHA-256, AES-CBC and HMAC from OpenSSL's providers");
        }
        return a;
    }();
    return algs;
}

std::string openSslErrorText() {
    const unsigned long code = ERR_get_error();
    ERR_clear_error();
    if (code == 0) return "unknown OpenSSL error";
    std::array<char, 256> text{};
    ERR_error_string_n(code, text.data(), text.size());
    return text.data();
}

void throwOpenSsl(const char* what) {
    throw CryptoError(std::string(what) + ": " + openSslErrorText());
}

}  // namespace detail

namespace {

using detail::algorithms;
using detail::throwOpenSsl;

struct BioFree {
    void operator()(BIO* b) const { BIO_free(b); }
};
using BioPtr = std::unique_ptr<BIO, BioFree>;
struct PkeyCtxFree {
    void operator()(EVP_PKEY_CTX* c) const { EVP_PKEY_CTX_free(c); }
};
using PkeyCtxPtr = std::unique_ptr<EVP_PKEY_CTX, PkeyCtxFree>;
struct MdCtxFree {
    void operator()(EVP_MD_CTX* c) const { EVP_MD_CTX_free(c); }
};
using MdCtxPtr = std::unique_ptr<EVP_MD_CTX, MdCtxFree>;

std::shared_ptr<EVP_PKEY> ownKey(EVP_PKEY* key) { return {key, EVP_PKEY_free}; }

// Key files are small; anything larger is not a key (and is not read into OpenSSL).
constexpr std::size_t kMaxKeyInput = 1 << 20;
// An OpenSSL length is an int.
constexpr std::size_t kMaxOneShot = INT_MAX;

int toInt(std::size_t n, const char* what) {
    if (n > kMaxOneShot) throw CryptoError(std::string(what) + ": input larger than 2 GiB");
    return static_cast<int>(n);
}

BioPtr memoryBio(const void* data, std::size_t size) {
    BioPtr bio(BIO_new_mem_buf(data, toInt(size, "BIO")));
    if (!bio) throwOpenSsl("BIO_new_mem_buf");
    return bio;
}

Bytes bioContents(BIO* bio) {
    char* data = nullptr;
    long n = BIO_get_mem_data(bio, &data);
    if (n < 0) throwOpenSsl("BIO_get_mem_data");
    return Bytes(reinterpret_cast<std::uint8_t*>(data), reinterpret_cast<std::uint8_t*>(data) + n);
}

void requireRsa(EVP_PKEY* key, const char* what) {
    if (EVP_PKEY_get_base_id(key) != EVP_PKEY_RSA) {
        EVP_PKEY_free(key);
        throw CryptoError(std::string(what) + ": not an RSA key");
    }
}

std::size_t keyBytes(EVP_PKEY* key) { return static_cast<std::size_t>(EVP_PKEY_get_size(key)); }

// The password callback of PEM reading: gives the caller's password and never prompts on a
// terminal (OpenSSL's default when no callback is given).
int pemPassword(char* buf, int size, int /*rwflag*/, void* u) {
    const auto* password = static_cast<const std::string_view*>(u);
    if (password->empty() || password->size() > static_cast<std::size_t>(size)) return -1;
    std::memcpy(buf, password->data(), password->size());
    return static_cast<int>(password->size());
}

const EVP_MD* oaepDigest(AsymmetricEncryption alg) {
    return alg == AsymmetricEncryption::RsaOaepSha1 ? algorithms().sha1 : algorithms().sha256;
}

// An EVP_PKEY_CTX for RSA-OAEP with the algorithm's digest for both OAEP and MGF1.
PkeyCtxPtr oaepContext(EVP_PKEY* key, AsymmetricEncryption alg, bool encrypt) {
    PkeyCtxPtr ctx(EVP_PKEY_CTX_new_from_pkey(nullptr, key, nullptr));
    if (!ctx) throwOpenSsl("EVP_PKEY_CTX_new_from_pkey");
    const EVP_MD* md = oaepDigest(alg);
    if ((encrypt ? EVP_PKEY_encrypt_init(ctx.get()) : EVP_PKEY_decrypt_init(ctx.get())) != 1 ||
        EVP_PKEY_CTX_set_rsa_padding(ctx.get(), RSA_PKCS1_OAEP_PADDING) != 1 ||
        EVP_PKEY_CTX_set_rsa_oaep_md(ctx.get(), md) != 1 ||
        EVP_PKEY_CTX_set_rsa_mgf1_md(ctx.get(), md) != 1) {
        throwOpenSsl("RSA-OAEP set-up");
    }
    return ctx;
}

// Sets the padding of a signature context (PKCS#1 v1.5 is RSA's default).
bool setSignaturePadding(EVP_PKEY_CTX* pctx, AsymmetricSignature alg) {
    if (alg == AsymmetricSignature::RsaPkcs15Sha256) {
        return EVP_PKEY_CTX_set_rsa_padding(pctx, RSA_PKCS1_PADDING) == 1;
    }
    // RSA-PSS-SHA2-256: salt length = digest length (32), MGF1 with SHA-256.
    return EVP_PKEY_CTX_set_rsa_padding(pctx, RSA_PKCS1_PSS_PADDING) == 1 &&
           EVP_PKEY_CTX_set_rsa_pss_saltlen(pctx, 32) == 1 &&
           EVP_PKEY_CTX_set_rsa_mgf1_md(pctx, algorithms().sha256) == 1;
}

Bytes digest(const EVP_MD* md, ByteView data, std::size_t size) {
    Bytes out(size);
    unsigned int len = 0;
    if (EVP_Digest(data.data(), data.size(), out.data(), &len, md, nullptr) != 1 || len != size) {
        throwOpenSsl("EVP_Digest");
    }
    return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------
// Primitives

void randomBytes(std::span<std::uint8_t> out) {
    while (!out.empty()) {
        const std::size_t n = std::min<std::size_t>(out.size(), 1 << 30);
        if (RAND_bytes(out.data(), static_cast<int>(n)) != 1) throwOpenSsl("RAND_bytes");
        out = out.subspan(n);
    }
}

Bytes randomBytes(std::size_t n) {
    Bytes out(n);
    randomBytes(out);
    return out;
}

Bytes sha1(ByteView data) { return digest(algorithms().sha1, data, 20); }
Bytes sha256(ByteView data) { return digest(algorithms().sha256, data, 32); }

bool constantTimeEqual(ByteView a, ByteView b) {
    if (a.size() != b.size()) return false;  // sizes are public (signature sizes)
    if (a.empty()) return true;
    return CRYPTO_memcmp(a.data(), b.data(), a.size()) == 0;
}

Bytes pbkdf2Sha256(std::string_view password, ByteView salt, unsigned iterations,
                   std::size_t length) {
    // Bounds: a stored hash is 32..64 bytes; 10 million iterations take seconds already.
    if (iterations == 0 || iterations > 10'000'000) {
        throw CryptoError("PBKDF2: iterations must be 1 .. 10,000,000");
    }
    if (length == 0 || length > 1024) throw CryptoError("PBKDF2: length must be 1 .. 1024");
    Bytes out(length);
    if (PKCS5_PBKDF2_HMAC(password.data(), toInt(password.size(), "PBKDF2"), salt.data(),
                          toInt(salt.size(), "PBKDF2"), static_cast<int>(iterations),
                          algorithms().sha256, static_cast<int>(length), out.data()) != 1) {
        throwOpenSsl("PKCS5_PBKDF2_HMAC");
    }
    return out;
}

Bytes pSha256(ByteView secret, ByteView seed, std::size_t length) {
    // Key material of a channel is < 100 bytes; bounded so that a bad length cannot run away.
    if (length > (1u << 20)) throw CryptoError("P_SHA256: length above 1 MiB");
    detail::HmacSha256 hmac(secret);
    Bytes out(length);
    // A(1) = HMAC(secret, seed); A(i) = HMAC(secret, A(i-1));
    // output = HMAC(secret, A(1) + seed) + HMAC(secret, A(2) + seed) + ...
    std::array<std::uint8_t, detail::kHmacSha256Size> a;
    hmac.mac(seed, a.data());
    Bytes input(a.size() + seed.size());
    std::copy(seed.begin(), seed.end(), input.begin() + static_cast<std::ptrdiff_t>(a.size()));
    std::array<std::uint8_t, detail::kHmacSha256Size> block;
    for (std::size_t done = 0; done < length;) {
        std::copy(a.begin(), a.end(), input.begin());
        hmac.mac(input, block.data());
        const std::size_t n = std::min(block.size(), length - done);
        std::copy_n(block.begin(), n, out.begin() + static_cast<std::ptrdiff_t>(done));
        done += n;
        hmac.mac(a, a.data());
    }
    OPENSSL_cleanse(a.data(), a.size());
    OPENSSL_cleanse(block.data(), block.size());
    OPENSSL_cleanse(input.data(), input.size());
    return out;
}

// ---------------------------------------------------------------------------------------
// Keys

PrivateKey PrivateKey::generateRsa(int bits) {
    if (bits < 2048 || bits > 4096 || bits % 8 != 0) {
        throw CryptoError("RSA key generation: " + std::to_string(bits) +
                          " bits (2048 .. 4096, a multiple of 8)");
    }
    PkeyCtxPtr ctx(EVP_PKEY_CTX_new_from_name(nullptr, "RSA", nullptr));
    if (!ctx) throwOpenSsl("EVP_PKEY_CTX_new_from_name(RSA)");
    EVP_PKEY* key = nullptr;
    if (EVP_PKEY_keygen_init(ctx.get()) != 1 ||
        EVP_PKEY_CTX_set_rsa_keygen_bits(ctx.get(), bits) != 1 ||
        EVP_PKEY_generate(ctx.get(), &key) != 1) {
        throwOpenSsl("RSA key generation");
    }
    return PrivateKey(ownKey(key));
}

PrivateKey PrivateKey::fromPem(std::string_view pem, std::string_view password) {
    if (pem.size() > kMaxKeyInput) throw CryptoError("private key PEM: larger than 1 MiB");
    BioPtr bio = memoryBio(pem.data(), pem.size());
    EVP_PKEY* key = PEM_read_bio_PrivateKey(bio.get(), nullptr, pemPassword, &password);
    if (!key) {
        throwOpenSsl(password.empty()
                         ? "private key PEM: not a readable (unencrypted) RSA private key"
                         : "private key PEM: not readable with this password");
    }
    requireRsa(key, "private key PEM");
    return PrivateKey(ownKey(key));
}

PrivateKey PrivateKey::fromDer(ByteView der) {
    if (der.size() > kMaxKeyInput) throw CryptoError("private key DER: larger than 1 MiB");
    const unsigned char* p = der.data();
    EVP_PKEY* key = d2i_AutoPrivateKey(nullptr, &p, static_cast<long>(der.size()));
    if (!key) throwOpenSsl("private key DER: neither PKCS#8 nor PKCS#1");
    if (p != der.data() + der.size()) {
        EVP_PKEY_free(key);
        throw CryptoError("private key DER: trailing bytes after the key");
    }
    requireRsa(key, "private key DER");
    return PrivateKey(ownKey(key));
}

std::string PrivateKey::toPem() const {
    if (!key_) throw CryptoError("toPem: empty private key");
    BioPtr bio(BIO_new(BIO_s_mem()));
    if (!bio || PEM_write_bio_PrivateKey(bio.get(), key_.get(), nullptr, nullptr, 0, nullptr,
                                         nullptr) != 1) {
        throwOpenSsl("PEM_write_bio_PrivateKey");
    }
    Bytes b = bioContents(bio.get());
    std::string pem(b.begin(), b.end());
    OPENSSL_cleanse(b.data(), b.size());
    return pem;
}

Bytes PrivateKey::toDer() const {
    if (!key_) throw CryptoError("toDer: empty private key");
    PKCS8_PRIV_KEY_INFO* info = EVP_PKEY2PKCS8(key_.get());
    if (!info) throwOpenSsl("EVP_PKEY2PKCS8");
    unsigned char* der = nullptr;
    const int n = i2d_PKCS8_PRIV_KEY_INFO(info, &der);
    PKCS8_PRIV_KEY_INFO_free(info);
    if (n <= 0) throwOpenSsl("i2d_PKCS8_PRIV_KEY_INFO");
    Bytes out(der, der + n);
    OPENSSL_clear_free(der, static_cast<std::size_t>(n));
    return out;
}

int PrivateKey::bits() const { return key_ ? EVP_PKEY_get_bits(key_.get()) : 0; }

PublicKey PrivateKey::publicKey() const {
    if (!key_) throw CryptoError("publicKey: empty private key");
    // Through the SubjectPublicKeyInfo: the PublicKey holds no private component.
    unsigned char* der = nullptr;
    const int n = i2d_PUBKEY(key_.get(), &der);
    if (n <= 0) throwOpenSsl("i2d_PUBKEY");
    const unsigned char* p = der;
    EVP_PKEY* pub = d2i_PUBKEY(nullptr, &p, n);
    OPENSSL_free(der);
    if (!pub) throwOpenSsl("d2i_PUBKEY");
    return PublicKey(ownKey(pub));
}

PublicKey PublicKey::fromDer(ByteView subjectPublicKeyInfo) {
    if (subjectPublicKeyInfo.size() > kMaxKeyInput) {
        throw CryptoError("public key DER: larger than 1 MiB");
    }
    const unsigned char* p = subjectPublicKeyInfo.data();
    EVP_PKEY* key = d2i_PUBKEY(nullptr, &p, static_cast<long>(subjectPublicKeyInfo.size()));
    if (!key) throwOpenSsl("public key DER: not a SubjectPublicKeyInfo");
    if (p != subjectPublicKeyInfo.data() + subjectPublicKeyInfo.size()) {
        EVP_PKEY_free(key);
        throw CryptoError("public key DER: trailing bytes after the key");
    }
    requireRsa(key, "public key DER");
    return PublicKey(ownKey(key));
}

Bytes PublicKey::toDer() const {
    if (!key_) throw CryptoError("toDer: empty public key");
    unsigned char* der = nullptr;
    const int n = i2d_PUBKEY(key_.get(), &der);
    if (n <= 0) throwOpenSsl("i2d_PUBKEY");
    Bytes out(der, der + n);
    OPENSSL_free(der);
    return out;
}

int PublicKey::bits() const { return key_ ? EVP_PKEY_get_bits(key_.get()) : 0; }

// ---------------------------------------------------------------------------------------
// Asymmetric signatures

Bytes sign(const PrivateKey& key, AsymmetricSignature alg, ByteView data) {
    if (!key) throw CryptoError("sign: empty private key");
    MdCtxPtr ctx(EVP_MD_CTX_new());
    if (!ctx) throwOpenSsl("EVP_MD_CTX_new");
    EVP_PKEY_CTX* pctx = nullptr;  // owned by ctx
    if (EVP_DigestSignInit(ctx.get(), &pctx, algorithms().sha256, nullptr, key.native()) != 1 ||
        !setSignaturePadding(pctx, alg)) {
        throwOpenSsl("signature set-up");
    }
    std::size_t len = keyBytes(key.native());
    Bytes out(len);
    if (EVP_DigestSign(ctx.get(), out.data(), &len, data.data(), data.size()) != 1) {
        throwOpenSsl("EVP_DigestSign");
    }
    out.resize(len);
    return out;
}

bool verify(const PublicKey& key, AsymmetricSignature alg, ByteView data, ByteView signature) {
    if (!key) throw CryptoError("verify: empty public key");
    MdCtxPtr ctx(EVP_MD_CTX_new());
    if (!ctx) throwOpenSsl("EVP_MD_CTX_new");
    EVP_PKEY_CTX* pctx = nullptr;
    if (EVP_DigestVerifyInit(ctx.get(), &pctx, algorithms().sha256, nullptr, key.native()) != 1 ||
        !setSignaturePadding(pctx, alg)) {
        throwOpenSsl("signature verification set-up");
    }
    const bool ok = signature.size() == keyBytes(key.native()) &&
                    EVP_DigestVerify(ctx.get(), signature.data(), signature.size(), data.data(),
                                     data.size()) == 1;
    ERR_clear_error();  // a bad signature queues errors; they must not reach a later call
    return ok;
}

// ---------------------------------------------------------------------------------------
// Asymmetric encryption

std::size_t plainBlockSize(int keyBits, AsymmetricEncryption alg) {
    // OAEP: k - 2*hLen - 2 bytes of message per block.
    const std::size_t overhead = alg == AsymmetricEncryption::RsaOaepSha1 ? 42 : 66;
    const std::size_t bytes = cipherBlockSize(keyBits);
    return bytes > overhead ? bytes - overhead : 0;
}

Bytes encrypt(const PublicKey& key, AsymmetricEncryption alg, ByteView plaintext) {
    if (!key) throw CryptoError("encrypt: empty public key");
    const std::size_t cipherBlock = keyBytes(key.native());
    const std::size_t plainBlock = plainBlockSize(key.bits(), alg);
    if (plainBlock == 0) throw CryptoError("encrypt: key too small for RSA-OAEP");
    PkeyCtxPtr ctx = oaepContext(key.native(), alg, true);
    const std::size_t blocks = (plaintext.size() + plainBlock - 1) / plainBlock;
    Bytes out(blocks * cipherBlock);
    for (std::size_t i = 0; i < blocks; ++i) {
        const ByteView in = plaintext.subspan(
            i * plainBlock, std::min(plainBlock, plaintext.size() - i * plainBlock));
        std::size_t len = cipherBlock;
        if (EVP_PKEY_encrypt(ctx.get(), out.data() + i * cipherBlock, &len, in.data(), in.size()) !=
                1 ||
            len != cipherBlock) {
            throwOpenSsl("EVP_PKEY_encrypt (RSA-OAEP)");
        }
    }
    return out;
}

std::optional<std::size_t> decryptInto(const PrivateKey& key, AsymmetricEncryption alg,
                                       ByteView ciphertext, std::span<std::uint8_t> out) {
    if (!key) throw CryptoError("decrypt: empty private key");
    if (out.size() < ciphertext.size()) {
        throw CryptoError("decryptInto: the output must hold as many bytes as the ciphertext");
    }
    const std::size_t cipherBlock = keyBytes(key.native());
    if (ciphertext.empty() || ciphertext.size() % cipherBlock != 0) return std::nullopt;
    PkeyCtxPtr ctx = oaepContext(key.native(), alg, false);
    // Each block goes through a buffer on the stack, so `out` may be `ciphertext` itself
    // (true in-place decryption) whatever OpenSSL writes into its output buffer.
    std::array<std::uint8_t, 1024> block;  // RSA up to 8192 bits
    if (cipherBlock > block.size()) throw CryptoError("decrypt: RSA key above 8192 bits");
    // Every block is decrypted even after one failed: the time does not tell which one did.
    bool ok = true;
    std::size_t written = 0;
    for (std::size_t offset = 0; offset < ciphertext.size(); offset += cipherBlock) {
        std::size_t len = cipherBlock;
        const bool blockOk = EVP_PKEY_decrypt(ctx.get(), block.data(), &len,
                                              ciphertext.data() + offset, cipherBlock) == 1;
        ok = ok && blockOk;
        if (blockOk) {
            std::memcpy(out.data() + written, block.data(), len);
            written += len;
        }
    }
    OPENSSL_cleanse(block.data(), block.size());
    ERR_clear_error();
    if (!ok) {
        OPENSSL_cleanse(out.data(), written);
        return std::nullopt;
    }
    return written;
}

std::optional<Bytes> decrypt(const PrivateKey& key, AsymmetricEncryption alg, ByteView ciphertext) {
    Bytes out(ciphertext.size());
    const auto n = decryptInto(key, alg, ciphertext, out);
    if (!n) return std::nullopt;
    out.resize(*n);
    return out;
}

// ---------------------------------------------------------------------------------------
// Security policies

namespace {

constexpr std::string_view kRsaSha256Uri = "http://www.w3.org/2001/04/xmldsig-more#rsa-sha256";
constexpr std::string_view kRsaPssSha256Uri =
    "http://opcfoundation.org/UA/security/rsa-pss-sha2-256";
constexpr std::string_view kRsaOaepUri = "http://www.w3.org/2001/04/xmlenc#rsa-oaep";
constexpr std::string_view kRsaOaepSha256Uri =
    "http://opcfoundation.org/UA/security/rsa-oaep-sha2-256";

// Most secure first.
constexpr std::array<SecurityPolicy, 3> kPolicies{{
    {PolicyId::Aes256Sha256RsaPss,
     "http://opcfoundation.org/UA/SecurityPolicy#Aes256_Sha256_RsaPss",
     AsymmetricSignature::RsaPssSha256, kRsaPssSha256Uri, AsymmetricEncryption::RsaOaepSha256,
     kRsaOaepSha256Uri, 32, 32, 16, 32, 32, 2048, 4096},
    {PolicyId::Basic256Sha256, "http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256",
     AsymmetricSignature::RsaPkcs15Sha256, kRsaSha256Uri, AsymmetricEncryption::RsaOaepSha1,
     kRsaOaepUri, 32, 32, 16, 32, 32, 2048, 4096},
    {PolicyId::Aes128Sha256RsaOaep,
     "http://opcfoundation.org/UA/SecurityPolicy#Aes128_Sha256_RsaOaep",
     AsymmetricSignature::RsaPkcs15Sha256, kRsaSha256Uri, AsymmetricEncryption::RsaOaepSha1,
     kRsaOaepUri, 32, 16, 16, 32, 32, 2048, 4096},
}};

}  // namespace

const SecurityPolicy* findPolicy(std::string_view uri) {
    for (const auto& p : kPolicies) {
        if (p.uri == uri) return &p;
    }
    return nullptr;
}

bool isDeprecatedPolicy(std::string_view uri) {
    return uri == "http://opcfoundation.org/UA/SecurityPolicy#Basic128Rsa15" ||
           uri == "http://opcfoundation.org/UA/SecurityPolicy#Basic256";
}

std::span<const SecurityPolicy> securityPolicies() { return kPolicies; }

SymmetricKeys deriveKeys(const SecurityPolicy& policy, ByteView secret, ByteView seed) {
    Bytes material = pSha256(
        secret, seed, policy.signingKeyLength + policy.encryptingKeyLength + policy.blockSize);
    const auto begin = material.begin();
    const auto signingEnd = begin + static_cast<std::ptrdiff_t>(policy.signingKeyLength);
    const auto encryptingEnd = signingEnd + static_cast<std::ptrdiff_t>(policy.encryptingKeyLength);
    SymmetricKeys keys{Bytes(begin, signingEnd), Bytes(signingEnd, encryptingEnd),
                       Bytes(encryptingEnd, material.end())};
    OPENSSL_cleanse(material.data(), material.size());
    return keys;
}

// ---------------------------------------------------------------------------------------
// SymmetricCipher: everything keyed is set up here once; a message only resets the IV (the
// AES key schedule stays in the contexts) and copies the prepared HMAC states.

struct SymmetricCipher::Impl {
    detail::HmacSha256 hmac;
    EVP_CIPHER_CTX* encryptCtx = nullptr;
    EVP_CIPHER_CTX* decryptCtx = nullptr;
    std::array<std::uint8_t, 16> iv{};

    Impl(const SecurityPolicy& policy, const SymmetricKeys& keys) : hmac(keys.signingKey) {
        if (policy.id == PolicyId::None || policy.blockSize != iv.size()) {
            throw CryptoError("SymmetricCipher: not a supported security policy");
        }
        if (keys.encryptingKey.size() != policy.encryptingKeyLength ||
            (keys.encryptingKey.size() != 16 && keys.encryptingKey.size() != 32)) {
            throw CryptoError(
                "SymmetricCipher: encrypting key of " + std::to_string(keys.encryptingKey.size()) +
                " bytes, the policy needs " + std::to_string(policy.encryptingKeyLength));
        }
        if (keys.iv.size() != iv.size()) {
            throw CryptoError("SymmetricCipher: the IV must be 16 bytes");
        }
        if (keys.signingKey.empty()) throw CryptoError("SymmetricCipher: empty signing key");
        std::copy(keys.iv.begin(), keys.iv.end(), iv.begin());
        const EVP_CIPHER* cipher =
            keys.encryptingKey.size() == 16 ? algorithms().aes128Cbc : algorithms().aes256Cbc;
        encryptCtx = EVP_CIPHER_CTX_new();
        decryptCtx = EVP_CIPHER_CTX_new();
        if (!encryptCtx || !decryptCtx ||
            EVP_EncryptInit_ex2(encryptCtx, cipher, keys.encryptingKey.data(), iv.data(),
                                nullptr) != 1 ||
            EVP_DecryptInit_ex2(decryptCtx, cipher, keys.encryptingKey.data(), iv.data(),
                                nullptr) != 1 ||
            EVP_CIPHER_CTX_set_padding(encryptCtx, 0) != 1 ||
            EVP_CIPHER_CTX_set_padding(decryptCtx, 0) != 1) {
            freeContexts();
            throwOpenSsl("AES-CBC set-up");
        }
    }
    ~Impl() { freeContexts(); }
    Impl(const Impl&) = delete;
    Impl& operator=(const Impl&) = delete;

    void freeContexts() {
        EVP_CIPHER_CTX_free(encryptCtx);  // frees (and cleanses) the key schedule
        EVP_CIPHER_CTX_free(decryptCtx);
        encryptCtx = decryptCtx = nullptr;
    }

    void run(EVP_CIPHER_CTX* ctx, bool encrypt, std::span<std::uint8_t> inout) const {
        if (inout.size() % iv.size() != 0) {
            throw CryptoError("AES-CBC: " + std::to_string(inout.size()) +
                              " bytes, not a multiple of the 16-byte block");
        }
        if (inout.empty()) return;
        // NULL cipher and key: only the IV (and the context's position) is reset.
        const int init = encrypt ? EVP_EncryptInit_ex2(ctx, nullptr, nullptr, iv.data(), nullptr)
                                 : EVP_DecryptInit_ex2(ctx, nullptr, nullptr, iv.data(), nullptr);
        int len = 0;
        if (init != 1 ||
            EVP_CipherUpdate(ctx, inout.data(), &len, inout.data(), toInt(inout.size(), "AES")) !=
                1 ||
            static_cast<std::size_t>(len) != inout.size()) {
            throwOpenSsl("AES-CBC");
        }
    }
};

SymmetricCipher::SymmetricCipher(const SecurityPolicy& policy, const SymmetricKeys& keys)
    : impl_(std::make_unique<Impl>(policy, keys)) {}
SymmetricCipher::~SymmetricCipher() = default;
SymmetricCipher::SymmetricCipher(SymmetricCipher&&) noexcept = default;
SymmetricCipher& SymmetricCipher::operator=(SymmetricCipher&&) noexcept = default;

void SymmetricCipher::sign(ByteView data, std::uint8_t* out) {
    if (!impl_) throw CryptoError("SymmetricCipher: moved-from object");
    impl_->hmac.mac(data, out);
}

bool SymmetricCipher::verify(ByteView data, ByteView signature) {
    if (!impl_) throw CryptoError("SymmetricCipher: moved-from object");
    std::array<std::uint8_t, detail::kHmacSha256Size> expected;
    impl_->hmac.mac(data, expected.data());
    return constantTimeEqual(expected, signature);
}

void SymmetricCipher::encrypt(std::span<std::uint8_t> inout) {
    if (!impl_) throw CryptoError("SymmetricCipher: moved-from object");
    impl_->run(impl_->encryptCtx, true, inout);
}

void SymmetricCipher::decrypt(std::span<std::uint8_t> inout) {
    if (!impl_) throw CryptoError("SymmetricCipher: moved-from object");
    impl_->run(impl_->decryptCtx, false, inout);
}

}  // namespace pnp::ua::crypto
