// The `openssl` command line as an independent peer: each step is a real process, started
// and waited for (with a deadline) by the test, working on files in a temporary directory
// that is removed afterwards. Our OAEP ciphertexts are decrypted by `openssl pkeyutl` and
// theirs by us; our signatures verified by `openssl dgst` and theirs by us; keys written by
// openssl (PKCS#8, traditional, encrypted, DER) are read by us and ours by openssl.
#include <gtest/gtest.h>

#include "crypto_test_support.hpp"
#include "ua/crypto/crypto.hpp"

namespace pnp::ua::crypto {
namespace {

using testing::RunResult;
using testing::TempDir;
using testing::testKey;

class OpensslInterop : public ::testing::Test {
  protected:
    void SetUp() override {
        openssl_ = testing::opensslPath();
        if (openssl_.empty()) GTEST_SKIP() << "the openssl command line is not installed";
    }

    // Runs `openssl args...` in the temporary directory; the test fails with its output when
    // the exit code is not the expected one.
    RunResult openssl(std::vector<std::string> args, int expectedExit = 0) {
        args.insert(args.begin(), openssl_);
        RunResult r = testing::run(args, dir_);
        std::string line;
        for (const auto& a : args) line += a + " ";
        EXPECT_EQ(r.exitCode, expectedExit) << line << "\n" << r.output;
        return r;
    }

    // Our key as PEM (private) and DER (SubjectPublicKeyInfo) files.
    void writeKeys(const PrivateKey& key) {
        dir_.write("key.pem", key.toPem());
        dir_.write("pub.der", key.publicKey().toDer());
    }

    static std::vector<std::string> oaepOptions(AsymmetricEncryption alg) {
        const std::string md = alg == AsymmetricEncryption::RsaOaepSha1 ? "sha1" : "sha256";
        return {"-pkeyopt", "rsa_padding_mode:oaep", "-pkeyopt", "rsa_oaep_md:" + md,
                "-pkeyopt", "rsa_mgf1_md:" + md};
    }
    static std::vector<std::string> signatureOptions(AsymmetricSignature alg) {
        if (alg == AsymmetricSignature::RsaPkcs15Sha256) {
            return {"-sigopt", "rsa_padding_mode:pkcs1"};
        }
        return {"-sigopt", "rsa_padding_mode:pss", "-sigopt", "rsa_pss_saltlen:32",
                "-sigopt", "rsa_mgf1_md:sha256"};
    }
    static std::vector<std::string> concat(std::vector<std::string> a,
                                           const std::vector<std::string>& b) {
        a.insert(a.end(), b.begin(), b.end());
        return a;
    }

    std::string openssl_;
    TempDir dir_;
};

TEST_F(OpensslInterop, OpensslDecryptsOurOaepBlocks) {
    for (int bits : {2048, 3072}) {
        const PrivateKey& key = testKey(bits);
        writeKeys(key);
        for (auto alg : {AsymmetricEncryption::RsaOaepSha1, AsymmetricEncryption::RsaOaepSha256}) {
            SCOPED_TRACE(std::to_string(bits) + " bits, OAEP " +
                         (alg == AsymmetricEncryption::RsaOaepSha1 ? "SHA-1" : "SHA-256"));
            // Two blocks: pkeyutl decrypts one block per run.
            const std::size_t plainBlock = plainBlockSize(bits, alg);
            const Bytes plain = randomBytes(plainBlock + 17);
            const Bytes cipher = encrypt(key.publicKey(), alg, plain);
            ASSERT_EQ(cipher.size(), 2 * cipherBlockSize(bits));
            Bytes decrypted;
            for (std::size_t b = 0; b < 2; ++b) {
                dir_.write("ct.bin", ByteView(cipher).subspan(b * cipherBlockSize(bits),
                                                              cipherBlockSize(bits)));
                openssl(concat({"pkeyutl", "-decrypt", "-inkey", dir_.file("key.pem"), "-in",
                                dir_.file("ct.bin"), "-out", dir_.file("pt.bin")},
                               oaepOptions(alg)));
                const Bytes part = dir_.read("pt.bin");
                decrypted.insert(decrypted.end(), part.begin(), part.end());
            }
            EXPECT_EQ(decrypted, plain);
        }
    }
}

TEST_F(OpensslInterop, WeDecryptOpensslsOaepBlocks) {
    const int bits = 2048;
    const PrivateKey& key = testKey(bits);
    writeKeys(key);
    for (auto alg : {AsymmetricEncryption::RsaOaepSha1, AsymmetricEncryption::RsaOaepSha256}) {
        SCOPED_TRACE(alg == AsymmetricEncryption::RsaOaepSha1 ? "SHA-1" : "SHA-256");
        const std::size_t plainBlock = plainBlockSize(bits, alg);
        const Bytes first = randomBytes(plainBlock);  // a full block
        const Bytes second = randomBytes(9);
        Bytes cipher;
        for (const Bytes* part : {&first, &second}) {
            dir_.write("pt.bin", *part);
            openssl(concat(
                {"pkeyutl", "-encrypt", "-pubin", "-keyform", "DER", "-inkey", dir_.file("pub.der"),
                 "-in", dir_.file("pt.bin"), "-out", dir_.file("ct.bin")},
                oaepOptions(alg)));
            const Bytes c = dir_.read("ct.bin");
            ASSERT_EQ(c.size(), cipherBlockSize(bits));
            cipher.insert(cipher.end(), c.begin(), c.end());
        }
        Bytes plain = first;
        plain.insert(plain.end(), second.begin(), second.end());
        EXPECT_EQ(decrypt(key, alg, cipher), plain);
        // The same ciphertext with the other OAEP digest, or tampered, does not decrypt.
        const auto other = alg == AsymmetricEncryption::RsaOaepSha1
                               ? AsymmetricEncryption::RsaOaepSha256
                               : AsymmetricEncryption::RsaOaepSha1;
        EXPECT_FALSE(decrypt(key, other, cipher).has_value());
        cipher[100] ^= 0x10;
        EXPECT_FALSE(decrypt(key, alg, cipher).has_value());
    }
}

TEST_F(OpensslInterop, OpensslVerifiesOurSignatures) {
    for (int bits : {2048, 4096}) {
        const PrivateKey& key = testKey(bits);
        writeKeys(key);
        const Bytes data = randomBytes(5000);
        dir_.write("data.bin", data);
        for (auto alg : {AsymmetricSignature::RsaPkcs15Sha256, AsymmetricSignature::RsaPssSha256}) {
            SCOPED_TRACE(std::to_string(bits) + " bits, " +
                         (alg == AsymmetricSignature::RsaPssSha256 ? "PSS" : "PKCS#1 v1.5"));
            Bytes sig = sign(key, alg, data);
            dir_.write("sig.bin", sig);
            const auto verifyArgs = concat({"dgst", "-sha256", "-verify", dir_.file("pub.der"),
                                            "-keyform", "DER", "-signature", dir_.file("sig.bin")},
                                           signatureOptions(alg));
            RunResult ok = openssl(concat(verifyArgs, {dir_.file("data.bin")}));
            EXPECT_NE(ok.output.find("Verified OK"), std::string::npos) << ok.output;
            // A tampered signature fails at the peer too.
            sig[7] ^= 0x04;
            dir_.write("sig.bin", sig);
            RunResult bad = openssl(concat(verifyArgs, {dir_.file("data.bin")}), 1);
            EXPECT_NE(bad.output.find("Verification failure"), std::string::npos) << bad.output;
        }
    }
}

TEST_F(OpensslInterop, WeVerifyOpensslsSignatures) {
    const PrivateKey& key = testKey(3072);
    writeKeys(key);
    const Bytes data = randomBytes(777);
    dir_.write("data.bin", data);
    for (auto alg : {AsymmetricSignature::RsaPkcs15Sha256, AsymmetricSignature::RsaPssSha256}) {
        SCOPED_TRACE(alg == AsymmetricSignature::RsaPssSha256 ? "PSS" : "PKCS#1 v1.5");
        openssl(
            concat({"dgst", "-sha256", "-sign", dir_.file("key.pem"), "-out", dir_.file("sig.bin")},
                   concat(signatureOptions(alg), {dir_.file("data.bin")})));
        Bytes sig = dir_.read("sig.bin");
        ASSERT_EQ(sig.size(), 384u);
        EXPECT_TRUE(verify(key.publicKey(), alg, data, sig));
        Bytes otherData = data;
        otherData[500] ^= 1;
        EXPECT_FALSE(verify(key.publicKey(), alg, otherData, sig));
        sig.back() ^= 0x01;
        EXPECT_FALSE(verify(key.publicKey(), alg, data, sig));
    }
    // PSS with a salt other than 32 bytes (here the maximum) is not the policy's algorithm.
    openssl({"dgst", "-sha256", "-sign", dir_.file("key.pem"), "-out", dir_.file("sig.bin"),
             "-sigopt", "rsa_padding_mode:pss", "-sigopt", "rsa_pss_saltlen:max",
             dir_.file("data.bin")});
    EXPECT_FALSE(
        verify(key.publicKey(), AsymmetricSignature::RsaPssSha256, data, dir_.read("sig.bin")));
}

TEST_F(OpensslInterop, KeyFormatsBothWays) {
    openssl({"genpkey", "-algorithm", "RSA", "-pkeyopt", "rsa_keygen_bits:2048", "-out",
             dir_.file("theirs.pem")});
    const PrivateKey theirs = PrivateKey::fromPem(dir_.readText("theirs.pem"));
    ASSERT_EQ(theirs.bits(), 2048);

    // Traditional RSA PEM and PKCS#1 DER.
    openssl({"rsa", "-in", dir_.file("theirs.pem"), "-traditional", "-out", dir_.file("trad.pem")});
    EXPECT_NE(dir_.readText("trad.pem").find("BEGIN RSA PRIVATE KEY"), std::string::npos);
    EXPECT_EQ(PrivateKey::fromPem(dir_.readText("trad.pem")).toDer(), theirs.toDer());
    openssl({"rsa", "-in", dir_.file("theirs.pem"), "-traditional", "-outform", "DER", "-out",
             dir_.file("pkcs1.der")});
    EXPECT_EQ(PrivateKey::fromDer(dir_.read("pkcs1.der")).toDer(), theirs.toDer());
    openssl({"pkcs8", "-topk8", "-nocrypt", "-in", dir_.file("theirs.pem"), "-outform", "DER",
             "-out", dir_.file("pkcs8.der")});
    EXPECT_EQ(dir_.read("pkcs8.der"), theirs.toDer());  // our DER is PKCS#8 as well
    dir_.write("ours.der", theirs.toDer());
    openssl({"pkey", "-inform", "DER", "-in", dir_.file("ours.der"), "-check", "-noout"});

    // Encrypted PKCS#8 and encrypted traditional PEM.
    openssl({"pkey", "-in", dir_.file("theirs.pem"), "-aes-256-cbc", "-passout",
             "pass:correct horse", "-out", dir_.file("enc8.pem")});
    openssl({"rsa", "-in", dir_.file("theirs.pem"), "-traditional", "-aes256", "-passout",
             "pass:correct horse", "-out", dir_.file("enctrad.pem")});
    for (const char* file : {"enc8.pem", "enctrad.pem"}) {
        SCOPED_TRACE(file);
        const std::string pem = dir_.readText(file);
        EXPECT_EQ(PrivateKey::fromPem(pem, "correct horse").toDer(), theirs.toDer());
        EXPECT_THROW(PrivateKey::fromPem(pem, "wrong"), CryptoError);
        EXPECT_THROW(PrivateKey::fromPem(pem), CryptoError);  // never prompts, just fails
    }

    // Their public key = ours from their private key; openssl reads our PEM and SPKI.
    openssl({"pkey", "-in", dir_.file("theirs.pem"), "-pubout", "-outform", "DER", "-out",
             dir_.file("theirs_pub.der")});
    EXPECT_EQ(dir_.read("theirs_pub.der"), theirs.publicKey().toDer());
    writeKeys(testKey(2048));
    openssl({"pkey", "-in", dir_.file("key.pem"), "-check", "-noout"});
    openssl({"pkey", "-pubin", "-inform", "DER", "-in", dir_.file("pub.der"), "-outform", "DER",
             "-out", dir_.file("pub2.der")});
    EXPECT_EQ(dir_.read("pub2.der"), testKey(2048).publicKey().toDer());

    // A key of another type is refused with a clear error.
    openssl({"genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out",
             dir_.file("ec.pem")});
    try {
        PrivateKey::fromPem(dir_.readText("ec.pem"));
        FAIL() << "an EC key was accepted";
    } catch (const CryptoError& e) {
        EXPECT_NE(std::string(e.what()).find("not an RSA key"), std::string::npos) << e.what();
    }
}

TEST_F(OpensslInterop, PSha256MatchesOpensslsTls1Prf) {
    // OpenSSL's TLS1-PRF with SHA-256 is P_SHA256 (the TLS 1.2 PRF): a second, independent
    // implementation for inputs of the size OPC UA uses (32-byte nonces, 80 bytes of keys).
    const Bytes secret = randomBytes(32), seed = randomBytes(32);
    RunResult r = openssl({"kdf", "-keylen", "80", "-kdfopt", "digest:SHA2-256", "-kdfopt",
                           "hexsecret:" + testing::toHex(secret), "-kdfopt",
                           "hexseed:" + testing::toHex(seed), "TLS1-PRF"});
    std::string expected;
    for (char c : r.output) {
        if (std::isxdigit(static_cast<unsigned char>(c))) {
            expected += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        }
    }
    EXPECT_EQ(testing::toHex(pSha256(secret, seed, 80)), expected);
}

}  // namespace
}  // namespace pnp::ua::crypto
