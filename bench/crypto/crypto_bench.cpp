// pnp_bench_crypto: the cost of securing one OPC UA message, per message size, with
// SymmetricCipher (contexts prepared once per key) next to the one-shot way (key set up for
// every message) measured in the same run; the HMAC-SHA256 and AES-CBC variants
// SymmetricCipher was chosen from; and RSA-2048 signature / OAEP medians.
//
// Sizes are the signed bytes; the encrypted bytes are the size rounded up to the 16-byte AES
// block (a message is padded before encryption). Each figure is the median over 31 rounds
// of the time per message of a round (a round: enough messages for ~1 ms), the variants of a
// table interleaved round by round.
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <functional>
#include <string>
#include <vector>

#include "ua/crypto/crypto.hpp"
#include "ua/crypto/hmac_sha256.hpp"

using namespace pnp::ua::crypto;
using Clock = std::chrono::steady_clock;

namespace {

volatile std::uint8_t gSink;  // keeps results alive

// The median per-call time (ns) of each op. The ops are measured in interleaved rounds
// (op 1, op 2, ..., op 1, ...) so that load from other processes of this shared machine falls
// on all of them alike; a round is ~1 ms of calls.
std::vector<double> medianNs(const std::vector<std::function<void()>>& ops, int rounds = 31) {
    std::vector<int> calls(ops.size(), 1);
    for (std::size_t k = 0; k < ops.size(); ++k) {
        for (;;) {
            const auto t0 = Clock::now();
            for (int i = 0; i < calls[k]; ++i) ops[k]();
            const auto ns = std::chrono::duration<double, std::nano>(Clock::now() - t0).count();
            if (ns > 1e6 || calls[k] >= (1 << 20)) break;
            calls[k] *= 2;
        }
    }
    std::vector<std::vector<double>> perCall(ops.size());
    for (int r = 0; r < rounds; ++r) {
        for (std::size_t k = 0; k < ops.size(); ++k) {
            const auto t0 = Clock::now();
            for (int i = 0; i < calls[k]; ++i) ops[k]();
            perCall[k].push_back(
                std::chrono::duration<double, std::nano>(Clock::now() - t0).count() / calls[k]);
        }
    }
    std::vector<double> medians;
    for (auto& v : perCall) {
        std::nth_element(v.begin(), v.begin() + rounds / 2, v.end());
        medians.push_back(v[static_cast<std::size_t>(rounds / 2)]);
    }
    return medians;
}

double medianNs(const std::function<void()>& op, int rounds = 31) {
    return medianNs(std::vector<std::function<void()>>{op}, rounds)[0];
}

std::string us(double ns) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.2f", ns / 1000.0);
    return buf;
}
std::string mbps(std::size_t bytes, double ns) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.0f", static_cast<double>(bytes) / ns * 1000.0);
    return buf;
}

std::size_t padded(std::size_t n) { return (n + 15) / 16 * 16; }

// ---- the one-shot baseline: what a stack does that keys OpenSSL for every message --------

void oneShotSignEncrypt(const SymmetricKeys& k, std::uint8_t* msg, std::size_t signLen,
                        std::size_t encLen, std::uint8_t* mac) {
    unsigned int macLen = 0;
    HMAC(EVP_sha256(), k.signingKey.data(), static_cast<int>(k.signingKey.size()), msg, signLen,
         mac, &macLen);
    EVP_CIPHER_CTX* ctx = EVP_CIPHER_CTX_new();
    int len = 0;
    EVP_EncryptInit_ex(ctx, EVP_aes_256_cbc(), nullptr, k.encryptingKey.data(), k.iv.data());
    EVP_CIPHER_CTX_set_padding(ctx, 0);
    EVP_EncryptUpdate(ctx, msg, &len, msg, static_cast<int>(encLen));
    EVP_EncryptFinal_ex(ctx, msg + len, &len);
    EVP_CIPHER_CTX_free(ctx);
}

bool oneShotDecryptVerify(const SymmetricKeys& k, std::uint8_t* msg, std::size_t signLen,
                          std::size_t encLen, const std::uint8_t* mac) {
    EVP_CIPHER_CTX* ctx = EVP_CIPHER_CTX_new();
    int len = 0;
    EVP_DecryptInit_ex(ctx, EVP_aes_256_cbc(), nullptr, k.encryptingKey.data(), k.iv.data());
    EVP_CIPHER_CTX_set_padding(ctx, 0);
    EVP_DecryptUpdate(ctx, msg, &len, msg, static_cast<int>(encLen));
    EVP_DecryptFinal_ex(ctx, msg + len, &len);
    EVP_CIPHER_CTX_free(ctx);
    std::uint8_t expected[32];
    unsigned int macLen = 0;
    HMAC(EVP_sha256(), k.signingKey.data(), static_cast<int>(k.signingKey.size()), msg, signLen,
         expected, &macLen);
    return CRYPTO_memcmp(expected, mac, 32) == 0;
}

// ---- HMAC variants ----------------------------------------------------------------------

// EVP_MAC_CTX_dup of a keyed template per message.
struct HmacDupTemplate {
    EVP_MAC_CTX* tmpl;
    explicit HmacDupTemplate(const pnp::ua::crypto::Bytes& key) {
        EVP_MAC* mac = EVP_MAC_fetch(nullptr, "HMAC", nullptr);
        tmpl = EVP_MAC_CTX_new(mac);
        EVP_MAC_free(mac);
        char digest[] = "SHA256";
        OSSL_PARAM params[] = {OSSL_PARAM_construct_utf8_string("digest", digest, 0),
                               OSSL_PARAM_construct_end()};
        EVP_MAC_init(tmpl, key.data(), key.size(), params);
    }
    ~HmacDupTemplate() { EVP_MAC_CTX_free(tmpl); }
    void mac(ByteView data, std::uint8_t* out) const {
        EVP_MAC_CTX* c = EVP_MAC_CTX_dup(tmpl);
        std::size_t len = 0;
        EVP_MAC_update(c, data.data(), data.size());
        EVP_MAC_final(c, out, &len, 32);
        EVP_MAC_CTX_free(c);
    }
};

// Hand-made HMAC from two prepared EVP_MD_CTX states, restored with EVP_MD_CTX_copy_ex.
struct HmacMdCopy {
    EVP_MD_CTX* inner = EVP_MD_CTX_new();
    EVP_MD_CTX* outer = EVP_MD_CTX_new();
    EVP_MD_CTX* work = EVP_MD_CTX_new();
    EVP_MD* md = EVP_MD_fetch(nullptr, "SHA256", nullptr);
    explicit HmacMdCopy(const pnp::ua::crypto::Bytes& key) {
        std::array<std::uint8_t, 64> block{}, pad{};
        std::copy(key.begin(), key.end(), block.begin());  // keys here are <= 64 bytes
        for (int i = 0; i < 64; ++i) pad[i] = block[i] ^ 0x36;
        EVP_DigestInit_ex2(inner, md, nullptr);
        EVP_DigestUpdate(inner, pad.data(), 64);
        for (int i = 0; i < 64; ++i) pad[i] = block[i] ^ 0x5c;
        EVP_DigestInit_ex2(outer, md, nullptr);
        EVP_DigestUpdate(outer, pad.data(), 64);
    }
    ~HmacMdCopy() {
        EVP_MD_CTX_free(inner);
        EVP_MD_CTX_free(outer);
        EVP_MD_CTX_free(work);
        EVP_MD_free(md);
    }
    void mac(ByteView data, std::uint8_t* out) const {
        std::uint8_t ih[32];
        unsigned int len = 0;
        EVP_MD_CTX_copy_ex(work, inner);
        EVP_DigestUpdate(work, data.data(), data.size());
        EVP_DigestFinal_ex(work, ih, &len);
        EVP_MD_CTX_copy_ex(work, outer);
        EVP_DigestUpdate(work, ih, 32);
        EVP_DigestFinal_ex(work, out, &len);
    }
};

}  // namespace

int main() {
    const SecurityPolicy& policy =
        *findPolicy("http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256");
    const SymmetricKeys keys = deriveKeys(policy, randomBytes(32), randomBytes(32));
    SymmetricCipher cipher(policy, keys);
    const std::size_t sizes[] = {2, 64, 1024, 8192, 32768};

    std::printf(
        "pnp_bench_crypto (%s), Basic256Sha256 (HMAC-SHA256 + AES-256-CBC), median of 31 "
        "interleaved rounds\n\n",
        OpenSSL_version(OPENSSL_VERSION));
    std::printf("Secured message (sign+encrypt / decrypt+verify), us per message and MB/s\n");
    std::printf("%8s | %12s %12s %8s | %12s %12s %8s | %9s %9s\n", "bytes", "ours s+e", "1shot s+e",
                "ours MB/s", "ours d+v", "1shot d+v", "ours MB/s", "s+e gain", "d+v gain");
    for (std::size_t size : sizes) {
        const std::size_t enc = padded(size);
        std::vector<std::uint8_t> msg(enc, 0x5a);
        std::array<std::uint8_t, 32> mac{}, scratchMac{};
        // decrypt+verify of a real ciphertext each time: a copy of it (the copy's time is
        // measured and taken off).
        std::vector<std::uint8_t> sealed(enc, 0x5a);
        cipher.sign(ByteView(sealed.data(), size), mac.data());
        cipher.encrypt(sealed);
        std::vector<std::uint8_t> work(enc);
        const auto t = medianNs({
            [&] {
                cipher.sign(ByteView(msg.data(), size), scratchMac.data());
                cipher.encrypt(msg);
                gSink = msg[0];
            },
            [&] {
                oneShotSignEncrypt(keys, msg.data(), size, enc, scratchMac.data());
                gSink = msg[0];
            },
            [&] {
                std::memcpy(work.data(), sealed.data(), enc);
                cipher.decrypt(work);
                gSink = cipher.verify(ByteView(work.data(), size), mac);
            },
            [&] {
                std::memcpy(work.data(), sealed.data(), enc);
                gSink = oneShotDecryptVerify(keys, work.data(), size, enc, mac.data());
            },
            [&] {
                std::memcpy(work.data(), sealed.data(), enc);
                gSink = work[0];
            },
        });
        const double oursSe = t[0], oneSe = t[1], oursDv = t[2], oneDv = t[3], copyNs = t[4];
        const double dv = oursDv - copyNs, oneDvNet = oneDv - copyNs;
        std::printf("%8zu | %12s %12s %8s | %12s %12s %8s | %8.2fx %8.2fx\n", size,
                    us(oursSe).c_str(), us(oneSe).c_str(), mbps(size, oursSe).c_str(),
                    us(dv).c_str(), us(oneDvNet).c_str(), mbps(size, dv).c_str(), oneSe / oursSe,
                    oneDvNet / dv);
    }

    std::printf("\nHMAC-SHA256 variants (key prepared once unless one-shot), us per message\n");
    std::printf("%8s | %10s %10s %10s %10s %10s | %8s\n", "bytes", "SHA256_CTX", "MAC reinit",
                "MAC dup", "MD copy", "HMAC()", "MB/s");
    detail::HmacSha256 fast(keys.signingKey);
    detail::HmacSha256Evp evp(keys.signingKey);
    HmacDupTemplate dup(keys.signingKey);
    HmacMdCopy mdCopy(keys.signingKey);
    for (std::size_t size : sizes) {
        std::vector<std::uint8_t> msg(size, 0x33);
        std::array<std::uint8_t, 32> out{};
        const auto t = medianNs({
            [&] {
                fast.mac(msg, out.data());
                gSink = out[0];
            },
            [&] {
                evp.mac(msg, out.data());
                gSink = out[0];
            },
            [&] {
                dup.mac(msg, out.data());
                gSink = out[0];
            },
            [&] {
                mdCopy.mac(msg, out.data());
                gSink = out[0];
            },
            [&] {
                unsigned int len = 0;
                HMAC(EVP_sha256(), keys.signingKey.data(), 32, msg.data(), msg.size(), out.data(),
                     &len);
                gSink = out[0];
            },
        });
        const double a = t[0], b = t[1], c = t[2], d = t[3], e = t[4];
        std::printf("%8zu | %10s %10s %10s %10s %10s | %8s\n", size, us(a).c_str(), us(b).c_str(),
                    us(c).c_str(), us(d).c_str(), us(e).c_str(), mbps(size, a).c_str());
    }

    std::printf("\nAES-256-CBC encryption variants, us per message\n");
    std::printf("%8s | %12s %12s %12s | %8s\n", "bytes", "IV reset", "key per msg", "new ctx+key",
                "MB/s");
    EVP_CIPHER* aes = EVP_CIPHER_fetch(nullptr, "AES-256-CBC", nullptr);
    EVP_CIPHER_CTX* reused = EVP_CIPHER_CTX_new();
    for (std::size_t size : sizes) {
        const std::size_t enc = padded(size);
        std::vector<std::uint8_t> msg(enc, 0x44);
        int len = 0;
        const auto t = medianNs({
            [&] {
                cipher.encrypt(msg);
                gSink = msg[0];
            },
            [&] {
                EVP_EncryptInit_ex2(reused, aes, keys.encryptingKey.data(), keys.iv.data(),
                                    nullptr);
                EVP_CIPHER_CTX_set_padding(reused, 0);
                EVP_EncryptUpdate(reused, msg.data(), &len, msg.data(), static_cast<int>(enc));
                gSink = msg[0];
            },
            [&] {
                EVP_CIPHER_CTX* ctx = EVP_CIPHER_CTX_new();
                EVP_EncryptInit_ex(ctx, EVP_aes_256_cbc(), nullptr, keys.encryptingKey.data(),
                                   keys.iv.data());
                EVP_CIPHER_CTX_set_padding(ctx, 0);
                EVP_EncryptUpdate(ctx, msg.data(), &len, msg.data(), static_cast<int>(enc));
                EVP_CIPHER_CTX_free(ctx);
                gSink = msg[0];
            },
        });
        const double a = t[0], b = t[1], c = t[2];
        std::printf("%8zu | %12s %12s %12s | %8s\n", size, us(a).c_str(), us(b).c_str(),
                    us(c).c_str(), mbps(enc, a).c_str());
    }
    EVP_CIPHER_CTX_free(reused);
    EVP_CIPHER_free(aes);

    std::printf("\nRSA-2048, us per operation (one block / 64-byte message)\n");
    const PrivateKey key = PrivateKey::generateRsa(2048);
    const PublicKey pub = key.publicKey();
    const Bytes data = randomBytes(64);
    for (auto alg : {AsymmetricSignature::RsaPkcs15Sha256, AsymmetricSignature::RsaPssSha256}) {
        const char* name = alg == AsymmetricSignature::RsaPssSha256 ? "PSS-SHA256" : "PKCS1-SHA256";
        const Bytes sig = sign(key, alg, data);
        const double s = medianNs([&] { gSink = sign(key, alg, data)[0]; }, 11);
        const double v = medianNs([&] { gSink = verify(pub, alg, data, sig); }, 11);
        std::printf("  %-14s sign %9s   verify %9s\n", name, us(s).c_str(), us(v).c_str());
    }
    for (auto alg : {AsymmetricEncryption::RsaOaepSha1, AsymmetricEncryption::RsaOaepSha256}) {
        const char* name = alg == AsymmetricEncryption::RsaOaepSha1 ? "OAEP-SHA1" : "OAEP-SHA256";
        const Bytes plain = randomBytes(plainBlockSize(2048, alg));
        const Bytes ct = encrypt(pub, alg, plain);
        Bytes out(ct.size());
        const double e = medianNs([&] { gSink = encrypt(pub, alg, plain)[0]; }, 11);
        const double d = medianNs([&] { gSink = decryptInto(key, alg, ct, out).has_value(); }, 11);
        std::printf("  %-14s encrypt %6s   decrypt %9s\n", name, us(e).c_str(), us(d).c_str());
    }
    return 0;
}
