// RSA keys (generation limits, PEM / DER round trips, encrypted PEM, bad input) and the
// asymmetric algorithms against ourselves: round trips for 2048, 3072 and 4096 bits, block
// sizes, multi-block OAEP, in-place decryption, and every kind of tampering (false /
// nullopt, never an exception, nothing left in OpenSSL's error queue).
#include <gtest/gtest.h>
#include <openssl/err.h>

#include "crypto_test_support.hpp"
#include "ua/crypto/crypto.hpp"

namespace pnp::ua::crypto {
namespace {

using testing::testKey;

constexpr AsymmetricSignature kSignatures[] = {AsymmetricSignature::RsaPkcs15Sha256,
                                               AsymmetricSignature::RsaPssSha256};
constexpr AsymmetricEncryption kEncryptions[] = {AsymmetricEncryption::RsaOaepSha1,
                                                 AsymmetricEncryption::RsaOaepSha256};

TEST(RsaKeys, GenerateOnlyFrom2048To4096Bits) {
    EXPECT_THROW(PrivateKey::generateRsa(1024), CryptoError);
    EXPECT_THROW(PrivateKey::generateRsa(2047), CryptoError);
    EXPECT_THROW(PrivateKey::generateRsa(8192), CryptoError);
    EXPECT_THROW(PrivateKey::generateRsa(0), CryptoError);
    for (int bits : {2048, 3072, 4096}) {
        const PrivateKey& key = testKey(bits);
        EXPECT_EQ(key.bits(), bits);
        EXPECT_EQ(key.publicKey().bits(), bits);
    }
}

TEST(RsaKeys, PemAndDerRoundTrips) {
    const PrivateKey& key = testKey(2048);
    const std::string pem = key.toPem();
    EXPECT_NE(pem.find("-----BEGIN PRIVATE KEY-----"), std::string::npos);  // PKCS#8
    const PrivateKey fromPem = PrivateKey::fromPem(pem);
    EXPECT_EQ(fromPem.toDer(), key.toDer());
    const PrivateKey fromDer = PrivateKey::fromDer(key.toDer());
    EXPECT_EQ(fromDer.toPem(), pem);
    // PKCS#8 DER starts with SEQUENCE { INTEGER 0, AlgorithmIdentifier rsaEncryption ... }.
    const Bytes der = key.toDer();
    ASSERT_GT(der.size(), 30u);
    EXPECT_EQ(der[0], 0x30);

    const Bytes spki = key.publicKey().toDer();
    const PublicKey pub = PublicKey::fromDer(spki);
    EXPECT_EQ(pub.toDer(), spki);
    EXPECT_EQ(pub.bits(), 2048);
    // The public key carries no private part: it cannot be read as a private key.
    EXPECT_THROW(PrivateKey::fromDer(spki), CryptoError);
}

TEST(RsaKeys, BadInputIsAClearError) {
    EXPECT_THROW(PrivateKey::fromPem(""), CryptoError);
    EXPECT_THROW(
        PrivateKey::fromPem("-----BEGIN PRIVATE KEY-----\nAAAA\n-----END PRIVATE KEY-----\n"),
        CryptoError);
    EXPECT_THROW(PrivateKey::fromDer({}), CryptoError);
    EXPECT_THROW(PrivateKey::fromDer(view("not a key at all")), CryptoError);
    EXPECT_THROW(PublicKey::fromDer(view("\x30\x03\x02\x01\x00")), CryptoError);
    Bytes der = testKey(2048).toDer();
    der.push_back(0);
    EXPECT_THROW(PrivateKey::fromDer(der), CryptoError);  // trailing byte
    Bytes spki = testKey(2048).publicKey().toDer();
    EXPECT_THROW(PublicKey::fromDer(ByteView(spki).first(spki.size() - 1)), CryptoError);
    try {
        PrivateKey::fromDer(view("garbage"));
        FAIL() << "no exception";
    } catch (const CryptoError& e) {
        EXPECT_NE(std::string(e.what()).find("private key DER"), std::string::npos) << e.what();
    }
    EXPECT_EQ(ERR_peek_error(), 0u);  // the failure left nothing behind
    EXPECT_THROW(sign(PrivateKey(), AsymmetricSignature::RsaPkcs15Sha256, view("x")), CryptoError);
    EXPECT_THROW(encrypt(PublicKey(), AsymmetricEncryption::RsaOaepSha1, view("x")), CryptoError);
}

TEST(AsymmetricSignatures, RoundTripAndTamperingForEveryKeySize) {
    const Bytes data = randomBytes(1000);
    for (int bits : {2048, 3072, 4096}) {
        const PrivateKey& key = testKey(bits);
        const PublicKey pub = key.publicKey();
        for (auto alg : kSignatures) {
            SCOPED_TRACE(std::to_string(bits) + " bits, algorithm " +
                         std::to_string(static_cast<int>(alg)));
            const Bytes sig = sign(key, alg, data);
            ASSERT_EQ(sig.size(), static_cast<std::size_t>(bits / 8));
            EXPECT_TRUE(verify(pub, alg, data, sig));

            Bytes badSig = sig;
            badSig[badSig.size() / 2] ^= 0x01;
            EXPECT_FALSE(verify(pub, alg, data, badSig));
            Bytes badData = data;
            badData[0] ^= 0x80;
            EXPECT_FALSE(verify(pub, alg, badData, sig));
            EXPECT_FALSE(verify(pub, alg, data, ByteView(sig).first(sig.size() - 1)));
            EXPECT_FALSE(verify(pub, alg, data, {}));
            EXPECT_FALSE(verify(pub, alg, data, Bytes(sig.size(), 0xff)));  // >= modulus
            // The other padding does not verify.
            const auto other = alg == AsymmetricSignature::RsaPkcs15Sha256
                                   ? AsymmetricSignature::RsaPssSha256
                                   : AsymmetricSignature::RsaPkcs15Sha256;
            EXPECT_FALSE(verify(pub, other, data, sig));
            EXPECT_EQ(ERR_peek_error(), 0u);
        }
    }
    // A different key of the same size.
    const PrivateKey other = PrivateKey::generateRsa(2048);
    const Bytes sig = sign(testKey(2048), AsymmetricSignature::RsaPssSha256, data);
    EXPECT_FALSE(verify(other.publicKey(), AsymmetricSignature::RsaPssSha256, data, sig));
}

TEST(AsymmetricSignatures, PssIsRandomizedPkcs15IsNot) {
    const Bytes data = randomBytes(100);
    const PrivateKey& key = testKey(2048);
    EXPECT_EQ(sign(key, AsymmetricSignature::RsaPkcs15Sha256, data),
              sign(key, AsymmetricSignature::RsaPkcs15Sha256, data));
    EXPECT_NE(sign(key, AsymmetricSignature::RsaPssSha256, data),
              sign(key, AsymmetricSignature::RsaPssSha256, data));
}

TEST(AsymmetricEncryption, BlockSizes) {
    EXPECT_EQ(plainBlockSize(2048, AsymmetricEncryption::RsaOaepSha1), 256u - 42u);
    EXPECT_EQ(plainBlockSize(2048, AsymmetricEncryption::RsaOaepSha256), 256u - 66u);
    EXPECT_EQ(plainBlockSize(4096, AsymmetricEncryption::RsaOaepSha1), 512u - 42u);
    EXPECT_EQ(plainBlockSize(3072, AsymmetricEncryption::RsaOaepSha256), 384u - 66u);
    EXPECT_EQ(cipherBlockSize(3072), 384u);
}

TEST(AsymmetricEncryption, MultiBlockRoundTripForEveryKeySize) {
    for (int bits : {2048, 3072, 4096}) {
        const PrivateKey& key = testKey(bits);
        const PublicKey pub = key.publicKey();
        for (auto alg : kEncryptions) {
            SCOPED_TRACE(std::to_string(bits) + " bits, algorithm " +
                         std::to_string(static_cast<int>(alg)));
            const std::size_t plainBlock = plainBlockSize(bits, alg);
            for (std::size_t size : {std::size_t{1}, plainBlock, plainBlock + 1, 3 * plainBlock}) {
                const Bytes plain = randomBytes(size);
                const Bytes cipher = encrypt(pub, alg, plain);
                const std::size_t blocks = (size + plainBlock - 1) / plainBlock;
                ASSERT_EQ(cipher.size(), blocks * cipherBlockSize(bits));
                const auto back = decrypt(key, alg, cipher);
                ASSERT_TRUE(back.has_value()) << size << " bytes";
                EXPECT_EQ(*back, plain);
            }
        }
    }
}

TEST(AsymmetricEncryption, DecryptIntoWorksInPlace) {
    const PrivateKey& key = testKey(2048);
    const auto alg = AsymmetricEncryption::RsaOaepSha256;
    const Bytes plain = randomBytes(2 * plainBlockSize(2048, alg) + 5);
    Bytes buffer = encrypt(key.publicKey(), alg, plain);
    const auto n = decryptInto(key, alg, buffer, buffer);
    ASSERT_TRUE(n.has_value());
    ASSERT_EQ(*n, plain.size());
    EXPECT_TRUE(std::equal(plain.begin(), plain.end(), buffer.begin()));

    Bytes small(10);
    EXPECT_THROW(decryptInto(key, alg, encrypt(key.publicKey(), alg, plain), small), CryptoError);
}

TEST(AsymmetricEncryption, EveryFailureIsTheSameNullopt) {
    const PrivateKey& key = testKey(2048);
    const PrivateKey& otherKey = testKey(3072);
    const PrivateKey sameSizeOther = PrivateKey::generateRsa(2048);
    for (auto alg : kEncryptions) {
        SCOPED_TRACE(static_cast<int>(alg));
        const Bytes plain = randomBytes(300);  // two blocks
        const Bytes cipher = encrypt(key.publicKey(), alg, plain);
        ASSERT_EQ(cipher.size(), 512u);
        // Tampering in the first and in the last block.
        for (std::size_t at : {std::size_t{3}, cipher.size() - 1}) {
            Bytes bad = cipher;
            bad[at] ^= 0x01;
            EXPECT_FALSE(decrypt(key, alg, bad).has_value()) << "byte " << at;
        }
        // Wrong lengths, wrong keys, the other OAEP digest, block >= modulus.
        EXPECT_FALSE(decrypt(key, alg, ByteView(cipher).first(511)).has_value());
        EXPECT_FALSE(decrypt(key, alg, {}).has_value());
        EXPECT_FALSE(decrypt(otherKey, alg, cipher).has_value());
        EXPECT_FALSE(decrypt(sameSizeOther, alg, cipher).has_value());
        const auto otherAlg = alg == AsymmetricEncryption::RsaOaepSha1
                                  ? AsymmetricEncryption::RsaOaepSha256
                                  : AsymmetricEncryption::RsaOaepSha1;
        EXPECT_FALSE(decrypt(key, otherAlg, cipher).has_value());
        EXPECT_FALSE(decrypt(key, alg, Bytes(256, 0xff)).has_value());
        EXPECT_FALSE(decrypt(key, alg, Bytes(256, 0x00)).has_value());
        EXPECT_EQ(ERR_peek_error(), 0u);
        // And the key still works afterwards.
        EXPECT_EQ(decrypt(key, alg, cipher), plain);
    }
}

}  // namespace
}  // namespace pnp::ua::crypto
