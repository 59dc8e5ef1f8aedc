// The SHA-256 block functions of OpenSSL's low-level API are deprecated in 3.0 (EVP is the
// recommended interface) but present in every 3.x build without no-deprecated. They are the
// same assembly EVP's SHA-256 calls; what they save is EVP_MD_CTX_copy_ex, which allocates a
// new provider context on every copy in OpenSSL 3.0 (two copies per HMAC). Kept to this file.
#define OPENSSL_SUPPRESS_DEPRECATED

#include "ua/crypto/hmac_sha256.hpp"

#include <openssl/core_names.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/params.h>
#include <openssl/sha.h>

#include <array>

#include "ua/crypto/openssl_support.hpp"

namespace pnp::ua::crypto::detail {

namespace {
constexpr std::size_t kShaBlock = 64;
}

struct HmacSha256::State {
    SHA256_CTX inner;  // after (key ^ ipad)
    SHA256_CTX outer;  // after (key ^ opad)
};

HmacSha256::HmacSha256(ByteView key) : state_(std::make_unique<State>()) {
    std::array<std::uint8_t, kShaBlock> block{};
    if (key.size() > kShaBlock) {
        SHA256(key.data(), key.size(), block.data());
    } else if (!key.empty()) {
        std::copy(key.begin(), key.end(), block.begin());
    }
    std::array<std::uint8_t, kShaBlock> pad;
    for (std::size_t i = 0; i < kShaBlock; ++i) pad[i] = block[i] ^ 0x36;
    SHA256_Init(&state_->inner);
    SHA256_Update(&state_->inner, pad.data(), pad.size());
    for (std::size_t i = 0; i < kShaBlock; ++i) pad[i] = block[i] ^ 0x5c;
    SHA256_Init(&state_->outer);
    SHA256_Update(&state_->outer, pad.data(), pad.size());
    OPENSSL_cleanse(block.data(), block.size());
    OPENSSL_cleanse(pad.data(), pad.size());
}

HmacSha256::~HmacSha256() {
    if (state_) OPENSSL_cleanse(state_.get(), sizeof(State));
}
HmacSha256::HmacSha256(HmacSha256&&) noexcept = default;
HmacSha256& HmacSha256::operator=(HmacSha256&& other) noexcept {
    if (this != &other) {
        if (state_) OPENSSL_cleanse(state_.get(), sizeof(State));
        state_ = std::move(other.state_);
    }
    return *this;
}

void HmacSha256::mac(ByteView data, std::uint8_t* out) const {
    if (!state_) throw CryptoError("HMAC-SHA256: moved-from object");
    SHA256_CTX ctx = state_->inner;
    SHA256_Update(&ctx, data.data(), data.size());
    std::array<std::uint8_t, kHmacSha256Size> innerHash;
    SHA256_Final(innerHash.data(), &ctx);
    ctx = state_->outer;
    SHA256_Update(&ctx, innerHash.data(), innerHash.size());
    SHA256_Final(out, &ctx);
    OPENSSL_cleanse(innerHash.data(), innerHash.size());
    OPENSSL_cleanse(&ctx, sizeof ctx);
}

HmacSha256Evp::HmacSha256Evp(ByteView key) {
    ctx_ = EVP_MAC_CTX_new(algorithms().hmac);
    if (!ctx_) throwOpenSsl("EVP_MAC_CTX_new");
    char digest[] = "SHA256";
    const OSSL_PARAM params[] = {OSSL_PARAM_construct_utf8_string(OSSL_MAC_PARAM_DIGEST, digest, 0),
                                 OSSL_PARAM_END};
    // An empty key still needs a non-null pointer: NULL means "keep the previous key".
    static const std::uint8_t kEmpty = 0;
    if (EVP_MAC_init(ctx_, key.empty() ? &kEmpty : key.data(), key.size(), params) != 1) {
        EVP_MAC_CTX_free(ctx_);
        ctx_ = nullptr;
        throwOpenSsl("EVP_MAC_init (HMAC-SHA256)");
    }
}

HmacSha256Evp::~HmacSha256Evp() { EVP_MAC_CTX_free(ctx_); }

void HmacSha256Evp::mac(ByteView data, std::uint8_t* out) {
    std::size_t len = 0;
    if (EVP_MAC_init(ctx_, nullptr, 0, nullptr) != 1 ||
        EVP_MAC_update(ctx_, data.data(), data.size()) != 1 ||
        EVP_MAC_final(ctx_, out, &len, kHmacSha256Size) != 1 || len != kHmacSha256Size) {
        throwOpenSsl("HMAC-SHA256");
    }
}

}  // namespace pnp::ua::crypto::detail
