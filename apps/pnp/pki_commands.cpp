// `pnp pki`: the operator's view of the PKI folder (src/ua/pki/README.md), so that a device
// that was just discovered can be approved:
//   pnp pki [--pki DIR] list [--json] | show THUMB | trust THUMB|FILE | reject THUMB |
//           remove THUMB | create --uri URI --name NAME ... | export [--pem] [--out FILE]
// DIR: --pki, else $PNP_PKI, else ${XDG_DATA_HOME:-$HOME/.local/share}/pnp/pki.
#include <fcntl.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "output.hpp"
#include "ua/pki/pki.hpp"
#include "value_text.hpp"

namespace pnp::cli {

namespace {

namespace fs = std::filesystem;
namespace pki = ua::pki;

struct PkiOptions {
    std::string dir;
    bool json = false;
    std::string thumb;  // show / trust / reject / remove
    // create
    std::string uri;
    std::string name;
    std::string organization = "pnp";
    std::vector<std::string> dns;
    std::vector<std::string> ips;
    bool ca = false;
    int days = 365 * 5;
    int keyBits = 2048;
    std::string outCert;
    std::string outKey;
    std::string ownName = "pnp";
    // export
    bool pem = false;
    std::string out;
};

fs::path pkiRoot(const PkiOptions& o) {
    if (!o.dir.empty()) return o.dir;
    if (const char* env = std::getenv("PNP_PKI"); env && *env) return env;
    if (const char* xdg = std::getenv("XDG_DATA_HOME"); xdg && *xdg) {
        return fs::path(xdg) / "pnp" / "pki";
    }
    const char* home = std::getenv("HOME");
    if (home == nullptr || *home == '\0') {
        throw UsageError("no PKI folder: give --pki DIR or set PNP_PKI (HOME is not set)");
    }
    return fs::path(home) / ".local" / "share" / "pnp" / "pki";
}

std::string utc(std::chrono::system_clock::time_point t) {
    const std::time_t tt = std::chrono::system_clock::to_time_t(t);
    std::tm tm{};
    gmtime_r(&tt, &tm);
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
    return buf;
}

std::string joined(const std::vector<std::string>& v) {
    std::string s;
    for (const std::string& x : v) s += (s.empty() ? "" : " ") + x;
    return s;
}

void checkThumb(const std::string& thumb) {
    if (thumb.size() < 8 || thumb.size() > 40 ||
        thumb.find_first_not_of("0123456789abcdefABCDEF") != std::string::npos) {
        throw UsageError("'" + thumb + "' is not a thumbprint (at least 8 hex digits)");
    }
}

Json entryJson(const pki::StoreEntry& e) {
    const pki::Certificate& c = e.certificate;
    return Json{{"thumbprint", c.thumbprintHex()},
                {"state", std::string(pki::toString(e.state))},
                {"subject", c.subject()},
                {"issuer", c.issuer()},
                {"applicationUri", c.uris().empty() ? std::string() : c.uris().front()},
                {"uris", c.uris()},
                {"dnsNames", c.dnsNames()},
                {"ipAddresses", c.ipAddresses()},
                {"serial", c.serialHex()},
                {"notBefore", utc(c.notBefore())},
                {"notAfter", utc(c.notAfter())},
                {"keyBits", c.keyBits()},
                {"signatureAlgorithm", c.signatureAlgorithm()},
                {"ca", c.isCa()},
                {"selfSigned", c.isSelfSigned()},
                {"file", e.file.string()}};
}

int runList(const PkiOptions& o) {
    pki::CertificateStore store(pkiRoot(o));
    const auto entries = store.list();
    if (o.json) {
        Json list = Json::array();
        for (const auto& e : entries) list.push_back(entryJson(e));
        std::cout << list.dump(2) << '\n';
        return kExitOk;
    }
    Table table({"THUMBPRINT", "STATE", "SUBJECT", "APPLICATION URI", "NOT AFTER"});
    for (const auto& e : entries) {
        const auto uris = e.certificate.uris();
        table.add({e.certificate.thumbprintHex().substr(0, 16), std::string(pki::toString(e.state)),
                   e.certificate.subject(), uris.empty() ? "-" : uris.front(),
                   utc(e.certificate.notAfter())});
    }
    if (table.empty()) {
        std::cerr << "no certificates in " << store.root().string() << "\n";
        return kExitOk;
    }
    table.print(std::cout);
    return kExitOk;
}

int runShow(const PkiOptions& o) {
    checkThumb(o.thumb);
    pki::CertificateStore store(pkiRoot(o));
    const auto e = store.find(o.thumb);
    if (!e) throw pki::PkiError("no certificate with thumbprint " + o.thumb);
    if (o.json) {
        std::cout << entryJson(*e).dump(2) << '\n';
        return kExitOk;
    }
    const pki::Certificate& c = e->certificate;
    Table t({"FIELD", "VALUE"});
    t.add({"thumbprint", c.thumbprintHex()});
    t.add({"state", std::string(pki::toString(e->state))});
    t.add({"file", e->file.string()});
    t.add({"subject", c.subject()});
    t.add({"issuer", c.issuer()});
    t.add({"serial", c.serialHex()});
    t.add({"not before", utc(c.notBefore())});
    t.add({"not after", utc(c.notAfter())});
    t.add({"application uri", joined(c.uris())});
    t.add({"dns names", joined(c.dnsNames())});
    t.add({"ip addresses", joined(c.ipAddresses())});
    t.add({"key", std::to_string(c.keyBits()) + " bit RSA"});
    t.add({"signature", c.signatureAlgorithm()});
    t.add({"ca", c.isCa() ? "yes" : "no"});
    t.add({"self-signed", c.isSelfSigned() ? "yes" : "no"});
    t.print(std::cout);
    return kExitOk;
}

int runTrust(const PkiOptions& o) {
    pki::CertificateStore store(pkiRoot(o));
    std::error_code ec;
    if (fs::is_regular_file(o.thumb, ec)) {
        const pki::Certificate cert = pki::Certificate::load(o.thumb);
        store.addTrusted(cert);
        std::cout << "trusted " << cert.thumbprintHex() << "  " << cert.subject() << '\n';
        return kExitOk;
    }
    checkThumb(o.thumb);
    store.trust(o.thumb);
    const auto e = store.find(o.thumb);
    std::cout << "trusted "
              << (e ? e->certificate.thumbprintHex() + "  " + e->certificate.subject() : o.thumb)
              << '\n';
    return kExitOk;
}

int runReject(const PkiOptions& o) {
    checkThumb(o.thumb);
    pki::CertificateStore store(pkiRoot(o));
    store.reject(o.thumb);
    std::cout << "rejected " << o.thumb << '\n';
    return kExitOk;
}

int runRemove(const PkiOptions& o) {
    checkThumb(o.thumb);
    pki::CertificateStore store(pkiRoot(o));
    store.remove(o.thumb);
    std::cout << "removed " << o.thumb << '\n';
    return kExitOk;
}

void writeFile(const std::string& file, std::string_view data, bool secret) {
    // A key file is created 0600 before anything is written to it.
    std::error_code ec;
    fs::remove(file, ec);
    const int fd =
        ::open(file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, secret ? 0600 : 0644);
    if (fd < 0) throw pki::PkiError("cannot create " + file + ": " + std::strerror(errno));
    std::size_t done = 0;
    while (done < data.size()) {
        const ssize_t n = ::write(fd, data.data() + done, data.size() - done);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) break;
        done += static_cast<std::size_t>(n);
    }
    if (::close(fd) != 0 || done != data.size()) throw pki::PkiError("cannot write " + file);
}

int runCreate(const PkiOptions& o) {
    if (o.outCert.empty() != o.outKey.empty()) {
        throw UsageError("--out-cert and --out-key go together");
    }
    if (!o.ca && o.uri.empty()) throw UsageError("--uri is required (the ApplicationUri)");
    pki::CertificateRequest r;
    r.applicationUri = o.uri;
    r.commonName = o.name;
    r.organization = o.organization;
    r.dnsNames = o.dns;
    r.ipAddresses = o.ips;
    r.ca = o.ca;
    r.keyBits = o.keyBits;
    r.validity = std::chrono::hours(24) * o.days;
    const pki::Identity id = pki::createSelfSigned(r);
    if (!o.outCert.empty()) {
        const bool pem = o.outCert.ends_with(".pem");
        const std::string cert =
            pem ? id.certificate.toPem()
                : std::string(id.certificate.der().begin(), id.certificate.der().end());
        writeFile(o.outCert, cert, false);
        writeFile(o.outKey, id.key.toPem(), true);
        std::cout << "created " << id.certificate.thumbprintHex() << "  " << o.outCert << " "
                  << o.outKey << '\n';
        return kExitOk;
    }
    pki::CertificateStore store(pkiRoot(o));
    store.setOwn(id, o.ownName);
    std::cout << "created " << id.certificate.thumbprintHex() << "  "
              << (store.root() / "own" / "certs" / (o.ownName + ".der")).string() << '\n';
    return kExitOk;
}

int runExport(const PkiOptions& o) {
    pki::CertificateStore store(pkiRoot(o));
    const auto cert = store.ownCertificate(o.ownName);
    if (!cert) {
        throw pki::PkiError("no own certificate '" + o.ownName + "' in " + store.root().string() +
                            " (create one with `pnp pki create`)");
    }
    const std::string data =
        o.pem ? cert->toPem() : std::string(cert->der().begin(), cert->der().end());
    if (!o.out.empty()) {
        writeFile(o.out, data, false);
        return kExitOk;
    }
    if (!o.pem && ::isatty(1)) {
        throw UsageError("DER is binary: give --out FILE or --pem, or redirect stdout");
    }
    std::cout.write(data.data(), static_cast<std::streamsize>(data.size()));
    std::cout.flush();
    return kExitOk;
}

}  // namespace

std::function<int()> addPkiCommands(CLI::App& app) {
    auto o = std::make_shared<PkiOptions>();
    CLI::App* cmd = app.add_subcommand(
        "pki", "application certificates and trust: list, approve or reject peers (PKI folder)");
    cmd->require_subcommand(1);
    cmd->add_option("--pki", o->dir,
                    "the PKI folder (default $PNP_PKI, else "
                    "${XDG_DATA_HOME:-$HOME/.local/share}/pnp/pki)");
    cmd->footer(
        "Layout: own/{certs,private} trusted/{certs,crl} issuers/{certs,crl} rejected/certs.\n"
        "A peer that was refused lands in rejected/; approve it with `pnp pki trust THUMB`.\n"
        "THUMB: the SHA-1 thumbprint (hex), or a unique prefix of at least 8 digits.\n"
        "Exit codes: 0 ok, 1 error, 2 usage error.");

    CLI::App* list = cmd->add_subcommand("list", "the certificates of the folder and their state");
    list->add_flag("--json", o->json, "print a JSON array");

    CLI::App* show = cmd->add_subcommand("show", "details of one certificate");
    show->add_option("THUMB", o->thumb, "thumbprint or prefix")->required();
    show->add_flag("--json", o->json, "print JSON");

    CLI::App* trust = cmd->add_subcommand(
        "trust", "trust a certificate (rejected/ -> trusted/), or import a certificate FILE");
    trust->add_option("THUMB", o->thumb, "thumbprint, prefix, or a .der / .pem file")->required();

    CLI::App* reject =
        cmd->add_subcommand("reject", "no longer trust a certificate (-> rejected/)");
    reject->add_option("THUMB", o->thumb, "thumbprint or prefix")->required();

    CLI::App* remove = cmd->add_subcommand("remove", "delete a certificate from the folder");
    remove->add_option("THUMB", o->thumb, "thumbprint or prefix")->required();

    CLI::App* create = cmd->add_subcommand(
        "create", "create a self-signed certificate: the own one (own/), or into files");
    create->add_option("--uri", o->uri, "the ApplicationUri (SubjectAltName URI)");
    create->add_option("--name", o->name, "the application name (CN)")->required();
    create->add_option("--org", o->organization, "the organization (O)")->capture_default_str();
    create->add_option("--dns", o->dns, "a host name (SubjectAltName DNS, repeatable)");
    create->add_option("--ip", o->ips, "an IP address (SubjectAltName IP, repeatable)");
    create->add_flag("--ca", o->ca, "a certificate authority (signs other certificates)");
    create->add_option("--days", o->days, "validity in days")
        ->capture_default_str()
        ->check(CLI::Range(1, 365 * 30));
    create->add_option("--key-bits", o->keyBits, "RSA key size")
        ->capture_default_str()
        ->check(CLI::IsMember({2048, 3072, 4096}));
    create->add_option("--out-cert", o->outCert, "write the certificate here (.der, or .pem)");
    create->add_option("--out-key", o->outKey, "write the private key here (PEM, mode 0600)");
    create->add_option("--own-name", o->ownName, "own/certs/NAME.der when not --out-cert")
        ->capture_default_str();

    CLI::App* exportCmd =
        cmd->add_subcommand("export", "print the own certificate (DER, or --pem) or write --out");
    exportCmd->add_option("--name", o->ownName, "own/certs/NAME.der")->capture_default_str();
    exportCmd->add_flag("--pem", o->pem, "PEM instead of DER");
    exportCmd->add_option("--out", o->out, "write to FILE instead of stdout");

    return [=]() -> int {
        if (!*cmd) return -1;
        if (*list) return runList(*o);
        if (*show) return runShow(*o);
        if (*trust) return runTrust(*o);
        if (*reject) return runReject(*o);
        if (*remove) return runRemove(*o);
        if (*create) return runCreate(*o);
        if (*exportCmd) return runExport(*o);
        return kExitUsage;
    };
}

}  // namespace pnp::cli
