// Interop with the `openssl` command line (run as real processes): our certificates and CRLs
// verified by `openssl verify -crl_check`, read by `openssl x509 -text`, and a certificate
// made by `openssl req -x509 -addext subjectAltName=URI:...` read and validated by us.
#include <gtest/gtest.h>
#include <openssl/pem.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

#include "process.hpp"
#include "ua/pki/pki.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::pki {
namespace {

namespace fs = std::filesystem;
using testing::runProcess;

class OpensslInterop : public ::testing::Test {
  protected:
    void SetUp() override {
        dir_ = fs::path(::testing::TempDir()) / ("pnp_pki_openssl_" + std::to_string(::getpid()));
        fs::remove_all(dir_);
        fs::create_directories(dir_);
        const auto version = runProcess({"openssl", "version"});
        if (version.exitCode != 0) GTEST_SKIP() << "the openssl command is not installed";
    }
    void TearDown() override {
        std::error_code ec;
        fs::remove_all(dir_, ec);
    }
    std::string write(const std::string& name, const std::string& text) {
        const fs::path p = dir_ / name;
        std::ofstream(p, std::ios::binary) << text;
        return p.string();
    }
    std::string crlPem(const std::string& name, const Bytes& der) {
        const unsigned char* p = der.data();
        X509_CRL* crl = d2i_X509_CRL(nullptr, &p, static_cast<long>(der.size()));
        EXPECT_NE(crl, nullptr);
        BIO* bio = BIO_new(BIO_s_mem());
        PEM_write_bio_X509_CRL(bio, crl);
        char* data = nullptr;
        const long n = BIO_get_mem_data(bio, &data);
        std::string text(data, static_cast<std::size_t>(n));
        BIO_free(bio);
        X509_CRL_free(crl);
        return write(name, text);
    }
    fs::path dir_;
};

CertificateRequest request(const std::string& name, bool ca, const std::string& uri = {}) {
    CertificateRequest r;
    r.commonName = name;
    r.ca = ca;
    r.applicationUri = uri;
    r.dnsNames =
        uri.empty() ? std::vector<std::string>{} : std::vector<std::string>{"robot-1.local"};
    r.ipAddresses =
        uri.empty() ? std::vector<std::string>{} : std::vector<std::string>{"127.0.0.1"};
    return r;
}

TEST_F(OpensslInterop, OurChainAndCrlsVerifyWithOpenssl) {
    const Identity root = createSelfSigned(request("interop root", true));
    const Identity inter = createSigned(request("interop intermediate", true), root);
    const Identity leaf =
        createSigned(request("interop leaf", false, "urn:pnp:interop:leaf"), inter);
    const std::string rootPem = write("root.pem", root.certificate.toPem());
    const std::string interPem = write("inter.pem", inter.certificate.toPem());
    const std::string leafPem = write("leaf.pem", leaf.certificate.toPem());
    const std::string rootCrl = crlPem("root.crl", createCrl(root, {}));
    const std::string interCrl = crlPem("inter.crl", createCrl(inter, {}));

    auto r = runProcess({"openssl", "verify", "-CAfile", rootPem, "-untrusted", interPem,
                         "-crl_check_all", "-CRLfile", rootCrl, "-CRLfile", interCrl, "-purpose",
                         "sslserver", leafPem});
    EXPECT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_NE(r.out.find(": OK"), std::string::npos) << r.out;
    r = runProcess({"openssl", "verify", "-CAfile", rootPem, "-untrusted", interPem, "-crl_check",
                    "-CRLfile", interCrl, "-purpose", "sslclient", leafPem});
    EXPECT_EQ(r.exitCode, 0) << r.out << r.err;

    // The leaf revoked in the intermediate's CRL: openssl says so too.
    const std::string revoked =
        crlPem("revoked.crl", createCrl(inter, {leaf.certificate.serialHex()}));
    r = runProcess({"openssl", "verify", "-CAfile", rootPem, "-untrusted", interPem, "-crl_check",
                    "-CRLfile", revoked, leafPem});
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE((r.out + r.err).find("revoked"), std::string::npos) << r.out << r.err;

    // A self-signed application certificate, trusted by itself.
    const Identity self = createSelfSigned(request("interop self", false, "urn:pnp:interop:self"));
    const std::string selfPem = write("self.pem", self.certificate.toPem());
    r = runProcess({"openssl", "verify", "-CAfile", selfPem, selfPem});
    EXPECT_EQ(r.exitCode, 0) << r.out << r.err;
}

TEST_F(OpensslInterop, OpensslShowsOurExtensions) {
    const Identity leaf = createSelfSigned(request("interop leaf", false, "urn:pnp:interop:text"));
    const std::string pem = write("leaf.pem", leaf.certificate.toPem());
    const auto r = runProcess({"openssl", "x509", "-in", pem, "-noout", "-text"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    for (const char* expected :
         {"URI:urn:pnp:interop:text", "DNS:robot-1.local", "IP Address:127.0.0.1",
          "Version: 3 (0x2)", "sha256WithRSAEncryption", "X509v3 Key Usage: critical",
          "Digital Signature, Non Repudiation, Key Encipherment, Data Encipherment, Certificate "
          "Sign",
          "TLS Web Server Authentication, TLS Web Client Authentication",
          "X509v3 Basic Constraints: critical", "CA:FALSE", "X509v3 Subject Key Identifier",
          "X509v3 Authority Key Identifier", "Public-Key: (2048 bit)"}) {
        EXPECT_NE(r.out.find(expected), std::string::npos) << expected << "\n" << r.out;
    }
    // The thumbprint is openssl's SHA-1 fingerprint.
    const auto f = runProcess({"openssl", "x509", "-in", pem, "-noout", "-fingerprint", "-sha1"});
    std::string hex;
    for (char c : f.out.substr(f.out.find('=') + 1)) {
        if (std::isxdigit(static_cast<unsigned char>(c))) hex += static_cast<char>(std::tolower(c));
    }
    EXPECT_EQ(hex, leaf.certificate.thumbprintHex());
}

TEST_F(OpensslInterop, CertificateMadeByOpensslIsReadAndValidated) {
    const std::string key = (dir_ / "key.pem").string();
    const std::string pem = (dir_ / "cert.pem").string();
    auto r =
        runProcess({"openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", key,
                    "-out", pem, "-days", "2", "-subj", "/CN=made by openssl/O=elsewhere",
                    "-addext", "subjectAltName=URI:urn:elsewhere:app,DNS:host.example,IP:10.1.2.3"},
                   {}, std::chrono::seconds(60));
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const Certificate cert = Certificate::load(pem);
    EXPECT_EQ(cert.uris(), std::vector<std::string>{"urn:elsewhere:app"});
    EXPECT_EQ(cert.dnsNames(), std::vector<std::string>{"host.example"});
    EXPECT_EQ(cert.ipAddresses(), std::vector<std::string>{"10.1.2.3"});
    EXPECT_EQ(cert.commonName(), "made by openssl");
    EXPECT_EQ(cert.subject(), "CN=made by openssl, O=elsewhere");
    EXPECT_TRUE(cert.isSelfSigned());

    // The DER form too, and validation in our store (unknown, then trusted).
    const std::string der = (dir_ / "cert.der").string();
    r = runProcess({"openssl", "x509", "-in", pem, "-outform", "DER", "-out", der});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(Certificate::load(der), cert);
    CertificateStore store(dir_ / "pki");
    ValidationOptions o;
    o.applicationUri = "urn:elsewhere:app";
    o.hostName = "HOST.example";
    EXPECT_EQ(store.validate({cert}, o), status::BadCertificateUntrusted);
    store.trust(cert.thumbprintHex().substr(0, 8));
    EXPECT_EQ(store.validate({cert}, o), StatusCode{});
    o.applicationUri = "urn:elsewhere";
    EXPECT_EQ(store.validate({cert}, o), status::BadCertificateUriInvalid);
}

TEST_F(OpensslInterop, OpensslReadsOurCrl) {
    const Identity ca = createSelfSigned(request("crl issuer", true));
    const Identity leaf = createSigned(request("leaf", false, "urn:pnp:crl:leaf"), ca);
    const std::string crl = crlPem("ca.crl", createCrl(ca, {leaf.certificate.serialHex()}));
    const auto r = runProcess({"openssl", "crl", "-in", crl, "-noout", "-text"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    std::string serial = leaf.certificate.serialHex();
    std::transform(serial.begin(), serial.end(), serial.begin(), ::toupper);
    EXPECT_NE(r.out.find("Serial Number: " + serial), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("Issuer: CN = crl issuer"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace pnp::ua::pki
