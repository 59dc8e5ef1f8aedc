// HMAC-SHA256 with the key prepared once (internal to pnp_ua_crypto; the tests and the
// benchmark use it directly). Two implementations of the same function, both tested against
// RFC 4231 and compared by bench/crypto:
//
// - HmacSha256: the inner and outer SHA-256 states after the padded key block are kept;
//   a message copies them (plain structs) and hashes only its own bytes. No allocation.
// - HmacSha256Evp: an EVP_MAC context holding the key, re-initialised per message. OpenSSL
//   3.0 duplicates (allocates) its digest contexts on every re-initialisation and final.
//
// SymmetricCipher uses HmacSha256, the faster one at every size (bench/crypto, README.md).
#pragma once

#include <cstdint>
#include <memory>

#include "ua/crypto/crypto.hpp"

typedef struct evp_mac_ctx_st EVP_MAC_CTX;

namespace pnp::ua::crypto::detail {

inline constexpr std::size_t kHmacSha256Size = 32;

class HmacSha256 {
  public:
    explicit HmacSha256(ByteView key);  // any length (RFC 2104: longer than 64 is hashed)
    ~HmacSha256();
    HmacSha256(HmacSha256&&) noexcept;
    HmacSha256& operator=(HmacSha256&&) noexcept;

    // kHmacSha256Size bytes into out.
    void mac(ByteView data, std::uint8_t* out) const;

  private:
    struct State;
    std::unique_ptr<State> state_;
};

class HmacSha256Evp {
  public:
    explicit HmacSha256Evp(ByteView key);
    ~HmacSha256Evp();
    HmacSha256Evp(const HmacSha256Evp&) = delete;
    HmacSha256Evp& operator=(const HmacSha256Evp&) = delete;

    void mac(ByteView data, std::uint8_t* out);

  private:
    EVP_MAC_CTX* ctx_ = nullptr;
};

}  // namespace pnp::ua::crypto::detail
