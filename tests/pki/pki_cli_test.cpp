// `pnp pki` run as a process (the built executable): create, list, a certificate dropped into
// rejected/ approved with `pnp pki trust <prefix>`, reject, remove, export, errors.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "process.hpp"
#include "ua/pki/pki.hpp"
#include "ua/types/status_codes.hpp"

#ifndef PNP_BINARY
#error "PNP_BINARY (path of the pnp executable) must be defined"
#endif

namespace pnp::ua::pki {
namespace {

namespace fs = std::filesystem;
using testing::ProcessResult;
using testing::runProcess;

class PkiCli : public ::testing::Test {
  protected:
    void SetUp() override {
        dir_ = fs::path(::testing::TempDir()) / ("pnp_pki_cli_" + std::to_string(::getpid()));
        fs::remove_all(dir_);
        fs::create_directories(dir_);
    }
    void TearDown() override {
        std::error_code ec;
        fs::remove_all(dir_, ec);
    }
    ProcessResult pnp(std::vector<std::string> args, std::vector<std::string> env = {}) {
        args.insert(args.begin(), {PNP_BINARY, "pki"});
        return runProcess(args, env, std::chrono::seconds(60));
    }
    ProcessResult pki(std::vector<std::string> args) {
        args.insert(args.begin(), {"--pki", (dir_ / "pki").string()});
        return pnp(std::move(args));
    }
    fs::path dir_;
};

TEST_F(PkiCli, CreateListTrustRejectRemoveExport) {
    auto r = pki({"create", "--uri", "urn:pnp:cli:own", "--name", "pnp cli", "--dns", "robot-1",
                  "--ip", "127.0.0.1"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const fs::path root = dir_ / "pki";
    const Certificate own = Certificate::load(root / "own" / "certs" / "pnp.der");
    EXPECT_EQ(own.uris(), std::vector<std::string>{"urn:pnp:cli:own"});
    EXPECT_EQ(own.dnsNames(), std::vector<std::string>{"robot-1"});
    EXPECT_NE(r.out.find(own.thumbprintHex()), std::string::npos) << r.out;
    struct stat st {};
    ASSERT_EQ(::stat((root / "own" / "private" / "pnp.pem").c_str(), &st), 0);
    EXPECT_EQ(st.st_mode & 0777, 0600u);

    // A peer that was refused by a server: its certificate in rejected/certs.
    CertificateRequest req;
    req.applicationUri = "urn:pnp:cli:peer";
    req.commonName = "peer device";
    const Identity peer = createSelfSigned(req);
    CertificateStore store(root);
    EXPECT_EQ(store.validate({peer.certificate}, {}), status::BadCertificateUntrusted);
    const std::string thumb = peer.certificate.thumbprintHex();
    ASSERT_TRUE(fs::exists(root / "rejected" / "certs" / (thumb + ".der")));

    r = pki({"list"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("THUMBPRINT"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find(thumb.substr(0, 16)), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("rejected"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("urn:pnp:cli:peer"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find(own.thumbprintHex().substr(0, 16)), std::string::npos) << r.out;

    r = pki({"list", "--json"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const auto list = nlohmann::json::parse(r.out);
    ASSERT_EQ(list.size(), 2u);
    bool sawPeer = false;
    for (const auto& e : list) {
        if (e["thumbprint"] == thumb) {
            sawPeer = true;
            EXPECT_EQ(e["state"], "rejected");
            EXPECT_EQ(e["applicationUri"], "urn:pnp:cli:peer");
        } else {
            EXPECT_EQ(e["state"], "own");
        }
    }
    EXPECT_TRUE(sawPeer);

    r = pki({"show", thumb.substr(0, 12)});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find(thumb), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("CN=peer device, O=pnp"), std::string::npos) << r.out;

    // The operator approves it: the server (this store) accepts it from now on.
    r = pki({"trust", thumb.substr(0, 8)});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_FALSE(fs::exists(root / "rejected" / "certs" / (thumb + ".der")));
    EXPECT_TRUE(fs::exists(root / "trusted" / "certs" / (thumb + ".der")));
    EXPECT_EQ(store.validate({peer.certificate}, {}), StatusCode{});

    r = pki({"reject", thumb.substr(0, 8)});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_TRUE(fs::exists(root / "rejected" / "certs" / (thumb + ".der")));
    EXPECT_EQ(store.validate({peer.certificate}, {}), status::BadCertificateUntrusted);

    r = pki({"remove", thumb});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_FALSE(fs::exists(root / "rejected" / "certs" / (thumb + ".der")));

    // Export: DER to a file, PEM to stdout.
    const fs::path exported = dir_ / "own.der";
    r = pki({"export", "--out", exported.string()});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(Certificate::load(exported), own);
    r = pki({"export", "--pem"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(Certificate::fromPem(r.out), own);

    // trust FILE imports a certificate.
    const fs::path file = dir_ / "peer.pem";
    std::ofstream(file) << peer.certificate.toPem();
    r = pki({"trust", file.string()});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_TRUE(fs::exists(root / "trusted" / "certs" / (thumb + ".der")));
}

TEST_F(PkiCli, CreateIntoFilesAndDefaultFolderFromEnvironment) {
    const fs::path cert = dir_ / "ca.pem";
    const fs::path key = dir_ / "ca.key";
    auto r = pnp({"create", "--name", "cli ca", "--ca", "--out-cert", cert.string(), "--out-key",
                  key.string()});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const Certificate ca = Certificate::load(cert);
    EXPECT_TRUE(ca.isCa());
    struct stat st {};
    ASSERT_EQ(::stat(key.c_str(), &st), 0);
    EXPECT_EQ(st.st_mode & 0777, 0600u);

    // PNP_PKI chooses the folder when --pki is not given.
    const fs::path envRoot = dir_ / "from-env";
    r = pnp({"trust", cert.string()}, {"PNP_PKI=" + envRoot.string()});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_TRUE(fs::exists(envRoot / "trusted" / "certs" / (ca.thumbprintHex() + ".der")));
    // And XDG_DATA_HOME when PNP_PKI is not set either.
    r = pnp({"list", "--json"}, {"PNP_PKI=", "XDG_DATA_HOME=" + (dir_ / "xdg").string()});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(nlohmann::json::parse(r.out).size(), 0u);
    r = pnp({"trust", cert.string()}, {"PNP_PKI=", "XDG_DATA_HOME=" + (dir_ / "xdg").string()});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_TRUE(fs::exists(dir_ / "xdg" / "pnp" / "pki" / "trusted" / "certs" /
                           (ca.thumbprintHex() + ".der")));
}

TEST_F(PkiCli, ErrorsAreOneLineWithExitCodes) {
    auto r = pki({"trust", "abc"});  // too short a prefix: usage
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_NE(r.err.find("thumbprint"), std::string::npos) << r.err;
    r = pki({"trust", "0123456789"});  // no such certificate
    EXPECT_EQ(r.exitCode, 1) << r.err;
    EXPECT_NE(r.err.find("error: "), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    r = pki({"export"});  // no own certificate
    EXPECT_EQ(r.exitCode, 1) << r.err;
    r = pki({"create", "--name", "x"});  // no --uri
    EXPECT_EQ(r.exitCode, 2) << r.err;
    r = pki({"create", "--uri", "urn:x", "--name", "x", "--ip", "999.1.1.1"});
    EXPECT_EQ(r.exitCode, 1) << r.err;
    EXPECT_NE(r.err.find("999.1.1.1"), std::string::npos) << r.err;
    r = pki({"frobnicate"});
    EXPECT_EQ(r.exitCode, 2);
    // A file that is not a certificate.
    const fs::path junk = dir_ / "junk.der";
    std::ofstream(junk) << "not a certificate";
    r = pki({"trust", junk.string()});
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.err.find("junk.der"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace pnp::ua::pki
