// The PKI folder (own / trusted / issuers / rejected, node-opcua's and Part 12 Annex F's
// layout) and certificate validation in the order of OPC 10000-4 §6.1.3 Table 106.
//
// The folder's contents are cached: each directory is re-read only when its mtime changed
// (or changed so recently that a second change could share the timestamp), so validate()
// costs a few stat() calls plus the signature checks. The OpenSSL X509_STORE built from it
// is immutable once published; validations share it without holding the mutex.
#include <arpa/inet.h>
#include <fcntl.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <mutex>
#include <optional>

#include "openssl_util.hpp"
#include "ua/pki/pki.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::pki {

using namespace detail;
namespace fs = std::filesystem;

namespace {

constexpr std::size_t kMaxFilesPerDirectory = 4096;  // beyond: ignored (bounded scan)
constexpr std::size_t kMaxCrlFile = 4 * 1024 * 1024;
constexpr std::size_t kMaxRecordedErrors = 64;
constexpr auto kRacyWindow = std::chrono::milliseconds(50);

using Thumb = std::string;  // raw SHA-1 (20 bytes)

Thumb thumbOf(X509* cert) {
    unsigned char md[EVP_MAX_MD_SIZE];
    unsigned int len = 0;
    if (X509_digest(cert, EVP_sha1(), md, &len) != 1) {
        ERR_clear_error();
        return {};
    }
    return Thumb(reinterpret_cast<const char*>(md), len);
}

Thumb thumbOf(const Certificate& cert) {
    const Bytes t = cert.thumbprint();
    return Thumb(t.begin(), t.end());
}

bool sameTimespec(const timespec& a, const timespec& b) {
    return a.tv_sec == b.tv_sec && a.tv_nsec == b.tv_nsec;
}

// Writes via a temporary file and rename(): readers never see half a file.
void writeAtomic(const fs::path& file, ByteView data, mode_t mode) {
    static std::atomic<unsigned> counter{0};
    const fs::path tmp = file.string() + ".tmp." + std::to_string(::getpid()) + "." +
                         std::to_string(counter.fetch_add(1));
    const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, mode);
    if (fd < 0) throw PkiError("cannot create " + tmp.string() + ": " + std::strerror(errno));
    std::size_t done = 0;
    while (done < data.size()) {
        const ssize_t n = ::write(fd, data.data() + done, data.size() - done);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) {
            const int err = errno;
            ::close(fd);
            ::unlink(tmp.c_str());
            throw PkiError("cannot write " + tmp.string() + ": " + std::strerror(err));
        }
        done += static_cast<std::size_t>(n);
    }
    ::fchmod(fd, mode);  // the umask may have taken bits away; never adds to `mode`
    if (::close(fd) != 0 || ::rename(tmp.c_str(), file.c_str()) != 0) {
        const int err = errno;
        ::unlink(tmp.c_str());
        throw PkiError("cannot write " + file.string() + ": " + std::strerror(err));
    }
}

void writeAtomic(const fs::path& file, std::string_view text, mode_t mode) {
    writeAtomic(file, crypto::view(text), mode);
}

void removeFile(const fs::path& file) {
    if (::unlink(file.c_str()) != 0 && errno != ENOENT) {
        throw PkiError("cannot remove " + file.string() + ": " + std::strerror(errno));
    }
}

bool isCertificateFile(const fs::path& p) {
    const std::string ext = p.extension().string();
    return ext == ".der" || ext == ".pem" || ext == ".crt" || ext == ".cer";
}

bool isCrlFile(const fs::path& p) {
    const std::string ext = p.extension().string();
    return ext == ".crl" || ext == ".der" || ext == ".pem";
}

X509CrlPtr parseCrl(std::string_view data) {
    X509CrlPtr crl;
    if (data.find("-----BEGIN") != std::string_view::npos) {
        BioPtr bio(BIO_new_mem_buf(data.data(), static_cast<int>(data.size())));
        if (bio) crl.reset(PEM_read_bio_X509_CRL(bio.get(), nullptr, nullptr, nullptr));
    } else {
        const auto* p = reinterpret_cast<const unsigned char*>(data.data());
        crl.reset(d2i_X509_CRL(nullptr, &p, static_cast<long>(data.size())));
        if (crl && p != reinterpret_cast<const unsigned char*>(data.data()) + data.size()) {
            crl.reset();
        }
    }
    ERR_clear_error();
    return crl;
}

std::string utcStamp() {
    const std::time_t t = std::time(nullptr);
    std::tm tm{};
    gmtime_r(&t, &tm);
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y%m%dT%H%M%SZ", &tm);
    return buf;
}

// own/certs/<name>.<stamp>.der: a replaced own certificate kept for reference
// (<stamp> as utcStamp() writes it: YYYYMMDDTHHMMSSZ).
bool isArchivedOwn(const fs::path& p) {
    constexpr std::string_view kStamp = "ddddddddTddddddZ";  // d: a digit
    const std::string stem = p.stem().string();
    if (stem.size() < kStamp.size() + 2 || stem[stem.size() - kStamp.size() - 1] != '.') {
        return false;
    }
    const std::string_view tail = std::string_view(stem).substr(stem.size() - kStamp.size());
    for (std::size_t i = 0; i < kStamp.size(); ++i) {
        const bool ok = kStamp[i] == 'd' ? std::isdigit(static_cast<unsigned char>(tail[i])) != 0
                                         : tail[i] == kStamp[i];
        if (!ok) return false;
    }
    return true;
}

void checkOwnName(std::string_view name) {
    const bool ok =
        !name.empty() && name.size() <= 64 && std::all_of(name.begin(), name.end(), [](char c) {
            return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_';
        });
    if (!ok) throw PkiError("invalid certificate name '" + std::string(name) + "' ([A-Za-z0-9_-])");
}

std::string lower(std::string_view s) {
    std::string out(s);
    std::transform(out.begin(), out.end(), out.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return out;
}

// "::1", "[::1]", "10.0.0.1" -> canonical text; "" when not an address.
std::string canonicalIp(std::string host) {
    if (host.size() > 2 && host.front() == '[' && host.back() == ']') {
        host = host.substr(1, host.size() - 2);
    }
    unsigned char buf[16];
    char text[INET6_ADDRSTRLEN] = {};
    if (inet_pton(AF_INET, host.c_str(), buf) == 1) {
        return inet_ntop(AF_INET, buf, text, sizeof text) ? text : "";
    }
    if (inet_pton(AF_INET6, host.c_str(), buf) == 1) {
        return inet_ntop(AF_INET6, buf, text, sizeof text) ? text : "";
    }
    return {};
}

EvpPkeyPtr loadPrivateKey(const fs::path& file) {
    const std::string pem = readFileBounded(file, 64 * 1024);
    BioPtr bio(BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size())));
    EvpPkeyPtr key(bio ? PEM_read_bio_PrivateKey(bio.get(), nullptr, nullptr, nullptr) : nullptr);
    ERR_clear_error();
    if (!key) throw PkiError(file.string() + ": not a PEM private key");
    return key;
}

std::string privateKeyPem(const crypto::PrivateKey& key) {
    BioPtr bio(BIO_new(BIO_s_mem()));
    check(bio && PEM_write_bio_PKCS8PrivateKey(bio.get(), key.native(), nullptr, nullptr, 0,
                                               nullptr, nullptr) == 1,
          "private key PEM");
    char* data = nullptr;
    const long n = BIO_get_mem_data(bio.get(), &data);
    return std::string(data, static_cast<std::size_t>(n));
}

bool keyMatches(const Certificate& cert, EVP_PKEY* key) {
    const bool ok = X509_check_private_key(cert.native(), key) == 1;
    ERR_clear_error();
    return ok;
}

// One directory of the folder, as last read.
struct DirCache {
    fs::path dir;
    bool valid = false;
    bool racy = false;
    bool exists = false;
    timespec mtime{};
    std::vector<StoreEntry> certs;                                     // certificate directories
    std::vector<std::pair<fs::path, std::shared_ptr<X509_CRL>>> crls;  // CRL directories
};

// Whether `d` changed since it was last read (then its state is updated: the caller reads it).
bool changedSinceRead(DirCache& d) {
    struct stat st {};
    const bool exists = ::stat(d.dir.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
    if (d.valid && !d.racy && exists == d.exists &&
        (!exists || sameTimespec(st.st_mtim, d.mtime))) {
        return false;
    }
    d.valid = true;
    d.exists = exists;
    d.mtime = exists ? st.st_mtim : timespec{};
    const auto modified = std::chrono::system_clock::time_point(
        std::chrono::duration_cast<std::chrono::system_clock::duration>(
            std::chrono::seconds(d.mtime.tv_sec) + std::chrono::nanoseconds(d.mtime.tv_nsec)));
    d.racy = exists && std::chrono::system_clock::now() - modified < kRacyWindow;
    return true;
}

// The files of a certificate directory (bounded), sorted.
std::vector<fs::path> certificateFiles(const fs::path& dir, bool crlDir) {
    std::error_code ec;
    std::vector<fs::path> files;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
        if (files.size() == kMaxFilesPerDirectory) break;
        std::error_code fec;
        if (!it->is_regular_file(fec)) continue;
        const fs::path& p = it->path();
        if (p.filename().string().find(".tmp.") != std::string::npos) continue;
        if (crlDir ? isCrlFile(p) : isCertificateFile(p)) files.push_back(p);
    }
    std::sort(files.begin(), files.end());
    return files;
}

// own/certs as the thumbprints that trustOwn adds to the trust list: the SHA-1 of each DER
// file, without parsing it (a folder shared by many applications holds many). True when
// they changed.
bool refreshThumbprints(DirCache& d, std::vector<Thumb>& out) {
    if (!changedSinceRead(d)) return false;
    out.clear();
    if (!d.exists) return true;
    for (const fs::path& p : certificateFiles(d.dir, false)) {
        if (isArchivedOwn(p)) continue;
        try {
            const std::string bytes = readFileBounded(p, kMaxCertificateSize);
            if (p.extension() == ".der") {
                unsigned char md[EVP_MAX_MD_SIZE];
                unsigned int len = 0;
                if (EVP_Digest(bytes.data(), bytes.size(), md, &len, EVP_sha1(), nullptr) == 1)
                    out.emplace_back(reinterpret_cast<const char*>(md), len);
            } else {
                out.push_back(thumbOf(Certificate::load(p)));
            }
        } catch (const std::exception&) {
            // not a certificate of the store
        }
        ERR_clear_error();
    }
    return true;
}

// Re-reads `d` if it changed; true when it did.
bool refreshDir(DirCache& d, bool crlDir, TrustState state) {
    if (!changedSinceRead(d)) return false;
    d.certs.clear();
    d.crls.clear();
    if (!d.exists) return true;
    for (const fs::path& p : certificateFiles(d.dir, crlDir)) {
        try {
            if (crlDir) {
                X509CrlPtr crl = parseCrl(readFileBounded(p, kMaxCrlFile));
                if (crl)
                    d.crls.emplace_back(p, std::shared_ptr<X509_CRL>(crl.release(), X509_CRL_free));
            } else {
                if (state == TrustState::Own && isArchivedOwn(p)) continue;
                d.certs.push_back(StoreEntry{Certificate::load(p), state, p});
            }
        } catch (const std::exception&) {
            // A file that does not parse is not a certificate of the store: skipped.
        }
    }
    return true;
}

// What validate() needs, built from trusted/ and issuers/; immutable once published.
struct TrustSnapshot {
    X509StorePtr store;
    std::vector<Thumb> trusted;  // sorted SHA-1 of trusted/certs
    bool isTrusted(const Thumb& t) const {
        return std::binary_search(trusted.begin(), trusted.end(), t);
    }
};

// Steps of OPC 10000-4 Table 106, in their order.
enum Step {
    kStructure,
    kChain,
    kSignature,
    kPolicy,
    kTrust,
    kValidity,
    kHostName,
    kUri,
    kUsage,
    kFindRevocation,
    kRevocation,
    kStepCount
};

struct Finding {
    int step;
    int depth;
    StatusCode status;
};

// The errors OpenSSL reports while it verifies (the callback lets it go on, so that the
// step that comes first in Table 106 decides, not the one OpenSSL meets first).
struct VerifyErrors {
    std::vector<std::pair<int, int>> errors;  // X509_V_ERR_*, depth
};

int verifyCallback(int ok, X509_STORE_CTX* ctx) {
    if (ok == 0) {
        auto* found = static_cast<VerifyErrors*>(X509_STORE_CTX_get_app_data(ctx));
        if (found != nullptr && found->errors.size() < kMaxRecordedErrors) {
            found->errors.emplace_back(X509_STORE_CTX_get_error(ctx),
                                       X509_STORE_CTX_get_error_depth(ctx));
        }
    }
    return 1;
}

// The Table 106 step and status of one OpenSSL verification error at `depth`.
Finding classify(int error, int depth) {
    const bool leaf = depth == 0;
    switch (error) {
        case X509_V_ERR_UNABLE_TO_GET_ISSUER_CERT:
        case X509_V_ERR_UNABLE_TO_GET_ISSUER_CERT_LOCALLY:
        case X509_V_ERR_UNABLE_TO_VERIFY_LEAF_SIGNATURE:
            return {kChain, depth, status::BadCertificateChainIncomplete};
        case X509_V_ERR_CERT_SIGNATURE_FAILURE:
        case X509_V_ERR_UNABLE_TO_DECRYPT_CERT_SIGNATURE:
        case X509_V_ERR_UNABLE_TO_DECODE_ISSUER_PUBLIC_KEY:
            return {kSignature, depth, status::BadCertificateInvalid};
        case X509_V_ERR_DEPTH_ZERO_SELF_SIGNED_CERT:
        case X509_V_ERR_SELF_SIGNED_CERT_IN_CHAIN:
        case X509_V_ERR_CERT_UNTRUSTED:
        case X509_V_ERR_CERT_REJECTED:
            return {kTrust, depth, status::BadCertificateUntrusted};
        case X509_V_ERR_CERT_NOT_YET_VALID:
        case X509_V_ERR_CERT_HAS_EXPIRED:
            return {
                kValidity, depth,
                leaf ? status::BadCertificateTimeInvalid : status::BadCertificateIssuerTimeInvalid};
        case X509_V_ERR_INVALID_CA:
        case X509_V_ERR_KEYUSAGE_NO_CERTSIGN:
        case X509_V_ERR_PATH_LENGTH_EXCEEDED:
        case X509_V_ERR_INVALID_PURPOSE:
            return {kUsage, depth,
                    leaf ? status::BadCertificateUseNotAllowed
                         : status::BadCertificateIssuerUseNotAllowed};
        case X509_V_ERR_UNABLE_TO_GET_CRL:
        case X509_V_ERR_CRL_NOT_YET_VALID:
        case X509_V_ERR_CRL_HAS_EXPIRED:
        case X509_V_ERR_CRL_SIGNATURE_FAILURE:
        case X509_V_ERR_UNABLE_TO_DECRYPT_CRL_SIGNATURE:
        case X509_V_ERR_ERROR_IN_CRL_LAST_UPDATE_FIELD:
        case X509_V_ERR_ERROR_IN_CRL_NEXT_UPDATE_FIELD:
        case X509_V_ERR_KEYUSAGE_NO_CRL_SIGN:
        case X509_V_ERR_UNABLE_TO_GET_CRL_ISSUER:
        case X509_V_ERR_DIFFERENT_CRL_SCOPE:
        case X509_V_ERR_CRL_PATH_VALIDATION_ERROR:
        case X509_V_ERR_UNHANDLED_CRITICAL_CRL_EXTENSION:
            return {kFindRevocation, depth,
                    leaf ? status::BadCertificateRevocationUnknown
                         : status::BadCertificateIssuerRevocationUnknown};
        case X509_V_ERR_CERT_REVOKED:
            return {kRevocation, depth,
                    leaf ? status::BadCertificateRevoked : status::BadCertificateIssuerRevoked};
        default:
            // Malformed fields, unhandled critical extensions, anything else: not usable.
            return {kStructure, depth, status::BadCertificateInvalid};
    }
}

bool weakSignature(X509* cert) {
    int mdnid = NID_undef;
    if (X509_get_signature_info(cert, &mdnid, nullptr, nullptr, nullptr) != 1) {
        ERR_clear_error();
        return true;
    }
    return mdnid == NID_sha1 || mdnid == NID_md5 || mdnid == NID_md5_sha1;
}

bool hostMatches(const Certificate& cert, const std::string& host) {
    const std::string ip = canonicalIp(host);
    if (!ip.empty()) {
        const auto ips = cert.ipAddresses();
        return std::find(ips.begin(), ips.end(), ip) != ips.end();
    }
    std::string wanted = lower(host);
    if (!wanted.empty() && wanted.back() == '.') wanted.pop_back();
    for (const std::string& dns : cert.dnsNames()) {
        std::string name = lower(dns);
        if (!name.empty() && name.back() == '.') name.pop_back();
        if (name == wanted) return true;
    }
    return false;
}

}  // namespace

// ---------------------------------------------------------------------------------------
struct CertificateStore::Impl {
    fs::path root;
    StoreConfig config;
    mutable std::mutex mutex;
    DirCache own, trusted, trustedCrl, issuers, issuersCrl, rejected;
    DirCache ownTrust;  // own/certs again, as thumbprints only (trustOwn)
    std::vector<Thumb> ownThumbprints;
    std::shared_ptr<const TrustSnapshot> snapshot;

    Impl(fs::path r, StoreConfig c) : root(std::move(r)), config(c) {
        own.dir = root / "own" / "certs";
        ownTrust.dir = own.dir;
        trusted.dir = root / "trusted" / "certs";
        trustedCrl.dir = root / "trusted" / "crl";
        issuers.dir = root / "issuers" / "certs";
        issuersCrl.dir = root / "issuers" / "crl";
        rejected.dir = root / "rejected" / "certs";
    }

    fs::path ownCertFile(std::string_view name) const {
        return root / "own" / "certs" / (std::string(name) + ".der");
    }
    fs::path ownKeyFile(std::string_view name) const {
        return root / "own" / "private" / (std::string(name) + ".pem");
    }

    void ensureLayout() {
        for (const char* sub :
             {"", "own", "own/certs", "own/private", "trusted", "trusted/certs", "trusted/crl",
              "issuers", "issuers/certs", "issuers/crl", "rejected", "rejected/certs"}) {
            const fs::path dir = *sub ? root / sub : root;
            std::error_code ec;
            if (fs::is_directory(dir, ec)) continue;
            std::error_code cec;
            fs::create_directories(dir.parent_path(), cec);
            if (::mkdir(dir.c_str(), 0700) != 0 && errno != EEXIST) {
                throw PkiError("cannot create " + dir.string() + ": " + std::strerror(errno));
            }
        }
        ::chmod((root / "own" / "private").c_str(), 0700);
    }

    // The trust snapshot, rebuilt when trusted/ or issuers/ changed. Under the mutex.
    std::shared_ptr<const TrustSnapshot> trustSnapshot() {
        bool changed = refreshDir(trusted, false, TrustState::Trusted);
        changed = refreshDir(trustedCrl, true, TrustState::Trusted) || changed;
        changed = refreshDir(issuers, false, TrustState::Issuer) || changed;
        changed = refreshDir(issuersCrl, true, TrustState::Issuer) || changed;
        if (config.trustOwn) changed = refreshThumbprints(ownTrust, ownThumbprints) || changed;
        if (snapshot && !changed) return snapshot;
        auto s = std::make_shared<TrustSnapshot>();
        s->store.reset(X509_STORE_new());
        check(s->store != nullptr, "X509_STORE_new");
        // Every certificate of trusted/ and issuers/ is an anchor for OpenSSL's chain
        // building; whether the chain is trusted is decided in validate() (Table 106 step 5).
        for (const DirCache* d : {&trusted, &issuers}) {
            for (const StoreEntry& e : d->certs) {
                if (X509_STORE_add_cert(s->store.get(), e.certificate.native()) != 1) {
                    ERR_clear_error();  // a duplicate: already there
                }
            }
        }
        for (const DirCache* d : {&trustedCrl, &issuersCrl}) {
            for (const auto& [path, crl] : d->crls) {
                if (X509_STORE_add_crl(s->store.get(), crl.get()) != 1) ERR_clear_error();
            }
        }
        for (const StoreEntry& e : trusted.certs) s->trusted.push_back(thumbOf(e.certificate));
        if (config.trustOwn)
            s->trusted.insert(s->trusted.end(), ownThumbprints.begin(), ownThumbprints.end());
        std::sort(s->trusted.begin(), s->trusted.end());
        snapshot = std::move(s);
        return snapshot;
    }

    void refreshAll() {
        trustSnapshot();
        refreshDir(rejected, false, TrustState::Rejected);
        refreshDir(own, false, TrustState::Own);
    }

    void invalidate() {
        for (DirCache* d :
             {&own, &ownTrust, &trusted, &trustedCrl, &issuers, &issuersCrl, &rejected}) {
            d->valid = false;
        }
    }

    std::vector<StoreEntry> entries() {
        refreshAll();
        std::vector<StoreEntry> out;
        for (const DirCache* d : {&own, &trusted, &issuers, &rejected}) {
            out.insert(out.end(), d->certs.begin(), d->certs.end());
        }
        return out;
    }

    // Every entry whose thumbprint starts with `prefix`; PkiError when several certificates
    // match.
    std::vector<StoreEntry> matching(std::string_view prefix) {
        const std::string p = lower(prefix);
        if (p.size() < 8 || p.size() > 40 ||
            p.find_first_not_of("0123456789abcdef") != std::string::npos) {
            throw PkiError("'" + std::string(prefix) +
                           "' is not a thumbprint (8 to 40 hex digits)");
        }
        std::vector<StoreEntry> out;
        std::string thumb;
        for (StoreEntry& e : entries()) {
            const std::string t = e.certificate.thumbprintHex();
            if (t.compare(0, p.size(), p) != 0) continue;
            if (!thumb.empty() && t != thumb) {
                throw PkiError("thumbprint prefix " + p + " matches several certificates");
            }
            thumb = t;
            out.push_back(std::move(e));
        }
        return out;
    }

    std::vector<StoreEntry> matchingOrThrow(std::string_view prefix) {
        auto m = matching(prefix);
        if (m.empty()) {
            throw PkiError("no certificate with thumbprint " + lower(prefix) + " in " +
                           root.string());
        }
        return m;
    }

    void keepRejectedBounded() {
        std::vector<std::pair<fs::file_time_type, fs::path>> files;
        std::error_code ec;
        for (fs::directory_iterator it(rejected.dir, ec), end; !ec && it != end; it.increment(ec)) {
            std::error_code fec;
            if (!it->is_regular_file(fec) || !isCertificateFile(it->path())) continue;
            files.emplace_back(it->last_write_time(fec), it->path());
            if (files.size() > 4 * kMaxFilesPerDirectory) break;
        }
        if (files.size() <= config.maxRejected) return;
        std::sort(files.begin(), files.end());
        const std::size_t excess = files.size() - config.maxRejected;
        for (std::size_t i = 0; i < excess; ++i) {
            std::error_code rec;
            fs::remove(files[i].second, rec);
        }
    }

    // An untrusted certificate is kept in rejected/ for the operator (`pnp pki trust`).
    void remember(const Certificate& cert) {
        if (config.maxRejected == 0) return;
        try {
            const fs::path file = rejected.dir / (cert.thumbprintHex() + ".der");
            std::error_code ec;
            if (fs::exists(file, ec)) return;
            ensureLayout();
            writeAtomic(file, cert.der(), 0644);
            keepRejectedBounded();
            rejected.valid = false;
        } catch (const std::exception&) {
            // A full or read-only disk does not change the verdict.
        }
    }

    void writeOwn(const Identity& id, std::string_view name) {
        checkOwnName(name);
        ensureLayout();
        const fs::path certFile = ownCertFile(name);
        const fs::path keyFile = ownKeyFile(name);
        std::error_code ec;
        if (!id.key) {
            // Part 12 UpdateCertificate after CreateSigningRequest: the key stays.
            EvpPkeyPtr current = loadPrivateKey(keyFile);
            if (!keyMatches(id.certificate, current.get())) {
                throw PkiError("the new certificate does not match the private key in " +
                               keyFile.string());
            }
        }
        const std::string stamp = utcStamp();
        if (fs::exists(certFile, ec)) {
            fs::rename(certFile,
                       root / "own" / "certs" / (std::string(name) + "." + stamp + ".der"), ec);
        }
        if (id.key) {
            if (fs::exists(keyFile, ec)) {
                fs::rename(keyFile,
                           root / "own" / "private" / (std::string(name) + "." + stamp + ".pem"),
                           ec);
            }
            writeAtomic(keyFile, privateKeyPem(id.key), 0600);
        }
        writeAtomic(certFile, id.certificate.der(), 0644);
        own.valid = false;
        ownTrust.valid = false;
    }
};

CertificateStore::CertificateStore(std::filesystem::path root, StoreConfig config)
    : impl_(std::make_unique<Impl>(std::move(root), config)) {}

CertificateStore::~CertificateStore() = default;

const std::filesystem::path& CertificateStore::root() const { return impl_->root; }

void CertificateStore::ensureLayout() {
    std::lock_guard lock(impl_->mutex);
    impl_->ensureLayout();
}

namespace {

// An exclusive lock on own/.lock for the life of the object: processes that start together
// (a cell) create one certificate, not one each. Bounded: after 10 s it goes on unlocked (a
// lock held that long is a stuck process; the files are still written atomically).
class OwnFolderLock {
  public:
    explicit OwnFolderLock(const fs::path& root) {
        fd_ = ::open((root / "own" / ".lock").c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0600);
        if (fd_ < 0) return;
        for (int i = 0; i < 1000; ++i) {
            if (::flock(fd_, LOCK_EX | LOCK_NB) == 0) return;
            if (errno != EWOULDBLOCK && errno != EINTR) break;
            ::usleep(10'000);
        }
    }
    ~OwnFolderLock() {
        if (fd_ >= 0) ::close(fd_);  // releases the lock
    }
    OwnFolderLock(const OwnFolderLock&) = delete;
    OwnFolderLock& operator=(const OwnFolderLock&) = delete;

  private:
    int fd_ = -1;
};

constexpr std::string_view kEphemeralKey = "ephemeral";
constexpr std::string_view kPidMark = "-pid";

// The pid of an ephemeral certificate's file name (<name>-pid<PID>.der), or 0.
long ephemeralPid(const fs::path& file) {
    const std::string stem = file.stem().string();
    const auto at = stem.rfind(kPidMark);
    if (at == std::string::npos || file.extension() != ".der") return 0;
    const std::string digits = stem.substr(at + kPidMark.size());
    if (digits.empty() || digits.size() > 9 ||
        !std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; }))
        return 0;
    return std::stol(digits);
}

}  // namespace

namespace {

// The own certificate `name` if it is usable for `request` (its URI, not expired, its key);
// else nullopt, with the key in *reusable when only the URI differs.
std::optional<Identity> loadOwn(const fs::path& certFile, const fs::path& keyFile,
                                const CertificateRequest& request, crypto::PrivateKey* reusable) {
    std::error_code ec;
    if (!fs::exists(certFile, ec) || !fs::exists(keyFile, ec)) return std::nullopt;
    try {
        Certificate cert = Certificate::load(certFile);
        EvpPkeyPtr key = loadPrivateKey(keyFile);
        const auto uris = cert.uris();
        const bool uriOk =
            request.applicationUri.empty() ||
            std::find(uris.begin(), uris.end(), request.applicationUri) != uris.end();
        const bool current = cert.notAfter() > std::chrono::system_clock::now();
        if (!current || !keyMatches(cert, key.get())) return std::nullopt;
        crypto::PrivateKey k(std::shared_ptr<EVP_PKEY>(key.release(), EVP_PKEY_free));
        if (uriOk) return Identity{std::move(cert), std::move(k)};
        if (reusable && k.bits() == request.keyBits) *reusable = std::move(k);
    } catch (const PkiError&) {
        // Unreadable: replaced (the old files are kept with a date).
    }
    return std::nullopt;
}

}  // namespace

Identity CertificateStore::loadOrCreateOwn(const CertificateRequest& request,
                                           std::string_view name) {
    checkOwnName(name);
    const fs::path certFile = impl_->ownCertFile(name);
    const fs::path keyFile = impl_->ownKeyFile(name);
    crypto::PrivateKey reusable;  // the key of a certificate replaced for its URI only
    {
        std::lock_guard lock(impl_->mutex);
        impl_->ensureLayout();
        OwnFolderLock folderLock(impl_->root);
        if (auto own = loadOwn(certFile, keyFile, request, &reusable)) return std::move(*own);
    }
    // Made without holding the locks: an RSA key takes 0.1-0.5 s, and the other applications
    // of the folder keep starting meanwhile.
    CertificateRequest r = request;
    if (!r.key && reusable) r.key = reusable;
    Identity id = createSelfSigned(r);
    std::lock_guard lock(impl_->mutex);
    OwnFolderLock folderLock(impl_->root);
    // Another process may have made one meanwhile: all agree on the first.
    if (auto own = loadOwn(certFile, keyFile, request, nullptr)) return std::move(*own);
    impl_->writeOwn(id, name);
    return id;
}

Identity CertificateStore::createEphemeral(const CertificateRequest& request,
                                           std::string_view name) {
    checkOwnName(name);
    std::lock_guard lock(impl_->mutex);
    impl_->ensureLayout();
    OwnFolderLock folderLock(impl_->root);
    // Certificates of processes that ended without removing theirs.
    std::error_code ec;
    std::size_t seen = 0;
    for (fs::directory_iterator it(impl_->root / "own" / "certs", ec), end;
         !ec && it != end && seen < kMaxFilesPerDirectory; it.increment(ec), ++seen) {
        const long pid = ephemeralPid(it->path());
        if (pid > 0 && ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH) {
            std::error_code rec;
            fs::remove(it->path(), rec);
        }
    }
    const fs::path keyFile = impl_->ownKeyFile(kEphemeralKey);
    crypto::PrivateKey key;
    try {
        if (fs::exists(keyFile, ec)) {
            EvpPkeyPtr k = loadPrivateKey(keyFile);
            key = crypto::PrivateKey(std::shared_ptr<EVP_PKEY>(k.release(), EVP_PKEY_free));
        }
    } catch (const PkiError&) {
        // unreadable: a new one below
    }
    if (!key || key.bits() != request.keyBits) {
        key = crypto::PrivateKey::generateRsa(request.keyBits);
        writeAtomic(keyFile, privateKeyPem(key), 0600);
    }
    CertificateRequest r = request;
    r.key = key;
    Identity id = createSelfSigned(r);
    writeAtomic(impl_->ownCertFile(ephemeralName(name)), id.certificate.der(), 0644);
    impl_->own.valid = false;
    impl_->ownTrust.valid = false;
    return id;
}

std::string CertificateStore::ephemeralName(std::string_view name) {
    return std::string(name.substr(0, 40)) + std::string(kPidMark) + std::to_string(::getpid());
}

void CertificateStore::removeEphemeral(std::string_view name) {
    std::lock_guard lock(impl_->mutex);
    std::error_code ec;
    fs::remove(impl_->ownCertFile(ephemeralName(name)), ec);
    impl_->own.valid = false;
    impl_->ownTrust.valid = false;
}

std::filesystem::path defaultFolder() {
    if (const char* p = std::getenv("PNP_PKI"); p && *p) return p;
    if (const char* x = std::getenv("XDG_DATA_HOME"); x && *x) return fs::path(x) / "pnp" / "pki";
    const char* home = std::getenv("HOME");
    return fs::path(home && *home ? home : "/tmp") / ".local" / "share" / "pnp" / "pki";
}

void CertificateStore::setOwn(const Identity& identity, std::string_view name) {
    if (!identity.certificate.native()) throw PkiError("setOwn: no certificate");
    std::lock_guard lock(impl_->mutex);
    impl_->writeOwn(identity, name);
}

std::optional<Certificate> CertificateStore::ownCertificate(std::string_view name) const {
    checkOwnName(name);
    const fs::path file = impl_->ownCertFile(name);
    std::error_code ec;
    if (!fs::exists(file, ec)) return std::nullopt;
    return Certificate::load(file);
}

StatusCode CertificateStore::validate(const std::vector<Certificate>& chain,
                                      const ValidationOptions& options) {
    if (chain.empty() || chain.front().native() == nullptr) return status::BadCertificateInvalid;
    std::shared_ptr<const TrustSnapshot> snap;
    {
        std::lock_guard lock(impl_->mutex);
        snap = impl_->trustSnapshot();
    }
    const Certificate& leafCert = chain.front();
    X509* leaf = leafCert.native();

    std::vector<Finding> findings;
    auto find = [&](int step, int depth, StatusCode s) { findings.push_back({step, depth, s}); };

    if (X509_get_version(leaf) != X509_VERSION_3)
        find(kStructure, 0, status::BadCertificateInvalid);
    // A self-signed leaf: its own signature (OpenSSL does not check an anchor's).
    const bool selfSigned = X509_self_signed(leaf, 0) == 1;
    ERR_clear_error();
    if (selfSigned && X509_verify(leaf, X509_get0_pubkey(leaf)) != 1) {
        ERR_clear_error();
        find(kSignature, 0, status::BadCertificateInvalid);
    }

    // The chain (leaf first) OpenSSL builds from the peer's certificates, issuers/ and
    // trusted/, with each certificate's signature, validity and CRL checked. A self-signed
    // leaf is its own chain: it is trusted by itself or not at all (Table 106 step 5), its
    // signature was checked above, and no CA publishes a CRL for it.
    std::vector<X509*> built;
    X509StackPtr untrusted;  // outlives ctx, which refers to it
    X509StoreCtxPtr ctx;
    VerifyErrors verifyErrors;
    if (selfSigned) {
        built.push_back(leaf);
        const int from = X509_cmp_current_time(X509_get0_notBefore(leaf));
        const int to = X509_cmp_current_time(X509_get0_notAfter(leaf));
        if (from == 0 || to == 0) {
            find(kStructure, 0, status::BadCertificateInvalid);
        } else if (from > 0 || to < 0) {
            find(kValidity, 0, status::BadCertificateTimeInvalid);
        }
    } else {
        untrusted.reset(sk_X509_new_null());
        ctx.reset(X509_STORE_CTX_new());
        if (!untrusted || !ctx) return status::BadCertificateInvalid;
        for (std::size_t i = 1; i < chain.size(); ++i) {
            if (chain[i].native() == nullptr) continue;
            X509_up_ref(chain[i].native());
            if (sk_X509_push(untrusted.get(), chain[i].native()) == 0) X509_free(chain[i].native());
        }
        if (X509_STORE_CTX_init(ctx.get(), snap->store.get(), leaf, untrusted.get()) != 1) {
            ERR_clear_error();
            return status::BadCertificateInvalid;
        }
        X509_STORE_CTX_set_flags(ctx.get(), X509_V_FLAG_CRL_CHECK | X509_V_FLAG_CRL_CHECK_ALL);
        X509_STORE_CTX_set_verify_cb(ctx.get(), verifyCallback);
        X509_STORE_CTX_set_app_data(ctx.get(), &verifyErrors);
        X509_verify_cert(ctx.get());
        ERR_clear_error();
        if (STACK_OF(X509)* c = X509_STORE_CTX_get0_chain(ctx.get())) {
            for (int i = 0; i < sk_X509_num(c); ++i) built.push_back(sk_X509_value(c, i));
        }
        if (built.empty()) built.push_back(leaf);
    }

    for (const auto& [error, depth] : verifyErrors.errors) {
        // A self-signed root CA has no CRL of an issuer above it: its own revocation is not
        // checked (the trust list decides); the CRLs of its children are.
        if (error == X509_V_ERR_UNABLE_TO_GET_CRL && depth >= 0 &&
            static_cast<std::size_t>(depth) < built.size() &&
            X509_self_signed(built[static_cast<std::size_t>(depth)], 0) == 1) {
            continue;
        }
        findings.push_back(classify(error, depth));
    }
    ERR_clear_error();

    // Step 4, security policy: key sizes and signature hashes.
    const int bits = leafCert.keyBits();
    if (bits < options.minKeyBits || bits > options.maxKeyBits || weakSignature(leaf)) {
        find(kPolicy, 0, status::BadCertificatePolicyCheckFailed);
    }
    for (std::size_t i = 1; i < built.size(); ++i) {
        EVP_PKEY* key = X509_get0_pubkey(built[i]);
        const bool root = X509_self_signed(built[i], 0) == 1;
        if (key == nullptr || EVP_PKEY_get_bits(key) < options.minKeyBits ||
            (!root && weakSignature(built[i]))) {
            find(kPolicy, static_cast<int>(i), status::BadCertificatePolicyCheckFailed);
        }
    }
    ERR_clear_error();

    // Step 5, trust list: the leaf itself, or a CA of its chain, is in trusted/. A
    // self-signed leaf only by itself (not by another certificate with its name and key).
    bool trustedChain = snap->isTrusted(thumbOf(leaf));
    if (!trustedChain && !selfSigned) {
        for (std::size_t i = 1; i < built.size() && !trustedChain; ++i) {
            trustedChain = (X509_get_extension_flags(built[i]) & EXFLAG_CA) != 0 &&
                           snap->isTrusted(thumbOf(built[i]));
        }
    }
    if (!trustedChain) find(kTrust, 0, status::BadCertificateUntrusted);

    // Steps 7 and 8: host name and ApplicationUri (exact).
    if (!options.hostName.empty() && !hostMatches(leafCert, options.hostName)) {
        find(kHostName, 0, status::BadCertificateHostNameInvalid);
    }
    if (!options.applicationUri.empty()) {
        const auto uris = leafCert.uris();
        if (std::find(uris.begin(), uris.end(), options.applicationUri) == uris.end()) {
            find(kUri, 0, status::BadCertificateUriInvalid);
        }
    }

    // Step 9, usage: an application instance certificate signs and encrypts keys; a server
    // needs serverAuth, a client clientAuth (when the extension is there at all).
    const std::uint32_t ku = X509_get_key_usage(leaf);
    const std::uint32_t xku = X509_get_extended_key_usage(leaf);
    const bool kuOk =
        ku == UINT32_MAX || ((ku & KU_DIGITAL_SIGNATURE) != 0 &&
                             (ku & (KU_KEY_ENCIPHERMENT | KU_DATA_ENCIPHERMENT)) != 0);
    const bool serverOk = !options.requireServerAuth || xku == UINT32_MAX || (xku & XKU_SSL_SERVER);
    const bool clientOk = !options.requireClientAuth || xku == UINT32_MAX || (xku & XKU_SSL_CLIENT);
    if (!kuOk || !serverOk || !clientOk) find(kUsage, 0, status::BadCertificateUseNotAllowed);
    ERR_clear_error();

    if (findings.empty()) return StatusCode{};
    const auto first =
        std::min_element(findings.begin(), findings.end(), [](const Finding& a, const Finding& b) {
            return std::pair(a.step, a.depth) < std::pair(b.step, b.depth);
        });
    if (first->status == status::BadCertificateUntrusted) {
        std::lock_guard lock(impl_->mutex);
        impl_->remember(leafCert);
    }
    return first->status;
}

std::vector<StoreEntry> CertificateStore::list() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->entries();
}

std::vector<StoreEntry> CertificateStore::trustList() const {
    std::lock_guard lock(impl_->mutex);
    impl_->trustSnapshot();  // refreshes trusted/ and issuers/
    std::vector<StoreEntry> out = impl_->trusted.certs;
    out.insert(out.end(), impl_->issuers.certs.begin(), impl_->issuers.certs.end());
    return out;
}

std::optional<StoreEntry> CertificateStore::find(std::string_view thumbprintHex) const {
    std::lock_guard lock(impl_->mutex);
    auto m = impl_->matching(thumbprintHex);
    if (m.empty()) return std::nullopt;
    // The most telling state when a certificate is in several places.
    for (TrustState s : {TrustState::Trusted, TrustState::Issuer, TrustState::Rejected}) {
        for (const StoreEntry& e : m) {
            if (e.state == s) return e;
        }
    }
    return m.front();
}

void CertificateStore::trust(std::string_view thumbprintHex) {
    std::lock_guard lock(impl_->mutex);
    const auto m = impl_->matchingOrThrow(thumbprintHex);
    impl_->ensureLayout();
    const Certificate& cert = m.front().certificate;
    const bool already = std::any_of(
        m.begin(), m.end(), [](const StoreEntry& e) { return e.state == TrustState::Trusted; });
    if (!already) {
        writeAtomic(impl_->trusted.dir / (cert.thumbprintHex() + ".der"), cert.der(), 0644);
    }
    for (const StoreEntry& e : m) {
        if (e.state == TrustState::Rejected) removeFile(e.file);
    }
    impl_->invalidate();
}

void CertificateStore::reject(std::string_view thumbprintHex) {
    std::lock_guard lock(impl_->mutex);
    const auto m = impl_->matchingOrThrow(thumbprintHex);
    const bool onlyOwn = std::all_of(
        m.begin(), m.end(), [](const StoreEntry& e) { return e.state == TrustState::Own; });
    if (onlyOwn) throw PkiError("the own certificate cannot be rejected");
    impl_->ensureLayout();
    const Certificate& cert = m.front().certificate;
    const fs::path target = impl_->rejected.dir / (cert.thumbprintHex() + ".der");
    std::error_code ec;
    if (!fs::exists(target, ec)) writeAtomic(target, cert.der(), 0644);
    for (const StoreEntry& e : m) {
        if (e.state == TrustState::Trusted || e.state == TrustState::Issuer) removeFile(e.file);
    }
    impl_->invalidate();
}

void CertificateStore::remove(std::string_view thumbprintHex) {
    std::lock_guard lock(impl_->mutex);
    const auto m = impl_->matchingOrThrow(thumbprintHex);
    bool removed = false;
    for (const StoreEntry& e : m) {
        if (e.state == TrustState::Own) continue;
        removeFile(e.file);
        removed = true;
    }
    if (!removed) {
        throw PkiError("the own certificate is not removed (replace it with `pnp pki create`)");
    }
    impl_->invalidate();
}

void CertificateStore::addTrusted(const Certificate& cert) {
    if (!cert.native()) throw PkiError("addTrusted: no certificate");
    std::lock_guard lock(impl_->mutex);
    impl_->ensureLayout();
    writeAtomic(impl_->trusted.dir / (cert.thumbprintHex() + ".der"), cert.der(), 0644);
    removeFile(impl_->rejected.dir / (cert.thumbprintHex() + ".der"));
    impl_->invalidate();
}

void CertificateStore::addIssuer(const Certificate& cert) {
    if (!cert.native()) throw PkiError("addIssuer: no certificate");
    std::lock_guard lock(impl_->mutex);
    impl_->ensureLayout();
    writeAtomic(impl_->issuers.dir / (cert.thumbprintHex() + ".der"), cert.der(), 0644);
    impl_->invalidate();
}

void CertificateStore::addCrl(ByteView crlDer, bool forIssuers) {
    if (crlDer.size() > kMaxCrlFile) throw PkiError("CRL too large");
    const std::string_view text(reinterpret_cast<const char*>(crlDer.data()), crlDer.size());
    if (text.find("-----BEGIN") != std::string_view::npos) throw PkiError("CRL must be DER");
    X509CrlPtr crl = parseCrl(text);
    if (!crl) throw PkiError("malformed DER CRL");
    // Named after its issuer, so that a newer CRL of the same CA replaces the older one.
    unsigned char* name = nullptr;
    const int n = i2d_X509_NAME(X509_CRL_get_issuer(crl.get()), &name);
    check(n > 0, "CRL issuer");
    unsigned char md[EVP_MAX_MD_SIZE];
    unsigned int len = 0;
    const int ok = EVP_Digest(name, static_cast<std::size_t>(n), md, &len, EVP_sha1(), nullptr);
    OPENSSL_free(name);
    check(ok == 1, "SHA-1");
    std::lock_guard lock(impl_->mutex);
    impl_->ensureLayout();
    const DirCache& dir = forIssuers ? impl_->issuersCrl : impl_->trustedCrl;
    writeAtomic(dir.dir / (hexLower(md, len) + ".crl"), crlDer, 0644);
    impl_->invalidate();
}

}  // namespace pnp::ua::pki
