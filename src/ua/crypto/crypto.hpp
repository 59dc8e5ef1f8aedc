// OPC UA's cryptography (OPC 10000-6 §6.1, §6.7.5; OPC 10000-7 security policy profiles) on
// OpenSSL 3: RSA keys, the asymmetric signature and encryption algorithms of the supported
// security policies, P_SHA256 key derivation, and symmetric contexts that are prepared once
// per key (not per message), so a small message pays only for its bytes.
//
// Errors: internal OpenSSL failures throw CryptoError; a signature that does not verify or a
// ciphertext that does not decrypt is a normal outcome (false / nullopt), never an exception,
// and the same outcome whatever was wrong (no padding oracle).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

typedef struct evp_pkey_st EVP_PKEY;

namespace pnp::ua::crypto {

using Bytes = std::vector<std::uint8_t>;
using ByteView = std::span<const std::uint8_t>;

inline ByteView view(std::string_view s) {
    return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

class CryptoError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

// Cryptographically secure random bytes (RAND_bytes). Throws CryptoError.
void randomBytes(std::span<std::uint8_t> out);
Bytes randomBytes(std::size_t n);

Bytes sha1(ByteView data);    // 20 bytes (certificate thumbprints)
Bytes sha256(ByteView data);  // 32 bytes

// Compares in time independent of the contents (equal sizes required for true).
bool constantTimeEqual(ByteView a, ByteView b);

// PBKDF2-HMAC-SHA256 (password hashes of the user store).
Bytes pbkdf2Sha256(std::string_view password, ByteView salt, unsigned iterations,
                   std::size_t length);

// P_SHA256 of RFC 5246 §5 (OPC 10000-6 §6.7.5): `length` bytes from secret and seed.
Bytes pSha256(ByteView secret, ByteView seed, std::size_t length);

class PublicKey;

// An RSA private key (RAII around EVP_PKEY; copies share the key, which is immutable).
class PrivateKey {
  public:
    static PrivateKey generateRsa(int bits);  // 2048 .. 4096
    // PEM (PKCS#8 or traditional RSA, optionally encrypted with `password`) or DER (PKCS#8
    // or PKCS#1). Throws CryptoError with a clear message on anything else.
    static PrivateKey fromPem(std::string_view pem, std::string_view password = {});
    static PrivateKey fromDer(ByteView der);
    std::string toPem() const;  // unencrypted PKCS#8 (the file is protected by its mode)
    Bytes toDer() const;        // PKCS#8
    int bits() const;
    PublicKey publicKey() const;
    EVP_PKEY* native() const { return key_.get(); }
    explicit operator bool() const { return key_ != nullptr; }

    PrivateKey() = default;
    explicit PrivateKey(std::shared_ptr<EVP_PKEY> key) : key_(std::move(key)) {}

  private:
    std::shared_ptr<EVP_PKEY> key_;
};

// An RSA public key.
class PublicKey {
  public:
    static PublicKey fromDer(ByteView subjectPublicKeyInfo);  // throws CryptoError
    Bytes toDer() const;                                      // SubjectPublicKeyInfo
    int bits() const;
    EVP_PKEY* native() const { return key_.get(); }
    explicit operator bool() const { return key_ != nullptr; }

    PublicKey() = default;
    explicit PublicKey(std::shared_ptr<EVP_PKEY> key) : key_(std::move(key)) {}

  private:
    std::shared_ptr<EVP_PKEY> key_;
};

// The asymmetric algorithms of the supported policies.
enum class AsymmetricSignature {
    RsaPkcs15Sha256,  // http://www.w3.org/2001/04/xmldsig-more#rsa-sha256
    RsaPssSha256,     // http://opcfoundation.org/UA/security/rsa-pss-sha2-256
};
enum class AsymmetricEncryption {
    RsaOaepSha1,    // http://www.w3.org/2001/04/xmlenc#rsa-oaep
    RsaOaepSha256,  // http://opcfoundation.org/UA/security/rsa-oaep-sha2-256
};

// Signature size = the key's size in bytes.
Bytes sign(const PrivateKey& key, AsymmetricSignature alg, ByteView data);
bool verify(const PublicKey& key, AsymmetricSignature alg, ByteView data, ByteView signature);

// RSA-OAEP over plaintext blocks of plainBlockSize(), each giving one cipher block of the
// key's size (OPC 10000-6 §6.7.2.5: a message is encrypted block by block).
std::size_t plainBlockSize(int keyBits, AsymmetricEncryption alg);  // bytes - 42 / - 66
inline std::size_t cipherBlockSize(int keyBits) { return static_cast<std::size_t>(keyBits) / 8; }
Bytes encrypt(const PublicKey& key, AsymmetricEncryption alg, ByteView plaintext);
// nullopt when any block fails to decrypt (the same outcome whatever failed).
std::optional<Bytes> decrypt(const PrivateKey& key, AsymmetricEncryption alg, ByteView ciphertext);
// In place (no allocation per message on the hot path): `out` must hold
// ciphertext.size() bytes; returns the plaintext length, nullopt on failure.
std::optional<std::size_t> decryptInto(const PrivateKey& key, AsymmetricEncryption alg,
                                       ByteView ciphertext, std::span<std::uint8_t> out);

// ---------------------------------------------------------------------------------------
// Security policies (OPC 10000-7). Basic128Rsa15 and Basic256 are deprecated and refused.
enum class PolicyId { None, Basic256Sha256, Aes128Sha256RsaOaep, Aes256Sha256RsaPss };

struct SecurityPolicy {
    PolicyId id;
    std::string_view uri;
    AsymmetricSignature asymmetricSignature;
    std::string_view asymmetricSignatureUri;  // SignatureData.Algorithm in sessions
    AsymmetricEncryption asymmetricEncryption;
    std::string_view asymmetricEncryptionUri;  // UserNameIdentityToken.EncryptionAlgorithm
    std::size_t signingKeyLength;              // symmetric HMAC-SHA256 key: 32
    std::size_t encryptingKeyLength;           // AES-CBC key: 32 / 16 / 32
    std::size_t blockSize;                     // AES block: 16
    std::size_t signatureSize;                 // HMAC-SHA256: 32
    std::size_t nonceLength;                   // 32
    int minKeyBits;                            // 2048
    int maxKeyBits;                            // 4096
};

inline constexpr std::string_view kNoneUri = "http://opcfoundation.org/UA/SecurityPolicy#None";

// The policy with that URI; nullptr for None, unknown and deprecated URIs.
const SecurityPolicy* findPolicy(std::string_view uri);
bool isDeprecatedPolicy(std::string_view uri);  // Basic128Rsa15, Basic256
// Every supported policy except None, most secure first
// (Aes256_Sha256_RsaPss, Basic256Sha256, Aes128_Sha256_RsaOaep).
std::span<const SecurityPolicy> securityPolicies();

// The keys of one direction of a channel (OPC 10000-6 §6.7.5): the client's keys are
// derive(serverNonce, clientNonce), the server's derive(clientNonce, serverNonce).
struct SymmetricKeys {
    Bytes signingKey;
    Bytes encryptingKey;
    Bytes iv;
};
SymmetricKeys deriveKeys(const SecurityPolicy& policy, ByteView secret, ByteView seed);

// HMAC-SHA256 + AES-CBC with one direction's keys, prepared once (cipher and MAC contexts
// set up here, only the IV / state reset per message). Not thread-safe: one per channel
// direction and token.
class SymmetricCipher {
  public:
    SymmetricCipher(const SecurityPolicy& policy, const SymmetricKeys& keys);
    ~SymmetricCipher();
    SymmetricCipher(SymmetricCipher&&) noexcept;
    SymmetricCipher& operator=(SymmetricCipher&&) noexcept;

    std::size_t signatureSize() const { return 32; }
    std::size_t blockSize() const { return 16; }
    // HMAC-SHA256 of data into out (signatureSize() bytes).
    void sign(ByteView data, std::uint8_t* out);
    // Constant-time comparison.
    bool verify(ByteView data, ByteView signature);
    // AES-CBC in place with the keys' IV; size a multiple of blockSize() (else CryptoError).
    void encrypt(std::span<std::uint8_t> inout);
    void decrypt(std::span<std::uint8_t> inout);

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::ua::crypto
