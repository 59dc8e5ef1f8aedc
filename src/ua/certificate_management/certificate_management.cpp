#include "ua/certificate_management/certificate_management.hpp"

#include <openssl/rand.h>
#include <sys/stat.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string_view>
#include <utility>

#include "ua/certificate_management/trust_list.hpp"
#include "ua/server/roles.hpp"
#include "ua/types/ns0_ids_methods.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::certificate_management {

namespace {

using server::MethodCallContext;
using server::MethodCompletion;
using Clock = std::chrono::steady_clock;

constexpr std::size_t kMaxPrivateKeySize = 16 * 1024;  // PEM of a 4096-bit key: ~3.3 KiB
constexpr std::size_t kMaxIssuerCertificates = 8;
constexpr std::size_t kMinNonceLength = 32;  // CreateSigningRequest with a new key
constexpr std::size_t kMaxTrustListElements = 10'000;
// An open TrustList that sees no call for this long is closed (Part 12: ActivityTimeout), so a
// client that vanished without closing does not lock the trust list for its session's life.
constexpr auto kFileIdleTimeout = std::chrono::minutes(5);

// Node ids of namespace 0 (OPC 10000-12 §7.10, §7.8).
NodeId ns0Node(UInt32 id) { return NodeId(0, id); }
const UInt32 kDefaultApplicationGroup =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup;
namespace tl {
constexpr UInt32 Open =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Open;
constexpr UInt32 Close =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Close;
constexpr UInt32 Read =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Read;
constexpr UInt32 Write =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Write;
constexpr UInt32 GetPosition =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_GetPosition;
constexpr UInt32 SetPosition =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_SetPosition;
constexpr UInt32 OpenWithMasks =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_OpenWithMasks;
constexpr UInt32 CloseAndUpdate =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_CloseAndUpdate;
constexpr UInt32 AddCertificate =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_AddCertificate;
constexpr UInt32 RemoveCertificate =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_RemoveCertificate;
constexpr UInt32 Size =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Size;
constexpr UInt32 OpenCount =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_OpenCount;
constexpr UInt32 Writable =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_Writable;
constexpr UInt32 UserWritable =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_UserWritable;
constexpr UInt32 LastUpdateTime =
    ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_TrustList_LastUpdateTime;
}  // namespace tl

// FileType Open modes (OPC 10000-20 / 10000-5 §C.2.1).
constexpr Byte kModeRead = 0x01;
constexpr Byte kModeWriteEraseExisting = 0x06;

struct OpenFile {
    NodeId session;
    bool writing = false;
    std::vector<Byte> data;  // reading: the encoded snapshot; writing: what was written
    std::size_t position = 0;
    Clock::time_point lastUse;
};

struct Pending {
    pki::Identity identity;  // the certificate and the key it will be used with
};

// Everything the handlers share. Handlers run on the network thread; the work they hand
// off runs on connection threads without the network lock: `mutex` guards the fields.
struct State {
    server::Server& server;
    std::shared_ptr<pki::CertificateStore> store;
    Options options;
    std::string applicationUri;

    std::mutex mutex;
    pki::Identity current;                     // the server's identity now
    std::optional<crypto::PrivateKey> newKey;  // CreateSigningRequest's, until used
    std::optional<Pending> pending;            // UpdateCertificate's, until ApplyChanges
    std::map<UInt32, OpenFile> files;          // TrustList handles
    UInt32 nextHandle = 1;

    State(server::Server& s, std::shared_ptr<pki::CertificateStore> st, Options o)
        : server(s), store(std::move(st)), options(std::move(o)) {}

    // Under mutex.
    void closeIdleFiles() {
        const auto now = Clock::now();
        for (auto it = files.begin(); it != files.end();) {
            if (now - it->second.lastUse > kFileIdleTimeout)
                it = files.erase(it);
            else
                ++it;
        }
    }
    std::size_t filesOf(const NodeId& session) const {
        return static_cast<std::size_t>(
            std::count_if(files.begin(), files.end(),
                          [&](const auto& f) { return f.second.session == session; }));
    }
    // The handle of `session`, or null (a handle of another session is not there for it).
    OpenFile* fileOf(const NodeId& session, UInt32 handle) {
        auto it = files.find(handle);
        if (it == files.end() || !(it->second.session == session)) return nullptr;
        it->second.lastUse = Clock::now();
        return &it->second;
    }
    void publishOpenCount() {
        std::size_t n;
        {
            std::lock_guard lock(mutex);
            n = files.size();
        }
        server.addressSpace().setValue(
            ns0Node(tl::OpenCount),
            DataValue(Variant(static_cast<UInt16>(std::min<std::size_t>(n, 0xFFFF)))));
    }
    // Size and LastUpdateTime after the trust list changed (off the network thread).
    void publishTrustList(std::optional<DateTime> updated) {
        const auto size = detail::encodeTrustList(detail::readTrustList(*store, detail::mask::All,
                                                                        options.maxTrustListSize))
                              .size();
        auto& as = server.addressSpace();
        as.setValue(ns0Node(tl::Size), DataValue(Variant(static_cast<UInt64>(size))));
        if (updated) as.setValue(ns0Node(tl::LastUpdateTime), DataValue(Variant(*updated)));
    }
};

// ---- arguments ------------------------------------------------------------------------------
template <class T>
const T* scalarArg(const std::vector<Variant>& in, std::size_t i) {
    return i < in.size() ? in[i].scalar<T>() : nullptr;
}
// An optional ByteString argument: absent / null is empty.
ByteString bytesArg(const std::vector<Variant>& in, std::size_t i) {
    const ByteString* b = scalarArg<ByteString>(in, i);
    return b ? *b : ByteString{};
}
crypto::ByteView view(const ByteString& b) { return crypto::ByteView(b.data(), b.size()); }

// certificateGroupId (null: the DefaultApplicationGroup) and certificateTypeId (null, or the
// one type of that group): Bad_InvalidArgument for anything else.
StatusCode checkGroupAndType(const std::vector<Variant>& in) {
    const NodeId* group = scalarArg<NodeId>(in, 0);
    const NodeId* type = scalarArg<NodeId>(in, 1);
    if (group == nullptr || type == nullptr) return status::BadInvalidArgument;
    if (!group->isNull() && !(*group == ns0Node(kDefaultApplicationGroup)))
        return status::BadInvalidArgument;
    if (!type->isNull() && !(*type == ns0Node(ns0::RsaSha256ApplicationCertificateType)))
        return status::BadInvalidArgument;
    return StatusCode{};
}

// Runs `work` once the network lock is released (the calling connection's thread), so that
// key generation and the store's files never hold up other clients; a throw fails the call.
// At most once: the transport runs the functions queued for after the lock again when one of
// them takes the lock itself (as sending its response does), so the work guards itself.
void offload(State& s, const MethodCompletion& done, std::function<void()> work) {
    auto started = std::make_shared<std::atomic<bool>>(false);
    s.server.afterResponsesWritten([done, started, work = std::move(work)] {
        if (started->exchange(true)) return;
        try {
            work();
        } catch (const std::exception&) {
            done.fail(status::BadInternalError);
        }
    });
}

std::string lower(std::string s) {
    std::transform(s.begin(), s.end(), s.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return s;
}

// ---- ServerConfiguration ---------------------------------------------------------------------
void updateCertificate(State& s, std::vector<Variant> in, const MethodCompletion& done) {
    if (StatusCode st = checkGroupAndType(in); st.isBad()) return done.fail(st);
    const ByteString* certificate = scalarArg<ByteString>(in, 2);
    if (certificate == nullptr || certificate->empty())
        return done.fail(status::BadCertificateInvalid);
    std::vector<pki::Certificate> issuers;
    if (in.size() > 3) {
        if (const auto* list = in[3].array<ByteString>()) {
            if (list->size() > kMaxIssuerCertificates) return done.fail(status::BadInvalidArgument);
            for (const ByteString& der : *list) {
                try {
                    issuers.push_back(pki::Certificate::fromDer(view(der)));
                } catch (const std::exception&) {
                    return done.fail(status::BadCertificateInvalid);
                }
            }
        }
    }
    const String* format = scalarArg<String>(in, 4);
    const ByteString key = bytesArg(in, 5);
    pki::Certificate leaf;
    try {
        leaf = pki::Certificate::fromDer(view(*certificate));
    } catch (const std::exception&) {
        return done.fail(status::BadCertificateInvalid);
    }
    if (StatusCode st = detail::checkApplicationCertificate(leaf, issuers, s.applicationUri);
        st.isBad())
        return done.fail(st);

    crypto::PrivateKey newKey;
    if (!key.empty()) {
        // Part 12 names "PEM" and "PFX"; PFX (PKCS#12) is not supported.
        if (format == nullptr || lower(*format) != "pem" || key.size() > kMaxPrivateKeySize)
            return done.fail(status::BadNotSupported);
        try {
            newKey = crypto::PrivateKey::fromPem(key.view());
        } catch (const std::exception&) {
            return done.fail(status::BadNotSupported);
        }
        if (newKey.bits() < 2048 || newKey.bits() > 4096)
            return done.fail(status::BadCertificatePolicyCheckFailed);
        if (!detail::sameKey(leaf, newKey)) return done.fail(status::BadSecurityChecksFailed);
    }
    {
        std::lock_guard lock(s.mutex);
        if (!newKey) {
            // The key of the last CreateSigningRequest with a new key, or the current one.
            if (s.newKey && detail::sameKey(leaf, *s.newKey))
                newKey = *s.newKey;
            else if (detail::sameKey(leaf, s.current.key))
                newKey = s.current.key;
            else
                return done.fail(status::BadSecurityChecksFailed);
        }
        s.pending = Pending{pki::Identity{leaf, newKey}};
    }
    done.succeed({Variant(Boolean{true})});  // applyChangesRequired
}

void applyChanges(State& s, const MethodCompletion& done) {
    std::optional<Pending> pending;
    {
        std::lock_guard lock(s.mutex);
        pending = std::exchange(s.pending, std::nullopt);
    }
    if (!pending) return done.succeed({});  // nothing to apply
    offload(s, done, [&s, done, identity = pending->identity] {
        try {
            s.store->setOwn(identity, s.options.ownCertificateName);
        } catch (const std::exception&) {
            std::lock_guard lock(s.mutex);
            if (!s.pending) s.pending = Pending{identity};  // may be applied again
            return done.fail(status::BadInternalError);
        }
        {
            std::lock_guard lock(s.mutex);
            s.current = identity;
            if (s.newKey && detail::sameKey(identity.certificate, *s.newKey)) s.newKey.reset();
        }
        // Answered once the server uses it, so that the client's next connection sees it.
        s.server.post([&s, done, identity] {
            s.server.setSecurityIdentity(identity);
            done.succeed({});
        });
    });
}

// CancelChanges (OPC 10000-12 1.05): the pending certificate is dropped.
void cancelChanges(State& s, const MethodCompletion& done) {
    {
        std::lock_guard lock(s.mutex);
        s.pending.reset();
    }
    done.succeed({});
}

void createSigningRequest(State& s, std::vector<Variant> in, const MethodCompletion& done) {
    if (StatusCode st = checkGroupAndType(in); st.isBad()) return done.fail(st);
    const String* subject = scalarArg<String>(in, 2);
    const Boolean* regenerate = scalarArg<Boolean>(in, 3);
    const ByteString nonce = bytesArg(in, 4);
    if (regenerate == nullptr) return done.fail(status::BadInvalidArgument);
    // Part 12: with a new key the caller adds at least 32 bytes of entropy.
    if (*regenerate && nonce.size() < kMinNonceLength) return done.fail(status::BadInvalidArgument);
    if (subject != nullptr && subject->size() > 1024) return done.fail(status::BadInvalidArgument);
    offload(s, done,
            [&s, done, subject = subject ? *subject : String{}, regenerate = *regenerate, nonce] {
                pki::Identity current;
                {
                    std::lock_guard lock(s.mutex);
                    current = s.current;
                }
                crypto::PrivateKey key = current.key;
                if (regenerate) {
                    if (!nonce.empty()) RAND_add(nonce.data(), static_cast<int>(nonce.size()), 0.0);
                    key =
                        crypto::PrivateKey::generateRsa(std::clamp(current.key.bits(), 2048, 4096));
                }
                pki::CertificateRequest request;
                request.applicationUri = s.applicationUri;
                request.dnsNames = current.certificate.dnsNames();
                request.ipAddresses = current.certificate.ipAddresses();
                crypto::Bytes csr;
                try {
                    csr = pki::createSigningRequest(
                        key, request,
                        subject.empty() ? pki::subjectNameOf(current.certificate) : subject);
                } catch (const pki::PkiError&) {
                    return done.fail(status::BadInvalidArgument);  // the subject name
                }
                if (regenerate) {
                    std::lock_guard lock(s.mutex);
                    s.newKey = key;  // replaces an earlier new key that was not used
                }
                done.succeed({Variant(ByteString(csr.data(), csr.size()))});
            });
}

void getRejectedList(State& s, const MethodCompletion& done) {
    offload(s, done, [&s, done] {
        std::vector<ByteString> out;
        for (const pki::StoreEntry& e : s.store->list()) {
            if (e.state != pki::TrustState::Rejected) continue;
            if (out.size() == s.options.maxRejectedListed) break;
            out.emplace_back(e.certificate.der().data(), e.certificate.der().size());
        }
        done.succeed({Variant(std::move(out))});
    });
}

// ---- TrustList -------------------------------------------------------------------------------
void openFile(State& s, const MethodCallContext& ctx, bool writing, UInt32 masks,
              const MethodCompletion& done) {
    UInt32 handle = 0;
    {
        std::lock_guard lock(s.mutex);
        s.closeIdleFiles();
        if (s.files.size() >= s.options.maxOpenFiles ||
            s.filesOf(ctx.sessionId) >= s.options.maxOpenFilesPerSession)
            return done.fail(status::BadResourceUnavailable);
        // Writing locks the file: no other handle while it is open for writing.
        const bool writer = std::any_of(s.files.begin(), s.files.end(),
                                        [](const auto& f) { return f.second.writing; });
        if (writer || (writing && !s.files.empty())) return done.fail(status::BadInvalidState);
        if (writing) {
            handle = s.nextHandle++;
            if (s.nextHandle == 0) s.nextHandle = 1;
            s.files[handle] = OpenFile{ctx.sessionId, true, {}, 0, Clock::now()};
        }
    }
    if (writing) {
        s.publishOpenCount();
        return done.succeed({Variant(handle)});
    }
    // Reading: a snapshot of the store (its files), taken off the network thread.
    offload(s, done, [&s, done, session = ctx.sessionId, masks] {
        auto data = detail::encodeTrustList(
            detail::readTrustList(*s.store, masks, s.options.maxTrustListSize));
        if (data.size() > s.options.maxTrustListSize)
            return done.fail(status::BadEncodingLimitsExceeded);
        UInt32 handle;
        {
            std::lock_guard lock(s.mutex);
            const bool writer = std::any_of(s.files.begin(), s.files.end(),
                                            [](const auto& f) { return f.second.writing; });
            if (writer) return done.fail(status::BadInvalidState);
            if (s.files.size() >= s.options.maxOpenFiles ||
                s.filesOf(session) >= s.options.maxOpenFilesPerSession)
                return done.fail(status::BadResourceUnavailable);
            handle = s.nextHandle++;
            if (s.nextHandle == 0) s.nextHandle = 1;
            s.files[handle] = OpenFile{session, false, std::move(data), 0, Clock::now()};
        }
        s.publishOpenCount();
        done.succeed({Variant(handle)});
    });
}

void openTrustList(State& s, const MethodCallContext& ctx, std::vector<Variant> in,
                   const MethodCompletion& done) {
    const Byte* mode = scalarArg<Byte>(in, 0);
    if (mode == nullptr || (*mode != kModeRead && *mode != kModeWriteEraseExisting))
        return done.fail(status::BadInvalidArgument);
    openFile(s, ctx, *mode == kModeWriteEraseExisting, detail::mask::All, done);
}

void openWithMasks(State& s, const MethodCallContext& ctx, std::vector<Variant> in,
                   const MethodCompletion& done) {
    const UInt32* masks = scalarArg<UInt32>(in, 0);
    if (masks == nullptr || *masks > detail::mask::All)
        return done.fail(status::BadInvalidArgument);
    openFile(s, ctx, false, *masks, done);
}

// The calling session's handle (argument 0): Bad_InvalidArgument when it is not one of its own.
template <class F>
void withFile(State& s, const MethodCallContext& ctx, const std::vector<Variant>& in,
              const MethodCompletion& done, F&& f) {
    const UInt32* handle = scalarArg<UInt32>(in, 0);
    std::lock_guard lock(s.mutex);
    s.closeIdleFiles();
    OpenFile* file = handle ? s.fileOf(ctx.sessionId, *handle) : nullptr;
    if (file == nullptr) return done.fail(status::BadInvalidArgument);
    f(*file, *handle);
}

void readFile(State& s, const MethodCallContext& ctx, std::vector<Variant> in,
              const MethodCompletion& done) {
    const Int32* length = scalarArg<Int32>(in, 1);
    withFile(s, ctx, in, done, [&](OpenFile& f, UInt32) {
        if (f.writing) return done.fail(status::BadInvalidState);
        if (length == nullptr || *length < 0) return done.fail(status::BadInvalidArgument);
        // At the end: an empty ByteString (Part 5 FileType Read).
        const std::size_t n = std::min({static_cast<std::size_t>(*length), s.options.maxReadLength,
                                        f.data.size() - f.position});
        ByteString chunk(f.data.data() + f.position, n);
        f.position += n;
        done.succeed({Variant(std::move(chunk))});
    });
}

void writeFile(State& s, const MethodCallContext& ctx, std::vector<Variant> in,
               const MethodCompletion& done) {
    const ByteString data = bytesArg(in, 1);
    withFile(s, ctx, in, done, [&](OpenFile& f, UInt32) {
        if (!f.writing) return done.fail(status::BadInvalidState);
        if (data.size() >
            s.options.maxTrustListSize - std::min(f.position, s.options.maxTrustListSize))
            return done.fail(status::BadEncodingLimitsExceeded);
        if (f.position + data.size() > f.data.size()) f.data.resize(f.position + data.size());
        std::copy(data.begin(), data.end(),
                  f.data.begin() + static_cast<std::ptrdiff_t>(f.position));
        f.position += data.size();
        done.succeed({});
    });
}

void getPosition(State& s, const MethodCallContext& ctx, std::vector<Variant> in,
                 const MethodCompletion& done) {
    withFile(s, ctx, in, done, [&](OpenFile& f, UInt32) {
        done.succeed({Variant(static_cast<UInt64>(f.position))});
    });
}

void setPosition(State& s, const MethodCallContext& ctx, std::vector<Variant> in,
                 const MethodCompletion& done) {
    const UInt64* position = scalarArg<UInt64>(in, 1);
    withFile(s, ctx, in, done, [&](OpenFile& f, UInt32) {
        if (position == nullptr) return done.fail(status::BadInvalidArgument);
        // Beyond the end: at the end (Part 5 FileType SetPosition).
        f.position = static_cast<std::size_t>(std::min<UInt64>(*position, f.data.size()));
        done.succeed({});
    });
}

void closeFile(State& s, const MethodCallContext& ctx, std::vector<Variant> in,
               const MethodCompletion& done) {
    bool closed = false;
    withFile(s, ctx, in, done, [&](OpenFile&, UInt32 handle) {
        s.files.erase(handle);
        closed = true;
        done.succeed({});
    });
    if (closed) s.publishOpenCount();
}

void closeAndUpdate(State& s, const MethodCallContext& ctx, std::vector<Variant> in,
                    const MethodCompletion& done) {
    std::optional<std::vector<Byte>> data;
    withFile(s, ctx, in, done, [&](OpenFile& f, UInt32 handle) {
        if (!f.writing) return done.fail(status::BadInvalidState);
        // Closed whatever comes of the update (Part 12: the data is discarded on error).
        data = std::move(f.data);
        s.files.erase(handle);
    });
    if (!data) return;
    s.publishOpenCount();
    offload(s, done, [&s, done, data = std::move(*data)] {
        TrustListDataType list;
        StatusCode st =
            detail::decodeTrustList(data, s.options.maxTrustListSize, kMaxTrustListElements, list);
        if (st.isGood()) st = detail::replaceTrustList(*s.store, list);
        if (st.isBad()) return done.fail(st);
        s.publishTrustList(DateTime::now());
        // The store re-reads its folder when it changed: no ApplyChanges needed.
        done.succeed({Variant(Boolean{false})});
    });
}

// AddCertificate / RemoveCertificate: not while the TrustList is open.
bool trustListOpen(State& s) {
    std::lock_guard lock(s.mutex);
    s.closeIdleFiles();
    return !s.files.empty();
}

void addCertificate(State& s, std::vector<Variant> in, const MethodCompletion& done) {
    const ByteString certificate = bytesArg(in, 0);
    const Boolean* trusted = scalarArg<Boolean>(in, 1);
    if (trusted == nullptr) return done.fail(status::BadInvalidArgument);
    if (trustListOpen(s)) return done.fail(status::BadInvalidState);
    // Part 12: issuer (CA) certificates come with their CRLs, through the file.
    if (!*trusted) return done.fail(status::BadCertificateInvalid);
    offload(s, done, [&s, done, certificate] {
        const StatusCode st = detail::addTrustedCertificate(*s.store, certificate);
        if (st.isBad()) return done.fail(st);
        s.publishTrustList(DateTime::now());
        done.succeed({});
    });
}

void removeCertificate(State& s, std::vector<Variant> in, const MethodCompletion& done) {
    const String* thumbprint = scalarArg<String>(in, 0);
    const Boolean* trusted = scalarArg<Boolean>(in, 1);
    if (thumbprint == nullptr || trusted == nullptr) return done.fail(status::BadInvalidArgument);
    if (trustListOpen(s)) return done.fail(status::BadInvalidState);
    offload(s, done, [&s, done, thumbprint = *thumbprint, trusted = *trusted] {
        const StatusCode st = detail::removeCertificate(*s.store, thumbprint, trusted);
        if (st.isBad()) return done.fail(st);
        s.publishTrustList(DateTime::now());
        done.succeed({});
    });
}

// The newest change of trusted/ and issuers/ (their folders' modification times).
DateTime lastChangeOf(const pki::CertificateStore& store) {
    Int64 newest = 0;
    for (const char* dir : {"trusted/certs", "trusted/crl", "issuers/certs", "issuers/crl"}) {
        struct stat st {};
        if (::stat((store.root() / dir).c_str(), &st) != 0) continue;
        newest =
            std::max<Int64>(newest, Int64{st.st_mtim.tv_sec} * 1'000'000'000 + st.st_mtim.tv_nsec);
    }
    return newest == 0 ? DateTime::now() : DateTime::fromUnixNanos(newest);
}

// The name of the own certificate file that holds `cert` (see Options::ownCertificateName).
std::string ownNameOf(const pki::CertificateStore& store, const pki::Certificate& cert,
                      const std::string& applicationUri) {
    for (const pki::StoreEntry& e : store.list())
        if (e.state == pki::TrustState::Own && e.certificate == cert) return e.file.stem().string();
    std::string name;
    const std::string_view uri = applicationUri;
    for (char c : uri.starts_with("urn:") ? uri.substr(4) : uri)
        name += (std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-') ? c : '-';
    return name.empty() ? "pnp" : name.substr(0, 64);
}

}  // namespace

void enableCertificateManagement(server::Server& server, Options options) {
    const auto& security = server.config().security;
    if (!security || !security->trust)
        throw std::invalid_argument("certificate management needs a server with a trust list");
    enableCertificateManagement(server, security->trust, std::move(options));
}

void enableCertificateManagement(server::Server& server,
                                 std::shared_ptr<pki::CertificateStore> store, Options options) {
    const auto& config = server.config();
    if (!config.security || !config.security->identity.certificate.native())
        throw std::invalid_argument("certificate management needs a secured server");
    if (!store) throw std::invalid_argument("certificate management needs a certificate store");
    if (options.maxOpenFiles == 0 || options.maxOpenFilesPerSession == 0 ||
        options.maxReadLength == 0 || options.maxTrustListSize == 0)
        throw std::invalid_argument("certificate management: every bound must be positive");

    auto s = std::make_shared<State>(server, std::move(store), std::move(options));
    s->applicationUri = config.applicationUri;
    s->current = config.security->identity;
    if (s->options.ownCertificateName.empty())
        s->options.ownCertificateName =
            !config.security->certificateName.empty()
                ? config.security->certificateName
                : ownNameOf(*s->store, s->current.certificate, s->applicationUri);
    auto& as = server.addressSpace();

    // Variables (OPC 10000-12 §7.10.3, §7.8.2).
    std::vector<String> capabilities = s->options.serverCapabilities;
    if (capabilities.empty()) capabilities = config.discovery.serverCapabilities;
    if (capabilities.empty()) capabilities = {"NA"};
    as.setValue(ns0Node(ns0::ServerConfiguration_ServerCapabilities),
                DataValue(Variant(capabilities)));
    as.setValue(ns0Node(ns0::ServerConfiguration_SupportedPrivateKeyFormats),
                DataValue(Variant(std::vector<String>{"PEM"})));
    as.setValue(ns0Node(ns0::ServerConfiguration_MaxTrustListSize),
                DataValue(Variant(static_cast<UInt32>(
                    std::min<std::size_t>(s->options.maxTrustListSize, 0xFFFFFFFFu)))));
    as.setValue(ns0Node(ns0::ServerConfiguration_HasSecureElement),
                DataValue(Variant(Boolean{false})));
    as.setValue(
        ns0Node(
            ns0::ServerConfiguration_CertificateGroups_DefaultApplicationGroup_CertificateTypes),
        DataValue(Variant(std::vector<NodeId>{ns0Node(ns0::RsaSha256ApplicationCertificateType)})));
    as.setValue(ns0Node(tl::Writable), DataValue(Variant(Boolean{true})));
    as.setValue(ns0Node(tl::UserWritable), DataValue(Variant(Boolean{true})));
    as.setValue(ns0Node(tl::OpenCount), DataValue(Variant(UInt16{0})));
    as.setValue(ns0Node(tl::LastUpdateTime), DataValue(Variant(lastChangeOf(*s->store))));
    s->publishTrustList(std::nullopt);

    // The handles of a session end with it (observers live as long as the server: weak).
    std::weak_ptr<State> weak = s;
    server.onSessionClosed([weak](const NodeId& session) {
        auto state = weak.lock();
        if (!state) return;
        bool closed = false;
        {
            std::lock_guard lock(state->mutex);
            for (auto it = state->files.begin(); it != state->files.end();) {
                if (it->second.session == session) {
                    it = state->files.erase(it);
                    closed = true;
                } else {
                    ++it;
                }
            }
        }
        if (closed) state->publishOpenCount();
    });

    using Handler =
        void (*)(State&, const MethodCallContext&, std::vector<Variant>, const MethodCompletion&);
    // SecurityAdmin only (counted on SignAndEncrypt channels only, below); everyone sees the
    // node.
    auto restrict = [&](UInt32 method) {
        using namespace server::permission;
        constexpr UInt32 observe = Browse | ReadRolePermissions;
        std::vector<RolePermissionType> rules(3);
        rules[0].roleId = server::role::anonymous();
        rules[0].permissions = observe;
        rules[1].roleId = server::role::authenticatedUser();
        rules[1].permissions = observe;
        rules[2].roleId = server::role::securityAdmin();
        rules[2].permissions = observe | Call;
        as.setRolePermissions(ns0Node(method), std::move(rules));
    };
    auto attach = [&](UInt32 method, Handler h) {
        as.setMethodHandler(ns0Node(method),
                            [s, h](const MethodCallContext& ctx, std::vector<Variant> in,
                                   MethodCompletion done) { h(*s, ctx, std::move(in), done); });
        restrict(method);
    };
    attach(ns0::ServerConfiguration_UpdateCertificate,
           [](State& st, const MethodCallContext&, std::vector<Variant> in,
              const MethodCompletion& d) { updateCertificate(st, std::move(in), d); });
    attach(ns0::ServerConfiguration_ApplyChanges,
           [](State& st, const MethodCallContext&, std::vector<Variant>,
              const MethodCompletion& d) { applyChanges(st, d); });
    attach(ns0::ServerConfiguration_CancelChanges,
           [](State& st, const MethodCallContext&, std::vector<Variant>,
              const MethodCompletion& d) { cancelChanges(st, d); });
    attach(ns0::ServerConfiguration_CreateSigningRequest,
           [](State& st, const MethodCallContext&, std::vector<Variant> in,
              const MethodCompletion& d) { createSigningRequest(st, std::move(in), d); });
    attach(ns0::ServerConfiguration_GetRejectedList,
           [](State& st, const MethodCallContext&, std::vector<Variant>,
              const MethodCompletion& d) { getRejectedList(st, d); });
    attach(tl::Open, openTrustList);
    attach(tl::OpenWithMasks, openWithMasks);
    attach(tl::Read, readFile);
    attach(tl::Write, writeFile);
    attach(tl::GetPosition, getPosition);
    attach(tl::SetPosition, setPosition);
    attach(tl::Close, closeFile);
    attach(tl::CloseAndUpdate, closeAndUpdate);
    attach(tl::AddCertificate,
           [](State& st, const MethodCallContext&, std::vector<Variant> in,
              const MethodCompletion& d) { addCertificate(st, std::move(in), d); });
    attach(tl::RemoveCertificate,
           [](State& st, const MethodCallContext&, std::vector<Variant> in,
              const MethodCompletion& d) { removeCertificate(st, std::move(in), d); });
    // Not supported, but as closed as the others (no handler: Bad_NotImplemented).
    restrict(ns0::ServerConfiguration_ResetToServerDefaults);
    as.requireEncryptedChannel(server::role::securityAdmin());
}

}  // namespace pnp::ua::certificate_management
