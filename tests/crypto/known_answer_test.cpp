// Known-answer tests of the symmetric side: RFC 4231 (HMAC-SHA256) through SymmetricCipher
// and both internal HMAC implementations, NIST SP 800-38A F.2 (AES-CBC), the TLS 1.2 PRF
// test vector (P_SHA256), RFC 7914 §11 (PBKDF2-HMAC-SHA256), FIPS 180 examples (SHA-1/256);
// then the policy table, key derivation and SymmetricCipher's behaviour.
#include <gtest/gtest.h>

#include <string>

#include "crypto_test_support.hpp"
#include "ua/crypto/crypto.hpp"
#include "ua/crypto/hmac_sha256.hpp"

namespace pnp::ua::crypto {
namespace {

using testing::hex;
using testing::toHex;

const SecurityPolicy& policy(std::string_view uri) {
    const SecurityPolicy* p = findPolicy(uri);
    if (!p) throw std::runtime_error("no policy " + std::string(uri));
    return *p;
}
const SecurityPolicy& basic256Sha256() {
    return policy("http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256");
}
const SecurityPolicy& aes128() {
    return policy("http://opcfoundation.org/UA/SecurityPolicy#Aes128_Sha256_RsaOaep");
}

// ---------------------------------------------------------------------------------------
// RFC 4231 §4: HMAC-SHA-256 test cases 1-7 (case 5's output is truncated to 128 bits).

struct HmacCase {
    Bytes key;
    Bytes data;
    std::string mac;  // hex, 64 digits or 32 for the truncated case
};

std::vector<HmacCase> rfc4231() {
    auto str = [](std::string_view s) { return Bytes(s.begin(), s.end()); };
    return {
        {Bytes(20, 0x0b), str("Hi There"),
         "b0344c61d8db38535ca8afceaf0bf12b881dc200c9833da726e9376c2e32cff7"},
        {str("Jefe"), str("what do ya want for nothing?"),
         "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"},
        {Bytes(20, 0xaa), Bytes(50, 0xdd),
         "773ea91e36800e46854db8ebd09181a72959098b3ef8c122d9635514ced565fe"},
        {hex("0102030405060708090a0b0c0d0e0f10111213141516171819"), Bytes(50, 0xcd),
         "82558a389a443c0ea4cc819899f2083a85f0faa3e578f8077a2e3ff46729665b"},
        {Bytes(20, 0x0c), str("Test With Truncation"), "a3b6167473100ee06e0c796c2955552b"},
        {Bytes(131, 0xaa), str("Test Using Larger Than Block-Size Key - Hash Key First"),
         "60e431591ee0b67f0d8a26aacbf5b77f8e0bc6213728c5140546040f0ee37f54"},
        {Bytes(131, 0xaa),
         str("This is a test using a larger than block-size key and a larger than block-size "
             "data. The key needs to be hashed before being used by the HMAC algorithm."),
         "9b09ffa71b942fcb27635fbcd5b0e944bfdc63644f0713938a7f51535c3a35e2"},
    };
}

// SymmetricKeys with the vector's signing key; the AES part is irrelevant to sign / verify.
SymmetricKeys keysWithSigningKey(const Bytes& signingKey) {
    return {signingKey, Bytes(32, 0x42), Bytes(16, 0x24)};
}

TEST(Rfc4231, SymmetricCipherSignsTheVectors) {
    int n = 0;
    for (const auto& c : rfc4231()) {
        SCOPED_TRACE("RFC 4231 test case " + std::to_string(++n));
        SymmetricCipher cipher(basic256Sha256(), keysWithSigningKey(c.key));
        std::array<std::uint8_t, 32> mac{};
        cipher.sign(c.data, mac.data());
        EXPECT_EQ(toHex(mac).substr(0, c.mac.size()), c.mac);
        // The same object again: per-message state is reset, not carried over.
        std::array<std::uint8_t, 32> again{};
        cipher.sign(c.data, again.data());
        EXPECT_EQ(mac, again);
        if (c.mac.size() == 64) {
            EXPECT_TRUE(cipher.verify(c.data, hex(c.mac)));
        }
    }
}

TEST(Rfc4231, VerifyRejectsAnyChangeAndWrongSizes) {
    const auto c = rfc4231()[1];
    SymmetricCipher cipher(basic256Sha256(), keysWithSigningKey(c.key));
    Bytes mac = hex(c.mac);
    ASSERT_TRUE(cipher.verify(c.data, mac));
    for (std::size_t i = 0; i < mac.size(); ++i) {
        Bytes bad = mac;
        bad[i] ^= 0x01;
        EXPECT_FALSE(cipher.verify(c.data, bad)) << "flipped bit in byte " << i;
    }
    Bytes data = c.data;
    data.back() ^= 0x80;
    EXPECT_FALSE(cipher.verify(data, mac));
    EXPECT_FALSE(cipher.verify(c.data, ByteView(mac).first(31)));
    Bytes longer = mac;
    longer.push_back(0);
    EXPECT_FALSE(cipher.verify(c.data, longer));
    EXPECT_FALSE(cipher.verify(c.data, {}));
}

TEST(Rfc4231, BothInternalHmacImplementationsAgree) {
    for (const auto& c : rfc4231()) {
        detail::HmacSha256 fast(c.key);
        detail::HmacSha256Evp evp(c.key);
        std::array<std::uint8_t, 32> a{}, b{};
        fast.mac(c.data, a.data());
        evp.mac(c.data, b.data());
        EXPECT_EQ(toHex(a).substr(0, c.mac.size()), c.mac);
        EXPECT_EQ(toHex(b).substr(0, c.mac.size()), c.mac);
    }
    // Key lengths around the 64-byte block, messages around the padding boundary.
    for (std::size_t keyLen : {0u, 1u, 32u, 63u, 64u, 65u, 200u}) {
        for (std::size_t dataLen : {0u, 1u, 55u, 56u, 64u, 1000u}) {
            Bytes key(keyLen, static_cast<std::uint8_t>(keyLen));
            Bytes data(dataLen, static_cast<std::uint8_t>(dataLen + 7));
            detail::HmacSha256 fast(key);
            detail::HmacSha256Evp evp(key);
            std::array<std::uint8_t, 32> a{}, b{};
            fast.mac(data, a.data());
            evp.mac(data, b.data());
            EXPECT_EQ(a, b) << "key " << keyLen << " data " << dataLen;
        }
    }
}

// ---------------------------------------------------------------------------------------
// NIST SP 800-38A F.2.1 / F.2.2 (CBC-AES128) and F.2.5 / F.2.6 (CBC-AES256).

const char* kNistIv = "000102030405060708090a0b0c0d0e0f";
const char* kNistPlain =
    "6bc1bee22e409f96e93d7e117393172a ae2d8a571e03ac9c9eb76fac45af8e51"
    "30c81c46a35ce411e5fbc1191a0a52ef f69f2445df4f9b17ad2b417be66c3710";

void checkNistCbc(const SecurityPolicy& p, const char* key, const char* cipherText) {
    SymmetricCipher cipher(p, {Bytes(32, 1), hex(key), hex(kNistIv)});
    Bytes buffer = hex(kNistPlain);
    cipher.encrypt(buffer);
    EXPECT_EQ(toHex(buffer), toHex(hex(cipherText)));
    cipher.decrypt(buffer);
    EXPECT_EQ(toHex(buffer), toHex(hex(kNistPlain)));
    // Every message starts from the keys' IV again (OPC UA: the IV of the token).
    Bytes second = hex(kNistPlain);
    cipher.encrypt(second);
    EXPECT_EQ(toHex(second), toHex(hex(cipherText)));
    // Block by block is not the same as one message: CBC chains within a message only.
    Bytes firstBlock = hex(kNistPlain);
    firstBlock.resize(16);
    cipher.encrypt(firstBlock);
    EXPECT_EQ(toHex(firstBlock), toHex(hex(cipherText)).substr(0, 32));
}

TEST(NistSp80038a, CbcAes128) {
    checkNistCbc(aes128(), "2b7e151628aed2a6abf7158809cf4f3c",
                 "7649abac8119b246cee98e9b12e9197d 5086cb9b507219ee95db113a917678b2"
                 "73bed6b8e3c1743b7116e69e22229516 3ff1caa1681fac09120eca307586e1a7");
}

TEST(NistSp80038a, CbcAes256) {
    checkNistCbc(basic256Sha256(),
                 "603deb1015ca71be2b73aef0857d77811f352c073b6108d72d9810a30914dff4",
                 "f58c4c04d6e5f1ba779eabfb5f7bfbd6 9cfc4e967edb808d679f777bc6702c7d"
                 "39f23369a9d9bacfa530e26304231461 b2eb05e2c39be9fcda6c19078c6a9d1b");
}

TEST(SymmetricCipher, RejectsPartialBlocksAndWrongKeys) {
    SymmetricCipher cipher(basic256Sha256(), {Bytes(32, 1), Bytes(32, 2), Bytes(16, 3)});
    Bytes partial(17);
    EXPECT_THROW(cipher.encrypt(partial), CryptoError);
    EXPECT_THROW(cipher.decrypt(partial), CryptoError);
    Bytes empty;
    EXPECT_NO_THROW(cipher.encrypt(empty));
    // Key sizes must be the policy's.
    EXPECT_THROW(SymmetricCipher(basic256Sha256(), {Bytes(32, 1), Bytes(16, 2), Bytes(16, 3)}),
                 CryptoError);
    EXPECT_THROW(SymmetricCipher(aes128(), {Bytes(32, 1), Bytes(32, 2), Bytes(16, 3)}),
                 CryptoError);
    EXPECT_THROW(SymmetricCipher(aes128(), {Bytes(32, 1), Bytes(16, 2), Bytes(8, 3)}), CryptoError);
    EXPECT_THROW(SymmetricCipher(aes128(), {Bytes(), Bytes(16, 2), Bytes(16, 3)}), CryptoError);
}

TEST(SymmetricCipher, MovedObjectKeepsWorking) {
    SymmetricCipher a(basic256Sha256(), {Bytes(32, 1), Bytes(32, 2), Bytes(16, 3)});
    Bytes data(64, 9);
    std::array<std::uint8_t, 32> before{}, after{};
    a.sign(data, before.data());
    SymmetricCipher b(std::move(a));
    b.sign(data, after.data());
    EXPECT_EQ(before, after);
    SymmetricCipher c(aes128(), {Bytes(32, 5), Bytes(16, 6), Bytes(16, 7)});
    c = std::move(b);
    c.sign(data, after.data());
    EXPECT_EQ(before, after);
}

TEST(SymmetricCipher, LargeMessageRoundTrip) {
    SymmetricCipher cipher(
        policy("http://opcfoundation.org/UA/SecurityPolicy#Aes256_Sha256_RsaPss"),
        {randomBytes(32), randomBytes(32), randomBytes(16)});
    Bytes message = randomBytes(65536);
    Bytes buffer = message;
    std::array<std::uint8_t, 32> mac{};
    cipher.sign(buffer, mac.data());
    cipher.encrypt(buffer);
    EXPECT_NE(buffer, message);
    cipher.decrypt(buffer);
    EXPECT_EQ(buffer, message);
    EXPECT_TRUE(cipher.verify(buffer, mac));
}

// ---------------------------------------------------------------------------------------
// P_SHA256: the TLS 1.2 PRF test vector (IETF TLS WG, 2010; in Botan's, wolfSSL's and mbed
// TLS's test suites). PRF(secret, label, seed) = P_SHA256(secret, label + seed).

TEST(PSha256, TlsPrfTestVector) {
    const Bytes secret = hex("9b be 43 6b a9 40 f0 17 b1 76 52 84 9a 71 db 35");
    Bytes seed = Bytes{'t', 'e', 's', 't', ' ', 'l', 'a', 'b', 'e', 'l'};
    const Bytes random = hex("a0 ba 9f 93 6c da 31 18 27 a6 f7 96 ff d5 19 8c");
    seed.insert(seed.end(), random.begin(), random.end());
    const Bytes out = pSha256(secret, seed, 100);
    EXPECT_EQ(toHex(out),
              "e3f229ba727be17b8d122620557cd453c2aab21d07c3d495329b52d4e61edb5a"
              "6b301791e90d35c9c9a46b4e14baf9af0fa022f7077def17abfd3797c0564bab"
              "4fbc91666e9def9b97fce34f796789baa48082d122ee42c5a72e5a5110fff701"
              "87347b66");
    // Shorter outputs are prefixes (the stream does not depend on the length asked for).
    EXPECT_EQ(toHex(pSha256(secret, seed, 33)), toHex(out).substr(0, 66));
    EXPECT_TRUE(pSha256(secret, seed, 0).empty());
}

TEST(DeriveKeys, SplitsPSha256InSigningEncryptingIvOrder) {
    const Bytes clientNonce =
        hex("00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff");
    const Bytes serverNonce =
        hex("ffeeddccbbaa99887766554433221100ffeeddccbbaa99887766554433221100");
    for (const auto& p : securityPolicies()) {
        SCOPED_TRACE(std::string(p.uri));
        const std::size_t total = p.signingKeyLength + p.encryptingKeyLength + p.blockSize;
        const Bytes material = pSha256(serverNonce, clientNonce, total);
        const SymmetricKeys keys = deriveKeys(p, serverNonce, clientNonce);
        ASSERT_EQ(keys.signingKey.size(), 32u);
        ASSERT_EQ(keys.encryptingKey.size(), p.encryptingKeyLength);
        ASSERT_EQ(keys.iv.size(), 16u);
        Bytes joined = keys.signingKey;
        joined.insert(joined.end(), keys.encryptingKey.begin(), keys.encryptingKey.end());
        joined.insert(joined.end(), keys.iv.begin(), keys.iv.end());
        EXPECT_EQ(joined, material);
        // The two directions get different keys.
        EXPECT_NE(deriveKeys(p, clientNonce, serverNonce).signingKey, keys.signingKey);
        EXPECT_NO_THROW(SymmetricCipher(p, keys));
    }
}

// ---------------------------------------------------------------------------------------
// RFC 7914 §11: PBKDF2-HMAC-SHA256.

TEST(Pbkdf2Sha256, Rfc7914Vectors) {
    EXPECT_EQ(toHex(pbkdf2Sha256("passwd", view("salt"), 1, 64)),
              "55ac046e56e3089fec1691c22544b605f94185216dde0465e68b9d57c20dacbc"
              "49ca9cccf179b645991664b39d77ef317c71b845b1e30bd509112041d3a19783");
    EXPECT_EQ(toHex(pbkdf2Sha256("Password", view("NaCl"), 80000, 64)),
              "4ddcd8f60b98be21830cee5ef22701f9641a4418d04c0414aeff08876b34ab56"
              "a1d425a1225833549adb841b51c9b3176a272bdebba1d078478f62b397f33c8d");
}

TEST(Pbkdf2Sha256, BoundsAreErrors) {
    EXPECT_THROW(pbkdf2Sha256("x", view("salt"), 0, 32), CryptoError);
    EXPECT_THROW(pbkdf2Sha256("x", view("salt"), 1, 0), CryptoError);
    EXPECT_THROW(pbkdf2Sha256("x", view("salt"), 1, 4096), CryptoError);
}

// ---------------------------------------------------------------------------------------
// FIPS 180 examples, random bytes, comparison.

TEST(Digests, FipsExamples) {
    EXPECT_EQ(toHex(sha1(view("abc"))), "a9993e364706816aba3e25717850c26c9cd0d89d");
    EXPECT_EQ(toHex(sha256(view("abc"))),
              "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    EXPECT_EQ(toHex(sha256({})),
              "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
}

TEST(Random, FillsAndDiffers) {
    const Bytes a = randomBytes(32), b = randomBytes(32);
    EXPECT_EQ(a.size(), 32u);
    EXPECT_NE(a, b);
    EXPECT_TRUE(randomBytes(0).empty());
}

TEST(ConstantTimeEqual, ComparesContentsAndSizes) {
    EXPECT_TRUE(constantTimeEqual(view("abc"), view("abc")));
    EXPECT_FALSE(constantTimeEqual(view("abc"), view("abd")));
    EXPECT_FALSE(constantTimeEqual(view("abc"), view("ab")));
    EXPECT_TRUE(constantTimeEqual({}, {}));
}

// ---------------------------------------------------------------------------------------
// The policy table (OPC 10000-7 security policy profiles).

TEST(SecurityPolicies, TableMatchesPart7) {
    const auto all = securityPolicies();
    ASSERT_EQ(all.size(), 3u);
    EXPECT_EQ(all[0].id, PolicyId::Aes256Sha256RsaPss);
    EXPECT_EQ(all[1].id, PolicyId::Basic256Sha256);
    EXPECT_EQ(all[2].id, PolicyId::Aes128Sha256RsaOaep);

    const auto& pss = policy("http://opcfoundation.org/UA/SecurityPolicy#Aes256_Sha256_RsaPss");
    EXPECT_EQ(pss.asymmetricSignature, AsymmetricSignature::RsaPssSha256);
    EXPECT_EQ(pss.asymmetricSignatureUri, "http://opcfoundation.org/UA/security/rsa-pss-sha2-256");
    EXPECT_EQ(pss.asymmetricEncryption, AsymmetricEncryption::RsaOaepSha256);
    EXPECT_EQ(pss.asymmetricEncryptionUri,
              "http://opcfoundation.org/UA/security/rsa-oaep-sha2-256");
    EXPECT_EQ(pss.encryptingKeyLength, 32u);

    const auto& b256 = basic256Sha256();
    EXPECT_EQ(b256.asymmetricSignature, AsymmetricSignature::RsaPkcs15Sha256);
    EXPECT_EQ(b256.asymmetricSignatureUri, "http://www.w3.org/2001/04/xmldsig-more#rsa-sha256");
    EXPECT_EQ(b256.asymmetricEncryption, AsymmetricEncryption::RsaOaepSha1);
    EXPECT_EQ(b256.asymmetricEncryptionUri, "http://www.w3.org/2001/04/xmlenc#rsa-oaep");
    EXPECT_EQ(b256.encryptingKeyLength, 32u);

    const auto& a128 = aes128();
    EXPECT_EQ(a128.asymmetricSignature, AsymmetricSignature::RsaPkcs15Sha256);
    EXPECT_EQ(a128.asymmetricEncryption, AsymmetricEncryption::RsaOaepSha1);
    EXPECT_EQ(a128.encryptingKeyLength, 16u);

    for (const auto& p : all) {
        EXPECT_EQ(findPolicy(p.uri), &p);
        EXPECT_EQ(p.signingKeyLength, 32u);
        EXPECT_EQ(p.blockSize, 16u);
        EXPECT_EQ(p.signatureSize, 32u);
        EXPECT_EQ(p.nonceLength, 32u);
        EXPECT_EQ(p.minKeyBits, 2048);
        EXPECT_EQ(p.maxKeyBits, 4096);
    }
}

TEST(SecurityPolicies, NoneDeprecatedAndUnknownAreNotFound) {
    EXPECT_EQ(findPolicy(kNoneUri), nullptr);
    EXPECT_EQ(findPolicy("http://opcfoundation.org/UA/SecurityPolicy#Basic128Rsa15"), nullptr);
    EXPECT_EQ(findPolicy("http://opcfoundation.org/UA/SecurityPolicy#Basic256"), nullptr);
    EXPECT_EQ(findPolicy("http://opcfoundation.org/UA/SecurityPolicy#basic256sha256"), nullptr);
    EXPECT_EQ(findPolicy(""), nullptr);
    EXPECT_TRUE(isDeprecatedPolicy("http://opcfoundation.org/UA/SecurityPolicy#Basic128Rsa15"));
    EXPECT_TRUE(isDeprecatedPolicy("http://opcfoundation.org/UA/SecurityPolicy#Basic256"));
    EXPECT_FALSE(isDeprecatedPolicy("http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256"));
    EXPECT_FALSE(isDeprecatedPolicy(kNoneUri));
}

}  // namespace
}  // namespace pnp::ua::crypto
