// SymmetricCipher's per-message work allocates nothing: OpenSSL's allocator is replaced by a
// counting one (CRYPTO_set_mem_functions must run before OpenSSL's first allocation, hence
// this program's own main), then messages of every size are signed, encrypted, decrypted
// and verified while the count must not move. The one-shot way is counted as a control, so
// that the counter is shown to see OpenSSL's allocations at all.
#include <gtest/gtest.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>

#include <atomic>
#include <cstdlib>

#include "ua/crypto/crypto.hpp"

namespace {

std::atomic<long> gAllocations{0};

void* countingMalloc(std::size_t n, const char*, int) {
    ++gAllocations;
    return std::malloc(n);
}
void* countingRealloc(void* p, std::size_t n, const char*, int) {
    ++gAllocations;
    return std::realloc(p, n);
}
void countingFree(void* p, const char*, int) { std::free(p); }

using namespace pnp::ua::crypto;

TEST(SymmetricCipherAllocations, NonePerMessage) {
    for (const auto& policy : securityPolicies()) {
        SCOPED_TRACE(std::string(policy.uri));
        SymmetricCipher cipher(policy, deriveKeys(policy, randomBytes(32), randomBytes(32)));
        std::vector<std::uint8_t> message(32768, 0x11);
        std::array<std::uint8_t, 32> mac{};
        // Warm-up: anything OpenSSL sets up lazily on first use is not per message.
        cipher.sign(message, mac.data());
        cipher.encrypt(message);
        cipher.decrypt(message);
        const long before = gAllocations.load();
        for (std::size_t size : {16u, 64u, 1024u, 8192u, 32768u}) {
            std::span<std::uint8_t> m(message.data(), size);
            for (int i = 0; i < 10; ++i) {
                cipher.sign(m, mac.data());
                cipher.encrypt(m);
                cipher.decrypt(m);
                EXPECT_TRUE(cipher.verify(m, mac));
            }
        }
        EXPECT_EQ(gAllocations.load() - before, 0) << "OpenSSL allocations per message";
    }
}

TEST(SymmetricCipherAllocations, TheCounterSeesOpenSslAllocations) {
    const Bytes key(32, 1), iv(16, 2);
    std::vector<std::uint8_t> message(64, 3);
    const long before = gAllocations.load();
    EVP_CIPHER_CTX* ctx = EVP_CIPHER_CTX_new();
    int len = 0;
    EVP_EncryptInit_ex(ctx, EVP_aes_256_cbc(), nullptr, key.data(), iv.data());
    EVP_EncryptUpdate(ctx, message.data(), &len, message.data(), 64);
    EVP_CIPHER_CTX_free(ctx);
    EXPECT_GT(gAllocations.load() - before, 0);
}

}  // namespace

int main(int argc, char** argv) {
    if (CRYPTO_set_mem_functions(countingMalloc, countingRealloc, countingFree) != 1) {
        std::fprintf(stderr, "CRYPTO_set_mem_functions failed (OpenSSL allocated already)\n");
        return 1;
    }
    ::testing::InitGoogleTest(&argc, argv);
    return RUN_ALL_TESTS();
}
