#include "ua/client/client.hpp"

#include <poll.h>
#include <sys/eventfd.h>
#include <sys/random.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <climits>
#include <deque>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_map>

#include "ua/client/browse_path.hpp"
#include "ua/client/subscription_engine.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::client {

namespace {

using transport::IncomingResponse;
using transport::TransportError;

constexpr std::string_view kSecurityPolicyNone = "http://opcfoundation.org/UA/SecurityPolicy#None";
constexpr UInt32 kNodeRoot = 84;
constexpr std::size_t kNonceLength = 32;

// Where every callback of one client runs: in the order the responses were read, one at a
// time, on whichever thread first has some to run (the background thread, or a blocking call
// that read responses for others). Callbacks are queued where the response is routed (under
// the client's lock, so in the order the socket delivered them) and run after that lock is
// released: two notifications of one subscription never run concurrently or out of order.
class CompletionQueue {
  public:
    void push(std::function<void()> f) {
        std::lock_guard lock(mutex_);
        queue_.push_back(std::move(f));
    }
    // Runs what is queued unless another thread is already doing so (it then runs these
    // too, in order). Returns how many this thread ran.
    std::size_t drain() noexcept {
        std::unique_lock lock(mutex_);
        if (running_) return 0;
        running_ = true;
        std::size_t n = 0;
        while (!queue_.empty()) {
            std::function<void()> f = std::move(queue_.front());
            queue_.pop_front();
            lock.unlock();
            try {
                f();
            } catch (...) {
                // Callbacks must not throw; there is nobody to report it to.
            }
            ++n;
            lock.lock();
        }
        running_ = false;
        return n;
    }

  private:
    std::mutex mutex_;
    std::deque<std::function<void()>> queue_;
    bool running_ = false;
};

// Callbacks queued while the client's lock is held and run after it was released (the object
// is declared before the lock, so it is destroyed after the lock).
class Completions {
  public:
    explicit Completions(CompletionQueue& queue) : queue_(queue) {}
    Completions(const Completions&) = delete;
    Completions& operator=(const Completions&) = delete;
    ~Completions() { run(); }

    void add(std::function<void()> f) { queue_.push(std::move(f)); }
    std::size_t run() noexcept { return queue_.drain(); }

  private:
    CompletionQueue& queue_;
};

bool sessionGone(StatusCode s) {
    switch (s.code()) {
        case status::BadSessionIdInvalid.value:
        case status::BadSessionClosed.value:
        case status::BadSessionNotActivated.value:
            return true;
        default:
            return false;
    }
}

ByteString randomNonce() {
    std::array<Byte, kNonceLength> n{};
    std::size_t got = 0;
    while (got < kNonceLength) {
        ssize_t r = ::getrandom(n.data() + got, kNonceLength - got, 0);
        if (r <= 0) break;
        got += static_cast<std::size_t>(r);
    }
    return ByteString(n.data(), n.size());
}

UInt32 timeoutHint(Clock::time_point now, Clock::time_point deadline) {
    if (deadline == Clock::time_point::max() || deadline <= now) return 0;
    auto ms = std::chrono::ceil<milliseconds>(deadline - now).count();
    return ms > static_cast<decltype(ms)>(UINT32_MAX) ? 0 : static_cast<UInt32>(ms);
}

int pollTimeoutMs(Clock::time_point until) {
    if (until == Clock::time_point::max()) return -1;
    auto now = Clock::now();
    if (until <= now) return 0;
    auto ms = std::chrono::ceil<milliseconds>(until - now).count();
    return ms > INT_MAX ? INT_MAX : static_cast<int>(ms);
}

std::string describe(std::string_view service, const NodeId& node) {
    return std::string(service) + " of " + node.toString();
}

}  // namespace

// ---------------------------------------------------------------------------------------------
class Client::Impl {
  public:
    explicit Impl(ClientConfig c) : config(std::move(c)), backoff(config.reconnect.initialDelay) {}

    // keepDiscoveryConnection: the last temporary connection, with its URL and whether it
    // is secured. Guarded by discoveryMutex (not the session's lock).
    std::mutex discoveryMutex;
    std::unique_ptr<transport::ClientConnection> discoveryConnection;
    std::string discoveryUrl;
    bool discoverySecured = false;
    ~Impl() {
        if (wakeFd >= 0) ::close(wakeFd);
    }

    struct Session {
        NodeId sessionId;
        NodeId authenticationToken;
        Double revisedTimeout = 0;
        ByteString serverNonce;
        std::string anonymousPolicyId = "anonymous";
        std::string userNamePolicyId = "username";
        // The policy a password is encrypted with (empty: sent as it is, only on an
        // encrypted channel or when the server asks for it that way).
        std::string userNameSecurityPolicyUri;
        std::string certificatePolicyId = "x509";
        std::string certificateSecurityPolicyUri;
    };
    struct Pending {
        Clock::time_point deadline;
        RawCallback callback;
        std::string_view service;
    };

    ClientConfig config;
    // The secured channel chosen by connect() (null: None), and the endpoint it belongs to.
    std::shared_ptr<const transport::ClientSecurityConfig> channelSecurity;
    std::optional<EndpointDescription> endpoint;
    ByteString clientNonce;  // of the last CreateSession
    mutable std::mutex mutex;
    CompletionQueue completions;  // every callback runs through it (order, one at a time)
    std::unique_ptr<transport::ClientConnection> conn;  // null: no channel
    std::uint64_t generation = 0;                       // of conn, +1 per new channel
    std::string url;
    Identity identity;
    bool wantConnected = false;  // connect() succeeded, disconnect() not called
    std::optional<Session> session;
    bool sessionActive = false;
    bool sessionInvalid = false;  // the server said it forgot the session
    UInt32 requestHandle = 0;
    RequestHeader header{};
    // When the deadline of the request being sent was resolved (precise clock).
    Clock::time_point resolvedAt{};
    std::unordered_map<UInt32, Pending> pending;
    Clock::time_point nextAsyncDeadline = Clock::time_point::max();
    Clock::time_point lastReceive{};
    Clock::time_point lastSend{};
    std::vector<std::string> namespaces;
    ClientStats stats;
    std::shared_ptr<SubscriptionEngine> subscriptions;  // null until the first Subscription

    // reconnect back-off (background / runIterate)
    Clock::time_point nextReconnect{};
    milliseconds backoff;

    // background thread
    std::thread thread;
    bool stopRequested = false;
    int wakeFd = -1;
    std::atomic<std::thread::id> backgroundThreadId{};  // while backgroundLoop() runs
    // Blocking calls in progress (they read the socket themselves): the background thread
    // then leaves the socket's data alone and does not queue on the lock they hold.
    std::atomic<int> blockingCalls{0};
    // Threads waiting in lockForRequest(), and how often it was taken: a blocking call that lets
    // go of the lock for callbacks hands it to them (std::mutex is not fair; the callbacks'
    // own sends would otherwise rarely get in before the call takes it back).
    std::atomic<int> lockWaiters{0};
    std::atomic<std::uint64_t> lockTaken{0};
    std::unique_lock<std::mutex> lockForRequest() {
        lockWaiters.fetch_add(1);
        std::unique_lock l(mutex);
        lockWaiters.fetch_sub(1);
        lockTaken.fetch_add(1);
        return l;
    }
    // The blocking calls waiting for their responses (-> the response, once another blocking
    // call read it while this one ran callbacks without the lock). Keyed by awaitedKey():
    // request ids start again on every new channel.
    std::unordered_map<std::uint64_t, std::optional<IncomingResponse>> awaited;
    std::uint64_t awaitedKey(UInt32 requestId) const { return generation << 32 | requestId; }
    mutable std::atomic<bool> wakeWanted{false};  // a wake() left to the end of a blocking call
    std::atomic<bool> asyncPending{false};        // as last seen by the background thread

    // ---- helpers (all with the mutex held) ----------------------------------------------

    transport::ClientConfig transportConfig() const {
        transport::ClientConfig t = config.transport;
        t.requestedLifetime = config.secureChannelLifetime;
        t.security = channelSecurity;
        return t;
    }

    // The RequestHeader of the next request. It lives here (with the session's
    // authentication token) and is encoded in place of the request's own header.
    RequestHeader& makeHeader(Clock::time_point now, Clock::time_point deadline) {
        header.timestamp = DateTime::nowCoarse();
        header.requestHandle = ++requestHandle;
        header.timeoutHint = timeoutHint(now, deadline);
        return header;
    }
    void setSession(std::optional<Session> s) {
        session = std::move(s);
        header.authenticationToken = session ? session->authenticationToken : NodeId();
    }

    // Makes the background thread re-evaluate what it waits for. Not needed on that thread
    // itself: after running callbacks it goes round its loop again before it waits (this
    // saves three system calls per data change, whose callback sends the next Publish).
    // While a blocking call runs, the background thread waits for its end and for nothing
    // else: a wake-up is then left to the end of the last blocking call (one system call and
    // one thread woken, after the call's callbacks, instead of several before them).
    void wake() const {
        if (wakeFd < 0 ||
            backgroundThreadId.load(std::memory_order_relaxed) == std::this_thread::get_id())
            return;
        wakeWanted.store(true);
        if (blockingCalls.load() == 0 && wakeWanted.exchange(false)) signalWakeFd();
    }
    // The end of a blocking call: delivers a wake-up left to it, and has the background thread
    // watch the socket again if it has async requests pending.
    void blockingCallEnded() {
        if (blockingCalls.fetch_sub(1) == 1 && (wakeWanted.exchange(false) || asyncPending.load()))
            signalWakeFd();
    }
    void signalWakeFd() const {
        if (wakeFd < 0) return;
        std::uint64_t one = 1;
        [[maybe_unused]] auto r = ::write(wakeFd, &one, sizeof one);
    }

    void ensureWakeFd() {
        if (wakeFd < 0) wakeFd = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    }

    void notePossibleSessionLoss(const IncomingResponse& m) {
        if (!detail::isNs0Numeric(m.typeId, DataTypeInfo<ServiceFault>::binaryEncodingId)) return;
        try {
            auto fault = decodeFromBuffer<ServiceFault>(m.body.data(), m.body.size(), false,
                                                        config.decodeLimits);
            if (sessionGone(fault.responseHeader.serviceResult)) sessionInvalid = true;
        } catch (const DecodeError&) {
        }
    }

    // A response that is not the one this thread waits for: another blocking call's (kept
    // for it), or an async request's (its callback is queued). Returns whether a callback was
    // queued.
    bool route(IncomingResponse&& m, Completions& done) {
        if (auto w = awaited.find(awaitedKey(m.requestId)); w != awaited.end()) {
            m.body.own();  // read on by this thread before the other one takes it
            w->second = std::move(m);
            return false;
        }
        auto it = pending.find(m.requestId);
        if (it == pending.end()) {
            ++stats.discardedResponses;
            return false;
        }
        notePossibleSessionLoss(m);
        m.body.own();  // the callback runs later, after more reads
        done.add([cb = std::move(it->second.callback), r = std::move(m)]() mutable {
            cb(Result<IncomingResponse>(std::move(r)));
        });
        pending.erase(it);
        return true;
    }

    void expireAsync(Clock::time_point now, Completions& done) {
        if (now < nextAsyncDeadline) return;
        nextAsyncDeadline = Clock::time_point::max();
        for (auto it = pending.begin(); it != pending.end();) {
            if (it->second.deadline <= now) {
                ++stats.timeouts;
                done.add([cb = std::move(it->second.callback), s = it->second.service] {
                    cb(Error(status::BadTimeout, std::string(s) + " timed out"));
                });
                it = pending.erase(it);
            } else {
                nextAsyncDeadline = std::min(nextAsyncDeadline, it->second.deadline);
                ++it;
            }
        }
    }

    void failPending(StatusCode s, std::string_view why, Completions& done) {
        for (auto& [id, p] : pending) {
            done.add(
                [cb = std::move(p.callback), s,
                 msg = std::string(p.service) + ": " + std::string(why)] { cb(Error(s, msg)); });
        }
        pending.clear();
        nextAsyncDeadline = Clock::time_point::max();
    }

    void dropConnection() {
        if (!conn) return;
        try {
            conn->close();
        } catch (...) {
        }
        conn.reset();
        sessionActive = false;
    }

    void connectionLost(StatusCode s, Completions& done) {
        dropConnection();
        ++stats.connectionsLost;
        failPending(s, "connection lost", done);
        nextReconnect = Clock::now();
        backoff = config.reconnect.initialDelay;
    }

    // Waits for the response with requestId `id` (sent on the current connection), routing
    // others. With `lock` (the client's lock, held), callbacks of responses read meanwhile
    // (a subscription's notifications) run at once, without the lock, instead of after the
    // call: a long call does not hold them back, and what they send (the next Publish) goes
    // out. Another thread may then read this call's response; it keeps it in `awaited`.
    IncomingResponse await(UInt32 id, Clock::time_point deadline, std::string_view service,
                           Completions& done, std::unique_lock<std::mutex>* lock = nullptr) {
        const std::uint64_t sentOn = generation;
        const std::uint64_t key = awaitedKey(id);
        // Registered in `awaited` only once the lock is first let go (before, nobody else
        // reads): no map node per call that runs no callback.
        struct Forget {  // on every way out, with the lock held
            std::unordered_map<std::uint64_t, std::optional<IncomingResponse>>& awaited;
            std::uint64_t key;
            bool registered = false;
            ~Forget() {
                if (registered) awaited.erase(key);
            }
        } forget{awaited, key};
        for (;;) {
            if (forget.registered)
                if (auto& kept = awaited[key]) return std::move(*kept);
            if (!conn || generation != sentOn)
                throw TransportError(status::BadConnectionClosed,
                                     "the connection was lost while waiting");
            std::optional<IncomingResponse> m =
                conn->receive(std::min(deadline, nextAsyncDeadline));
            Clock::time_point now = m ? transport::coarseNow() : Clock::now();
            if (!m) {
                if (now >= deadline) {
                    ++stats.timeouts;
                    throw Error(status::BadTimeout, std::string(service) + " timed out");
                }
                expireAsync(now, done);
                continue;
            }
            lastReceive = now;
            if (m->requestId == id) return std::move(*m);
            if (route(std::move(*m), done) && lock != nullptr) {
                if (!forget.registered) awaited.emplace(key, std::nullopt);
                forget.registered = true;
                const std::uint64_t taken = lockTaken.load();
                lock->unlock();
                done.run();
                // Another thread (one running callbacks whose next Publish waits for the
                // lock, say) gets it first; bounded, in case it is not scheduled soon.
                const auto until = Clock::now() + std::chrono::milliseconds(5);
                while (lockWaiters.load() > 0 && lockTaken.load() == taken && Clock::now() < until)
                    std::this_thread::yield();
                lock->lock();
            }
        }
    }

    // One request on the current connection, no reconnect. TransportError passes through.
    IncomingResponse exchange(Client::EncodeRef encode, Clock::time_point deadline,
                              std::string_view service, Completions& done, bool& sent,
                              std::unique_lock<std::mutex>* lock = nullptr) {
        UInt32 id = sendRequest(encode, deadline);
        sent = true;
        return await(id, deadline, service, done, lock);
    }

    // Encodes and sends one request on the current connection; returns its request id.
    UInt32 sendRequest(Client::EncodeRef encode, Clock::time_point deadline) {
        // The precise time the deadline was resolved at, unless the coarse clock is later.
        Clock::time_point now = std::max(resolvedAt, transport::coarseNow());
        Buffer buffer = conn->messageBuffer();
        Splices splices;  // large byte runs stay in the request (sent before send() returns)
        encode(buffer, makeHeader(now, deadline), &splices);
        UInt32 id = conn->send(std::move(buffer), std::move(splices), deadline);
        ++stats.requestsSent;
        lastSend = now;
        return id;
    }

    // A session-management request: a transport failure drops the connection.
    template <class Req>
    ResponseOf<Req> sessionCall(Req& req, Clock::time_point deadline, Completions& done) {
        constexpr std::string_view service = detail::serviceName<Req>();
        if (!conn) throw Error(status::BadNotConnected, std::string(service) + ": not connected");
        bool sent = false;
        try {
            IncomingResponse r = exchange(encoderFor(req), deadline, service, done, sent);
            return decodeIncoming<ResponseOf<Req>>(r, service, config.decodeLimits);
        } catch (const TransportError& e) {
            connectionLost(e.status(), done);
            throw Error(e.status(), std::string(service) + ": " + e.message());
        }
    }

    void openChannel(Clock::time_point deadline) {
        try {
            conn = transport::ClientConnection::connect(url, transportConfig(), deadline);
            ++generation;
        } catch (const TransportError& e) {
            throw Error(e.status(), "cannot connect to " + url + ": " + e.message());
        }
        lastReceive = Clock::now();
    }

    void createSession(Clock::time_point deadline, Completions& done) {
        CreateSessionRequest req{};
        req.clientDescription.applicationUri = config.applicationUri;
        req.clientDescription.productUri = config.productUri;
        req.clientDescription.applicationName = LocalizedText("", config.applicationName);
        req.clientDescription.applicationType = ApplicationType::Client;
        req.endpointUrl = url;
        req.sessionName =
            config.sessionName.empty() ? config.applicationName + " session" : config.sessionName;
        req.clientNonce = randomNonce();
        clientNonce = req.clientNonce;
        req.requestedSessionTimeout = static_cast<Double>(config.requestedSessionTimeout.count());
        req.maxResponseMessageSize = config.transport.maxMessageSize;
        if (channelSecurity) {
            const auto& der = channelSecurity->identity.certificate.der();
            req.clientCertificate = ByteString(der.data(), der.size());
        }
        setSession(std::nullopt);
        sessionActive = false;
        CreateSessionResponse resp = sessionCall(req, deadline, done);
        if (channelSecurity) checkServerSignature(req, resp);

        Session s;
        s.sessionId = std::move(resp.sessionId);
        s.authenticationToken = std::move(resp.authenticationToken);
        s.revisedTimeout = resp.revisedSessionTimeout;
        s.serverNonce = std::move(resp.serverNonce);
        choosePolicies(
            endpoint ? std::vector<EndpointDescription>{*endpoint} : resp.serverEndpoints, s);
        setSession(std::move(s));
        sessionInvalid = false;
        namespaces.clear();  // possibly another server (instance)
        ++stats.sessionsCreated;
    }

    // The server proves it holds its certificate's key: serverSignature over our certificate
    // and nonce (Part 4 §5.6.2), with the certificate we opened the channel to.
    void checkServerSignature(const CreateSessionRequest& req, const CreateSessionResponse& resp) {
        const auto& server = channelSecurity->serverCertificate;
        const auto& der = server.der();
        const auto& policy = *channelSecurity->policy;
        crypto::Bytes data(req.clientCertificate.data(),
                           req.clientCertificate.data() + req.clientCertificate.size());
        data.insert(data.end(), req.clientNonce.data(),
                    req.clientNonce.data() + req.clientNonce.size());
        const bool sameCertificate =
            resp.serverCertificate.size() >= der.size() &&
            std::equal(der.begin(), der.end(), resp.serverCertificate.data());
        const bool signed_ =
            resp.serverSignature.algorithm == policy.asymmetricSignatureUri &&
            crypto::verify(server.publicKey(), policy.asymmetricSignature, data,
                           crypto::ByteView(resp.serverSignature.signature.data(),
                                            resp.serverSignature.signature.size()));
        if (!sameCertificate || !signed_)
            throw Error(status::BadApplicationSignatureInvalid,
                        "CreateSession: the server's signature does not prove its certificate");
    }

    static void choosePolicies(const std::vector<EndpointDescription>& endpoints, Session& s) {
        bool anonymous = false, user = false, certificate = false;
        for (const auto& ep : endpoints) {
            const bool secured =
                !ep.securityPolicyUri.empty() && ep.securityPolicyUri != kSecurityPolicyNone;
            for (const auto& t : ep.userIdentityTokens) {
                const bool ownPolicy =
                    !t.securityPolicyUri.empty() && t.securityPolicyUri != kSecurityPolicyNone;
                // Empty on a secured endpoint: the channel's policy protects the token.
                const std::string policy =
                    ownPolicy ? t.securityPolicyUri : (secured ? ep.securityPolicyUri : "");
                if (ownPolicy && !crypto::findPolicy(t.securityPolicyUri)) continue;
                if (!anonymous && t.tokenType == UserTokenType::Anonymous) {
                    s.anonymousPolicyId = t.policyId;
                    anonymous = true;
                } else if (!user && t.tokenType == UserTokenType::UserName) {
                    s.userNamePolicyId = t.policyId;
                    s.userNameSecurityPolicyUri = policy;
                    user = true;
                } else if (!certificate && t.tokenType == UserTokenType::Certificate) {
                    s.certificatePolicyId = t.policyId;
                    s.certificateSecurityPolicyUri = policy;
                    certificate = true;
                }
            }
        }
    }

    // The server's certificate, for encrypting a password / signing a user token: the one of
    // the secured channel, else the chosen endpoint's.
    std::optional<pki::Certificate> serverCertificate() const {
        if (channelSecurity) return channelSecurity->serverCertificate;
        if (endpoint && endpoint->serverCertificate.size() > 0) {
            try {
                return pki::Certificate::chainFromDer(
                           crypto::ByteView(endpoint->serverCertificate.data(),
                                            endpoint->serverCertificate.size()))
                    .front();
            } catch (const std::exception&) {
            }
        }
        return std::nullopt;
    }

    ExtensionObject identityToken() const {
        if (const auto* u = std::get_if<UserName>(&identity)) {
            UserNameIdentityToken t{};
            t.policyId = session->userNamePolicyId;
            t.userName = u->user;
            const crypto::SecurityPolicy* policy =
                crypto::findPolicy(session->userNameSecurityPolicyUri);
            const auto server = policy ? serverCertificate() : std::nullopt;
            if (policy && server) {
                // The legacy format every peer understands (Part 4 §7.41.2.2): length of
                // password + nonce, the password, the server's last nonce; encrypted for the
                // server's certificate.
                const auto& nonce = session->serverNonce;
                crypto::Bytes plain(4);
                const auto length = static_cast<UInt32>(u->password.size() + nonce.size());
                for (int i = 0; i < 4; ++i)
                    plain[static_cast<std::size_t>(i)] = static_cast<Byte>(length >> (8 * i));
                plain.insert(plain.end(), u->password.begin(), u->password.end());
                plain.insert(plain.end(), nonce.data(), nonce.data() + nonce.size());
                const auto cipher =
                    crypto::encrypt(server->publicKey(), policy->asymmetricEncryption, plain);
                t.password = ByteString(cipher.data(), cipher.size());
                t.encryptionAlgorithm = std::string(policy->asymmetricEncryptionUri);
            } else {
                t.password = ByteString(u->password);
            }
            return toExtensionObject(t);
        }
        if (const auto* c = std::get_if<UserCertificate>(&identity)) {
            X509IdentityToken t{};
            t.policyId = session->certificatePolicyId;
            const auto& der = c->identity.certificate.der();
            t.certificateData = ByteString(der.data(), der.size());
            return toExtensionObject(t);
        }
        AnonymousIdentityToken t{};
        t.policyId = session->anonymousPolicyId;
        return toExtensionObject(t);
    }

    // sign(server certificate + server nonce) with `key`, by `policy`: the proof of a client
    // (clientSignature) or of an X.509 user (userTokenSignature).
    SignatureData signServerNonce(const crypto::SecurityPolicy& policy,
                                  const crypto::PrivateKey& key) const {
        SignatureData sig;
        const auto server = serverCertificate();
        if (!server) return sig;
        crypto::Bytes data = server->der();
        const auto& nonce = session->serverNonce;
        data.insert(data.end(), nonce.data(), nonce.data() + nonce.size());
        const auto signature = crypto::sign(key, policy.asymmetricSignature, data);
        sig.algorithm = std::string(policy.asymmetricSignatureUri);
        sig.signature = ByteString(signature.data(), signature.size());
        return sig;
    }

    void activateSession(Clock::time_point deadline, Completions& done) {
        ActivateSessionRequest req{};
        req.localeIds = config.localeIds;
        req.userIdentityToken = identityToken();
        if (channelSecurity)
            req.clientSignature =
                signServerNonce(*channelSecurity->policy, channelSecurity->identity.key);
        if (const auto* c = std::get_if<UserCertificate>(&identity)) {
            const crypto::SecurityPolicy* policy =
                crypto::findPolicy(session->certificateSecurityPolicyUri);
            if (policy) req.userTokenSignature = signServerNonce(*policy, c->identity.key);
        }
        ActivateSessionResponse resp = sessionCall(req, deadline, done);
        session->serverNonce = std::move(resp.serverNonce);
        sessionActive = true;
        sessionInvalid = false;
    }

    // New channel + the existing session re-activated, or a new session.
    void reconnect(Clock::time_point deadline, Completions& done) {
        deadline = std::min(deadline, Clock::now() + config.connectTimeout);
        dropConnection();
        openChannel(deadline);
        try {
            if (session) {
                try {
                    activateSession(deadline, done);
                    ++stats.sessionsReactivated;
                    ++stats.reconnects;
                    notifySessionChange(SessionChange::Reactivated, done);
                    return;
                } catch (const Error& e) {
                    if (!conn || !sessionGone(e.status())) throw;
                }
            }
            createSession(deadline, done);
            activateSession(deadline, done);
            ++stats.reconnects;
            notifySessionChange(SessionChange::Recreated, done);
        } catch (...) {
            dropConnection();
            throw;
        }
    }

    // The server forgot the session while the channel stayed up.
    void renewSession(Clock::time_point deadline, Completions& done) {
        deadline = std::min(deadline, Clock::now() + config.connectTimeout);
        createSession(deadline, done);
        activateSession(deadline, done);
        notifySessionChange(SessionChange::Recreated, done);
    }

    // Subscriptions follow the session after the lock is released (they call the client).
    void notifySessionChange(SessionChange change, Completions& done) {
        if (subscriptions) done.add([e = subscriptions, change] { e->sessionChanged(change); });
    }

    // A connection that was idle for a while may have been closed by the server: look at the
    // socket before using it.
    void checkIdleConnection(Clock::time_point now, Completions& done) {
        if (config.idleCheckAfter.count() <= 0 || now - lastReceive < config.idleCheckAfter) return;
        pollfd p{conn->nativeHandle(), POLLIN | POLLRDHUP, 0};
        if (::poll(&p, 1, 0) <= 0 || p.revents == 0) return;
        try {
            while (auto m = conn->receive(now)) route(std::move(*m), done);
        } catch (const TransportError& e) {
            connectionLost(e.status(), done);
            return;
        }
        if (p.revents & (POLLERR | POLLHUP | POLLRDHUP | POLLNVAL))
            connectionLost(status::BadConnectionClosed, done);
    }

    // Makes sure there is a channel and an active session, reconnecting if allowed.
    void ensureReady(Clock::time_point deadline, std::string_view service, Completions& done) {
        if (!wantConnected)
            throw Error(status::BadNotConnected, std::string(service) + ": not connected");
        if (conn) checkIdleConnection(transport::coarseNow(), done);
        if (!conn) {
            if (!config.reconnect.enabled)
                throw Error(status::BadNotConnected,
                            std::string(service) + ": connection lost (reconnect disabled)");
            reconnect(deadline, done);
        } else if (sessionInvalid || !sessionActive) {
            renewSession(deadline, done);
        }
    }

    static bool isSessionFault(const IncomingResponse& r, const DecodeLimits& limits) {
        if (!detail::isNs0Numeric(r.typeId, DataTypeInfo<ServiceFault>::binaryEncodingId))
            return false;
        try {
            auto f = decodeFromBuffer<ServiceFault>(r.body.data(), r.body.size(), false, limits);
            return sessionGone(f.responseHeader.serviceResult);
        } catch (const DecodeError&) {
            return false;
        }
    }

    // A request whose deadline passed before it was sent is not sent at all.
    void checkDeadline(Clock::time_point deadline, std::string_view service) {
        if (transport::deadlinePassed(deadline)) {
            ++stats.timeouts;
            throw Error(status::BadTimeout,
                        std::string(service) + ": deadline passed before sending");
        }
    }

    // `lock`: see await().
    IncomingResponse roundTrip(Client::EncodeRef encode, bool idempotent,
                               Clock::time_point deadline, std::string_view service,
                               Completions& done, std::unique_lock<std::mutex>* lock = nullptr) {
        for (int attempt = 0;; ++attempt) {
            checkDeadline(deadline, service);
            ensureReady(deadline, service, done);
            bool sent = false;
            const std::uint64_t sentOn = generation;
            try {
                IncomingResponse r = exchange(encode, deadline, service, done, sent, lock);
                if (attempt == 0 && config.reconnect.enabled &&
                    isSessionFault(r, config.decodeLimits)) {
                    // The server rejected the request without executing it: a new session
                    // and one more try, whatever the service.
                    sessionInvalid = true;
                    ++stats.retries;
                    continue;
                }
                if (!pending.empty()) wake();  // responses may be buffered in the transport
                return r;
            } catch (const TransportError& e) {
                if (e.status() == status::BadRequestTooLarge && conn && conn->isOpen())
                    throw Error(e.status(), std::string(service) + ": " + e.message());
                // Lost while this call ran callbacks: another thread saw it and may have
                // connected again already.
                if (conn && generation == sentOn) connectionLost(e.status(), done);
                bool retry = attempt == 0 && config.reconnect.enabled &&
                             (!sent || (idempotent && config.reconnect.retryIdempotent));
                if (!retry) throw Error(e.status(), std::string(service) + ": " + e.message());
                ++stats.retries;
            }
        }
    }

    void sendAsync(Client::EncodeRef encode, Clock::time_point deadline, std::string_view service,
                   RawCallback& callback, Completions& done) {
        for (int attempt = 0;; ++attempt) {
            checkDeadline(deadline, service);
            ensureReady(deadline, service, done);
            try {
                UInt32 id = sendRequest(encode, deadline);
                pending.insert_or_assign(id, Pending{deadline, std::move(callback), service});
                nextAsyncDeadline = std::min(nextAsyncDeadline, deadline);
                wake();
                return;
            } catch (const TransportError& e) {
                if (e.status() == status::BadRequestTooLarge && conn && conn->isOpen())
                    throw Error(e.status(), std::string(service) + ": " + e.message());
                connectionLost(e.status(), done);
                // Not sent: safe to send again on a new connection.
                if (attempt > 0 || !config.reconnect.enabled)
                    throw Error(e.status(), std::string(service) + ": " + e.message());
                ++stats.retries;
            }
        }
    }

    Clock::duration keepAliveInterval() const {
        if (config.keepAliveInterval.count() > 0) return config.keepAliveInterval;
        if (!session || session->revisedTimeout <= 0) return Clock::duration::max();
        return std::chrono::duration_cast<Clock::duration>(
            std::chrono::duration<double, std::milli>(session->revisedTimeout / 3));
    }

    void sendKeepAlive(Clock::time_point now, Completions& done) {
        ReadRequest req{};
        req.maxAge = 0;
        req.timestampsToReturn = TimestampsToReturn::Neither;
        ReadValueId id{};
        id.nodeId = NodeId(0, ns0::Server_ServerStatus_CurrentTime);
        id.attributeId = static_cast<UInt32>(AttributeId::Value);
        req.nodesToRead.push_back(std::move(id));
        RawCallback cb = [](Result<IncomingResponse>) {};
        ++stats.keepAlives;
        try {
            sendAsync(encoderFor(req), now + config.requestTimeout, "KeepAlive", cb, done);
        } catch (const Error&) {
        }
    }

    // One pass of the event loop: returns when the loop should run again at the latest.
    // `readable`: poll() reported data on the socket (read it once, without waiting).
    Clock::time_point housekeeping(Completions& done, bool readable) {
        Clock::time_point now = Clock::now();
        expireAsync(now, done);
        if (wantConnected && config.reconnect.enabled && (!conn || sessionInvalid) &&
            now >= nextReconnect) {
            try {
                if (!conn)
                    reconnect(now + config.connectTimeout, done);
                else
                    renewSession(now + config.connectTimeout, done);
                backoff = config.reconnect.initialDelay;
            } catch (const Error&) {
                nextReconnect = Clock::now() + backoff;
                backoff = std::min<milliseconds>(backoff * 2, config.reconnect.maxDelay);
            }
            now = Clock::now();
        }
        if (conn) {
            try {
                bool read = readable;
                while (auto m = conn->receiveReady(std::exchange(read, false))) {
                    lastReceive = now;
                    route(std::move(*m), done);
                }
                conn->renewIfDue();
            } catch (const TransportError& e) {
                connectionLost(e.status(), done);
            }
        }
        Clock::time_point next = now + std::chrono::seconds(1);
        if (conn) next = std::min(next, std::max(now, conn->renewalDue()));
        if (conn && sessionActive) {
            Clock::duration ka = keepAliveInterval();
            if (ka != Clock::duration::max()) {
                if (now - lastSend >= ka) {
                    sendKeepAlive(now, done);
                    next = std::min(next, now + ka);
                } else {
                    next = std::min(next, lastSend + ka);
                }
            }
        }
        if (wantConnected && (!conn || sessionInvalid) && config.reconnect.enabled)
            next = std::min(next, std::max(now, nextReconnect));
        return std::min(next, nextAsyncDeadline);
    }

    // Waits (without the lock) until the socket has `events` or the wake-up eventfd is
    // readable, or until `until`. Returns the socket's revents.
    short waitForEvents(int fd, short events, Clock::time_point until) {
        pollfd fds[2] = {{wakeFd, POLLIN, 0}, {fd, events, 0}};
        if (::poll(fds, fd >= 0 ? 2 : 1, pollTimeoutMs(until)) <= 0) return 0;
        if (fds[0].revents & POLLIN) {
            std::uint64_t v;
            [[maybe_unused]] auto r = ::read(wakeFd, &v, sizeof v);
        }
        return fd >= 0 ? fds[1].revents : 0;
    }

    // The peer hung up connection `gen` (seen by poll): make sure it is treated as lost even
    // if nothing can be read from it.
    void peerHungUp(std::uint64_t gen, Completions& done) {
        if (!conn || gen != generation) return;
        try {
            while (auto m = conn->receive(Clock::now())) route(std::move(*m), done);
        } catch (const TransportError& e) {
            connectionLost(e.status(), done);
            return;
        }
        connectionLost(status::BadConnectionClosed, done);
    }

    // The background thread. It watches the socket for a hang-up always, and for incoming
    // data only while async requests are pending (so that blocking calls, which read their
    // responses themselves, do not wake it).
    void backgroundLoop() {
        backgroundThreadId = std::this_thread::get_id();
        struct Leave {
            std::atomic<std::thread::id>& id;
            ~Leave() { id = std::thread::id(); }
        } leave{backgroundThreadId};
        short revents = 0;  // of the socket, from the last poll()
        std::uint64_t watched = 0;
        for (;;) {
            // A blocking call reads the socket (and dispatches what it finds): wait for it to
            // end (it wakes us) without touching the socket's data or its lock.
            if (blockingCalls.load() > 0) {
                revents = waitForEvents(-1, 0, Clock::now() + std::chrono::milliseconds(50));
                continue;
            }
            Completions done(completions);
            Clock::time_point until;
            int fd = -1;
            short events = 0;
            {
                std::lock_guard lock(mutex);
                if (stopRequested) return;
                if (revents & (POLLRDHUP | POLLHUP | POLLERR)) peerHungUp(watched, done);
                until = housekeeping(done, (revents & POLLIN) && watched == generation);
                if (conn) {
                    fd = conn->nativeHandle();
                    events = pending.empty() ? POLLRDHUP : (POLLIN | POLLRDHUP);
                    asyncPending = !pending.empty();
                    watched = generation;
                }
            }
            // The callbacks may have sent requests (wake() does not signal this thread): the
            // socket events and the deadline computed above may be stale, so look again
            // before waiting (a Republish sent by a callback was otherwise left unread for up
            // to a second).
            if (done.run() > 0) {
                revents = 0;
                continue;
            }
            revents = waitForEvents(fd, events, until);
        }
    }

    void close(Completions& done) {
        wantConnected = false;
        if (conn && session && sessionActive) {
            try {
                CloseSessionRequest req{};
                req.deleteSubscriptions = true;
                sessionCall(req, Clock::now() + config.closeTimeout, done);
            } catch (...) {
            }
        }
        dropConnection();
        setSession(std::nullopt);
        sessionActive = false;
        sessionInvalid = false;
        namespaces.clear();
        failPending(status::BadShutdown, "client disconnected", done);
    }
};

// ---------------------------------------------------------------------------------------------

namespace {
std::mutex defaultSecurityMutex;
std::optional<DefaultSecurity> processDefaultSecurity;

ClientConfig withDefaultSecurity(ClientConfig config) {
    if (config.security || !config.useDefaultSecurity) return config;
    std::lock_guard lock(defaultSecurityMutex);
    if (!processDefaultSecurity) return config;
    config.security = processDefaultSecurity->security;
    config.applicationUri = processDefaultSecurity->applicationUri;
    config.applicationName = processDefaultSecurity->applicationName;
    return config;
}
}  // namespace

void setDefaultSecurity(std::optional<DefaultSecurity> security) {
    std::lock_guard lock(defaultSecurityMutex);
    processDefaultSecurity = std::move(security);
}

std::optional<DefaultSecurity> defaultSecurity() {
    std::lock_guard lock(defaultSecurityMutex);
    return processDefaultSecurity;
}

Client::Client(ClientConfig config)
    : impl_(std::make_unique<Impl>(withDefaultSecurity(std::move(config)))) {}

Client::~Client() {
    if (!impl_) return;
    stopBackgroundThread();
    if (impl_->subscriptions) impl_->subscriptions->rebind(nullptr);
    disconnect();
}

Client::Client(Client&& o) noexcept : impl_(std::move(o.impl_)) {
    if (impl_ && impl_->subscriptions) impl_->subscriptions->rebind(this);
}

Client& Client::operator=(Client&& o) noexcept {
    if (this != &o) {
        if (impl_) {
            stopBackgroundThread();
            if (impl_->subscriptions) impl_->subscriptions->rebind(nullptr);
            disconnect();
        }
        impl_ = std::move(o.impl_);
        if (impl_ && impl_->subscriptions) impl_->subscriptions->rebind(this);
    }
    return *this;
}

std::shared_ptr<SubscriptionEngine> Client::subscriptionEngine() {
    std::lock_guard lock(impl_->mutex);
    if (!impl_->subscriptions) impl_->subscriptions = std::make_shared<SubscriptionEngine>(this);
    return impl_->subscriptions;
}

const ClientConfig& Client::config() const { return impl_->config; }
const DecodeLimits& Client::decodeLimits() const { return impl_->config.decodeLimits; }

namespace {
// The most secure endpoint the client supports, accepts and trusts (Part 4 §5.4.4: the
// client chooses), with the channel configuration for it. Throws Error.
std::pair<EndpointDescription, std::shared_ptr<const transport::ClientSecurityConfig>>
chooseEndpoint(const ClientSecurity& sec, const std::vector<EndpointDescription>& endpoints,
               std::string_view url) {
    std::vector<const EndpointDescription*> candidates;
    for (const auto& ep : endpoints) {
        if (!ep.transportProfileUri.empty() &&
            ep.transportProfileUri !=
                "http://opcfoundation.org/UA-Profile/Transport/uatcp-uasc-uabinary")
            continue;
        const bool none = ep.securityMode == MessageSecurityMode::None;
        if (none) {
            if (sec.allowNone) candidates.push_back(&ep);
            continue;
        }
        if (!crypto::findPolicy(ep.securityPolicyUri)) continue;  // unknown or deprecated
        if (!sec.policyUri.empty() && ep.securityPolicyUri != sec.policyUri) continue;
        if (static_cast<int>(ep.securityMode) < static_cast<int>(sec.minimumMode)) continue;
        candidates.push_back(&ep);
    }
    std::stable_sort(candidates.begin(), candidates.end(), [](const auto* a, const auto* b) {
        if ((a->securityMode == MessageSecurityMode::None) !=
            (b->securityMode == MessageSecurityMode::None))
            return b->securityMode == MessageSecurityMode::None;
        if (a->securityMode != b->securityMode) return a->securityMode > b->securityMode;
        return a->securityLevel > b->securityLevel;
    });
    if (candidates.empty())
        throw Error(status::BadSecurityPolicyRejected,
                    "no endpoint of " + std::string(url) +
                        " offers a security policy and mode this client accepts");
    const EndpointDescription& ep = *candidates.front();
    if (ep.securityMode == MessageSecurityMode::None) return {ep, nullptr};
    std::vector<pki::Certificate> chain;
    try {
        chain = pki::Certificate::chainFromDer(
            crypto::ByteView(ep.serverCertificate.data(), ep.serverCertificate.size()));
    } catch (const std::exception& e) {
        throw Error(status::BadCertificateInvalid,
                    "the server certificate of " + std::string(url) + ": " + e.what());
    }
    if (chain.empty())
        throw Error(status::BadCertificateInvalid,
                    std::string(url) + " offers a secured endpoint without a certificate");
    if (sec.trust) {
        pki::ValidationOptions options;
        options.applicationUri = ep.server.applicationUri;
        const StatusCode st = sec.trust->validate(chain, options);
        if (st.isBad())
            throw Error(st, "the server certificate of " + std::string(url) + " (" +
                                chain.front().subject() + ", thumbprint " +
                                chain.front().thumbprintHex().substr(0, 16) +
                                ") is not accepted; an operator trusts it with `pnp pki trust " +
                                chain.front().thumbprintHex().substr(0, 16) + "`");
    }
    auto channel = std::make_shared<transport::ClientSecurityConfig>();
    channel->policy = crypto::findPolicy(ep.securityPolicyUri);
    channel->mode = ep.securityMode;
    channel->identity = sec.identity;
    channel->serverCertificate = chain.front();
    return {ep, std::move(channel)};
}
}  // namespace

void Client::connect(std::string_view endpointUrl, Identity identity, Deadline deadline) {
    Impl& s = *impl_;
    const Clock::time_point dl = deadline.resolve(Clock::now(), s.config.connectTimeout);
    std::optional<EndpointDescription> endpoint;
    std::shared_ptr<const transport::ClientSecurityConfig> channelSecurity;
    if (s.config.security) {
        // Which endpoints the server offers: asked on a channel without security, then
        // checked against what we accept and trust.
        auto [ep, channel] = chooseEndpoint(*s.config.security,
                                            getEndpoints(endpointUrl, Deadline(dl)), endpointUrl);
        endpoint = std::move(ep);
        channelSecurity = std::move(channel);
    }
    Completions done(s.completions);
    std::lock_guard lock(s.mutex);
    if (s.wantConnected || s.conn) s.close(done);
    s.url = std::string(endpointUrl);
    s.identity = std::move(identity);
    s.endpoint = std::move(endpoint);
    s.channelSecurity = std::move(channelSecurity);
    try {
        s.openChannel(dl);
        s.createSession(dl, done);
        s.activateSession(dl, done);
    } catch (...) {
        s.dropConnection();
        s.setSession(std::nullopt);
        throw;
    }
    s.wantConnected = true;
    s.backoff = s.config.reconnect.initialDelay;
}

void Client::disconnect() noexcept {
    if (!impl_) return;
    Completions done(impl_->completions);
    std::lock_guard lock(impl_->mutex);
    impl_->close(done);
}

bool Client::isConnected() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->wantConnected;
}

bool Client::isChannelOpen() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->conn && impl_->conn->isOpen();
}

std::string Client::endpointUrl() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->url;
}

NodeId Client::sessionId() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->session ? impl_->session->sessionId : NodeId();
}

Double Client::sessionTimeout() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->session ? impl_->session->revisedTimeout : 0;
}

int Client::nativeHandle() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->conn ? impl_->conn->nativeHandle() : -1;
}

ClientStats Client::stats() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->stats;
}

// ---- engine ------------------------------------------------------------------------------

void Client::roundTrip(EncodeRef encode, DecodeRef decode, bool idempotent, Deadline deadline,
                       std::string_view service) {
    Impl& s = *impl_;
    // Declared first, so it ends after the lock is released: the background thread, which
    // kept off the socket meanwhile, watches it again for pending async responses.
    struct Blocking {
        Impl& s;
        explicit Blocking(Impl& i) : s(i) { s.blockingCalls.fetch_add(1); }
        ~Blocking() { s.blockingCallEnded(); }
    } blocking(s);
    Completions done(s.completions);  // run after the lock is released (and while waiting)
    std::unique_lock lock = s.lockForRequest();
    s.resolvedAt = Clock::now();
    Clock::time_point dl = deadline.resolve(s.resolvedAt, s.config.requestTimeout);
    decode(s.roundTrip(encode, idempotent, dl, service, done, &lock), s.config.decodeLimits);
}

void Client::sendAsync(EncodeRef encode, Deadline deadline, std::string_view service,
                       RawCallback callback) {
    Impl& s = *impl_;
    Completions done(s.completions);
    std::unique_lock lock = s.lockForRequest();
    s.resolvedAt = Clock::now();
    Clock::time_point dl = deadline.resolve(s.resolvedAt, s.config.requestTimeout);
    try {
        s.sendAsync(encode, dl, service, callback, done);
    } catch (const Error& e) {
        done.add([cb = std::move(callback), e] { cb(e); });
    }
}

IncomingResponse Client::discoveryRoundTrip(std::string_view url, EncodeRef encode,
                                            Deadline deadline, std::string_view service,
                                            bool secured) {
    Impl& s = *impl_;
    Clock::time_point dl;
    {
        Completions done(s.completions);
        std::lock_guard lock(s.mutex);
        dl = deadline.resolve(Clock::now(), s.config.requestTimeout);
        if (url.empty() || (s.wantConnected && url == s.url)) {
            if (!s.wantConnected)
                throw Error(status::BadNotConnected,
                            std::string(service) + ": not connected and no URL given");
            IncomingResponse r = s.roundTrip(encode, true, dl, service, done);
            r.body.own();  // outlives the lock
            return r;
        }
    }
    // A temporary connection, without a session and without the client's lock — or the one
    // kept from the last request to this URL (keepDiscoveryConnection).
    const bool secure = secured && s.config.security;
    auto exchange = [&](transport::ClientConnection& c) {
        const Clock::time_point now = Clock::now();
        Buffer buffer = transport::ClientConnection::newMessageBuffer();
        RequestHeader h{};
        h.timestamp = DateTime::now();
        h.requestHandle = 1;
        h.timeoutHint = timeoutHint(now, dl);
        encode(buffer, h);
        const UInt32 id = c.send(std::move(buffer), dl);
        for (;;) {
            auto m = c.receive(dl);
            if (!m) throw Error(status::BadTimeout, std::string(service) + " timed out");
            if (m->requestId == id) {
                m->body.own();  // outlives the connection
                return std::move(*m);
            }
        }
    };
    auto keep = [&](std::unique_ptr<transport::ClientConnection> c) {
        std::lock_guard lock(s.discoveryMutex);
        s.discoveryConnection = std::move(c);  // the one before is closed
        s.discoveryUrl = std::string(url);
        s.discoverySecured = secure;
    };
    if (s.config.keepDiscoveryConnection) {
        std::unique_ptr<transport::ClientConnection> kept;
        {
            std::lock_guard lock(s.discoveryMutex);
            if (s.discoveryConnection && s.discoveryUrl == url && s.discoverySecured == secure &&
                s.discoveryConnection->isOpen())
                kept = std::move(s.discoveryConnection);
        }
        if (kept) {
            try {
                IncomingResponse r = exchange(*kept);
                keep(std::move(kept));
                return r;
            } catch (const TransportError&) {
                // Closed meanwhile (idle, the server restarted): a new one below.
            }
        }
    }
    transport::ClientConfig transport = s.config.transport;
    if (secure) {
        auto [ep, channel] =
            chooseEndpoint(*s.config.security, getEndpoints(url, Deadline(dl)), url);
        transport.security = std::move(channel);
    }
    try {
        auto c = transport::ClientConnection::connect(std::string(url), transport, dl);
        IncomingResponse r = exchange(*c);
        if (s.config.keepDiscoveryConnection)
            keep(std::move(c));
        else
            c->close();
        return r;
    } catch (const TransportError& e) {
        throw Error(e.status(),
                    std::string(service) + " at " + std::string(url) + ": " + e.message());
    }
}

// ---- discovery -----------------------------------------------------------------------------

std::vector<EndpointDescription> Client::getEndpoints(std::string_view url, Deadline deadline) {
    GetEndpointsRequest req{};
    {
        std::lock_guard lock(impl_->mutex);
        req.endpointUrl = url.empty() ? impl_->url : std::string(url);
    }
    auto r = discoveryRoundTrip(url, encoderFor(req), deadline, "GetEndpoints");
    return decodeIncoming<GetEndpointsResponse>(r, "GetEndpoints", decodeLimits()).endpoints;
}

std::vector<ApplicationDescription> Client::findServers(std::string_view url, Deadline deadline) {
    FindServersRequest req{};
    {
        std::lock_guard lock(impl_->mutex);
        req.endpointUrl = url.empty() ? impl_->url : std::string(url);
    }
    auto r = discoveryRoundTrip(url, encoderFor(req), deadline, "FindServers");
    return decodeIncoming<FindServersResponse>(r, "FindServers", decodeLimits()).servers;
}

// ---- view ----------------------------------------------------------------------------------

std::vector<BrowseResult> Client::browse(std::vector<BrowseDescription> nodes,
                                         UInt32 maxReferencesPerNode, Deadline deadline) {
    BrowseRequest req{};
    req.requestedMaxReferencesPerNode = maxReferencesPerNode;
    req.nodesToBrowse = std::move(nodes);
    return request(std::move(req), deadline).results;
}

BrowseResult Client::browse(const BrowseDescription& node, UInt32 maxReferencesPerNode,
                            Deadline deadline) {
    auto results = browse(std::vector<BrowseDescription>{node}, maxReferencesPerNode, deadline);
    if (results.size() != 1) throw Error(status::BadUnexpectedError, "Browse: expected one result");
    return std::move(results.front());
}

std::vector<ReferenceDescription> Client::browse(const NodeId& node, const BrowseOptions& options,
                                                 Deadline deadline) {
    Clock::time_point dl = deadline.resolve(Clock::now(), config().requestTimeout);
    BrowseDescription d{};
    d.nodeId = node;
    d.browseDirection = options.direction;
    d.referenceTypeId = options.referenceTypeId;
    d.includeSubtypes = options.includeSubtypes;
    d.nodeClassMask = options.nodeClassMask;
    d.resultMask = options.resultMask;
    BrowseResult r = browse(d, options.maxReferencesPerNode, dl);
    std::vector<ReferenceDescription> refs = std::move(r.references);
    for (;;) {
        if (r.statusCode.isBad()) {
            if (!r.continuationPoint.empty()) {
                try {
                    browseNext(r.continuationPoint, true, dl);
                } catch (const Error&) {
                }
            }
            throw Error(r.statusCode, describe("Browse", node));
        }
        if (r.continuationPoint.empty()) return refs;
        r = browseNext(r.continuationPoint, false, dl);
        for (auto& ref : r.references) refs.push_back(std::move(ref));
    }
}

std::vector<BrowseResult> Client::browseNext(std::vector<ByteString> continuationPoints,
                                             bool release, Deadline deadline) {
    BrowseNextRequest req{};
    req.releaseContinuationPoints = release;
    req.continuationPoints = std::move(continuationPoints);
    return request(std::move(req), deadline).results;
}

BrowseResult Client::browseNext(const ByteString& continuationPoint, bool release,
                                Deadline deadline) {
    auto results = browseNext(std::vector<ByteString>{continuationPoint}, release, deadline);
    if (results.size() != 1)
        throw Error(status::BadUnexpectedError, "BrowseNext: expected one result");
    return std::move(results.front());
}

std::vector<BrowsePathResult> Client::translateBrowsePaths(std::vector<BrowsePath> paths,
                                                           Deadline deadline) {
    TranslateBrowsePathsToNodeIdsRequest req{};
    req.browsePaths = std::move(paths);
    return request(std::move(req), deadline).results;
}

NodeId Client::resolve(std::string_view path, Deadline deadline) {
    return resolve(NodeId(0, kNodeRoot), path, deadline);
}

NodeId Client::resolve(const NodeId& start, std::string_view path, Deadline deadline) {
    Clock::time_point dl = deadline.resolve(Clock::now(), config().requestTimeout);
    BrowsePath bp{};
    bp.startingNode = start;
    bp.relativePath =
        parseRelativePath(path, [&](std::string_view uri) { return namespaceIndex(uri, dl); });
    auto results = translateBrowsePaths({std::move(bp)}, dl);
    if (results.size() != 1)
        throw Error(status::BadUnexpectedError, "TranslateBrowsePaths: expected one result");
    const BrowsePathResult& r = results.front();
    std::string what = "resolve \"" + std::string(path) + "\"";
    if (r.statusCode.isBad()) throw Error(r.statusCode, what);
    for (const auto& t : r.targets) {
        if (t.remainingPathIndex != UINT32_MAX) continue;  // only partly followed
        if (t.targetId.serverIndex != 0) continue;
        if (t.targetId.namespaceUri.empty()) return t.targetId.nodeId;
        return toNodeId(t.targetId, dl);
    }
    throw Error(status::BadNoMatch, what);
}

std::vector<NodeId> Client::registerNodes(std::vector<NodeId> nodes, Deadline deadline) {
    RegisterNodesRequest req{};
    req.nodesToRegister = std::move(nodes);
    return request(std::move(req), deadline).registeredNodeIds;
}

void Client::unregisterNodes(std::vector<NodeId> nodes, Deadline deadline) {
    UnregisterNodesRequest req{};
    req.nodesToUnregister = std::move(nodes);
    request(std::move(req), deadline);
}

// ---- attributes ----------------------------------------------------------------------------

std::vector<DataValue> Client::read(std::vector<ReadValueId> nodes, Deadline deadline) {
    return read(std::move(nodes), TimestampsToReturn::Both, deadline);
}

std::vector<DataValue> Client::read(std::vector<ReadValueId> nodes, TimestampsToReturn timestamps,
                                    Deadline deadline) {
    ReadRequest req{};
    req.maxAge = 0;
    req.timestampsToReturn = timestamps;
    req.nodesToRead = std::move(nodes);
    std::size_t n = req.nodesToRead.size();
    auto results = request(std::move(req), deadline).results;
    if (results.size() != n)
        throw Error(status::BadUnexpectedError, "Read: result count does not match the request");
    return results;
}

namespace {
ReadRequest singleRead(const NodeId& node, AttributeId attribute, TimestampsToReturn ts) {
    ReadRequest req{};
    req.maxAge = 0;
    req.timestampsToReturn = ts;
    req.nodesToRead.push_back(ReadValueId{node, static_cast<UInt32>(attribute), String(), {}});
    return req;
}

DataValue singleResult(ReadResponse&& resp) {
    if (resp.results.size() != 1)
        throw Error(status::BadUnexpectedError, "Read: expected one result");
    return std::move(resp.results.front());
}

Variant valueOf(DataValue&& dv, const NodeId& node) {
    StatusCode s = dv.statusOrGood();
    if (s.isBad()) throw Error(s, describe("Read", node));
    return dv.value ? std::move(*dv.value) : Variant();
}

WriteRequest singleWrite(const NodeId& node, AttributeId attribute, DataValue value) {
    // Built in place: copy-constructing the NodeId is cheaper than assigning it.
    WriteRequest req{};
    req.nodesToWrite.push_back(
        WriteValue{node, static_cast<UInt32>(attribute), String(), std::move(value)});
    return req;
}

StatusCode singleStatus(WriteResponse&& resp) {
    if (resp.results.size() != 1)
        throw Error(status::BadUnexpectedError, "Write: expected one result");
    return resp.results.front();
}

CallRequest singleCall(const NodeId& object, const NodeId& method, std::vector<Variant> inputs) {
    CallRequest req{};
    req.methodsToCall.push_back(CallMethodRequest{object, method, std::move(inputs)});
    return req;
}

CallResult callResultOf(CallResponse&& resp) {
    if (resp.results.size() != 1)
        throw Error(status::BadUnexpectedError, "Call: expected one result");
    CallMethodResult& r = resp.results.front();
    return CallResult{r.statusCode, std::move(r.inputArgumentResults),
                      std::move(r.outputArguments)};
}
}  // namespace

DataValue Client::readAttribute(const NodeId& node, AttributeId attribute, Deadline deadline) {
    return singleResult(request(singleRead(node, attribute, TimestampsToReturn::Both), deadline));
}

Variant Client::readValue(const NodeId& node, Deadline deadline) {
    return valueOf(
        singleResult(
            request(singleRead(node, AttributeId::Value, TimestampsToReturn::Neither), deadline)),
        node);
}

std::vector<StatusCode> Client::write(std::vector<WriteValue> nodes, Deadline deadline) {
    WriteRequest req{};
    req.nodesToWrite = std::move(nodes);
    return request(std::move(req), deadline).results;
}

StatusCode Client::writeAttribute(const NodeId& node, AttributeId attribute, DataValue value,
                                  Deadline deadline) {
    return singleStatus(request(singleWrite(node, attribute, std::move(value)), deadline));
}

StatusCode Client::writeValue(const NodeId& node, Variant value, Deadline deadline) {
    return singleStatus(
        request(singleWrite(node, AttributeId::Value, DataValue(std::move(value))), deadline));
}

// ---- methods -------------------------------------------------------------------------------

std::vector<CallMethodResult> Client::call(std::vector<CallMethodRequest> calls,
                                           Deadline deadline) {
    CallRequest req{};
    req.methodsToCall = std::move(calls);
    return request(std::move(req), deadline).results;
}

CallResult Client::call(const NodeId& object, const NodeId& method, std::vector<Variant> inputs,
                        Deadline deadline) {
    return callResultOf(request(singleCall(object, method, std::move(inputs)), deadline));
}

// ---- async convenience -----------------------------------------------------------------------

void Client::readAsync(std::vector<ReadValueId> nodes,
                       std::function<void(Result<std::vector<DataValue>>)> callback,
                       Deadline deadline) {
    ReadRequest req{};
    req.maxAge = 0;
    req.timestampsToReturn = TimestampsToReturn::Both;
    req.nodesToRead = std::move(nodes);
    requestAsync(
        std::move(req),
        [cb = std::move(callback)](Result<ReadResponse> r) {
            if (!r.ok())
                cb(*r.error());
            else
                cb(std::move(r.value().results));
        },
        deadline);
}

void Client::readValueAsync(const NodeId& node, std::function<void(Result<Variant>)> callback,
                            Deadline deadline) {
    requestAsync(
        singleRead(node, AttributeId::Value, TimestampsToReturn::Neither),
        [cb = std::move(callback), node](Result<ReadResponse> r) {
            auto result = [&]() -> Result<Variant> {
                if (!r.ok()) return *r.error();
                try {
                    return valueOf(singleResult(std::move(r.value())), node);
                } catch (const Error& e) {
                    return e;
                }
            }();
            cb(std::move(result));
        },
        deadline);
}

void Client::writeAsync(std::vector<WriteValue> nodes,
                        std::function<void(Result<std::vector<StatusCode>>)> callback,
                        Deadline deadline) {
    WriteRequest req{};
    req.nodesToWrite = std::move(nodes);
    requestAsync(
        std::move(req),
        [cb = std::move(callback)](Result<WriteResponse> r) {
            if (!r.ok())
                cb(*r.error());
            else
                cb(std::move(r.value().results));
        },
        deadline);
}

void Client::callAsync(const NodeId& object, const NodeId& method, std::vector<Variant> inputs,
                       std::function<void(Result<CallResult>)> callback, Deadline deadline) {
    requestAsync(
        singleCall(object, method, std::move(inputs)),
        [cb = std::move(callback)](Result<CallResponse> r) {
            auto result = [&]() -> Result<CallResult> {
                if (!r.ok()) return *r.error();
                try {
                    return callResultOf(std::move(r.value()));
                } catch (const Error& e) {
                    return e;
                }
            }();
            cb(std::move(result));
        },
        deadline);
}

// ---- namespaces ----------------------------------------------------------------------------

std::vector<std::string> Client::namespaceArray(Deadline deadline) {
    Variant v = readValue(NodeId(0, ns0::Server_NamespaceArray), deadline);
    const auto* a = v.array<String>();
    if (!a) throw Error(status::BadTypeMismatch, "Read of NamespaceArray: not an array of String");
    std::lock_guard lock(impl_->mutex);
    impl_->namespaces = *a;
    return *a;
}

UInt16 Client::namespaceIndex(std::string_view uri, Deadline deadline) {
    auto lookup = [&]() -> std::optional<UInt16> {
        std::lock_guard lock(impl_->mutex);
        const auto& ns = impl_->namespaces;
        for (std::size_t i = 0; i < ns.size(); ++i)
            if (ns[i] == uri) return static_cast<UInt16>(i);
        return std::nullopt;
    };
    if (auto i = lookup()) return *i;
    namespaceArray(deadline);
    if (auto i = lookup()) return *i;
    throw Error(status::BadNotFound, "namespace \"" + std::string(uri) + "\" is not on the server");
}

NodeId Client::parseNodeId(std::string_view text, Deadline deadline) {
    auto x = ExpandedNodeId::parse(text);
    if (!x || x->serverIndex != 0)
        throw Error(status::BadNodeIdInvalid, "invalid NodeId \"" + std::string(text) + "\"");
    return toNodeId(*x, deadline);
}

NodeId Client::toNodeId(const ExpandedNodeId& id, Deadline deadline) {
    if (id.serverIndex != 0)
        throw Error(status::BadNodeIdInvalid, "NodeId on another server: " + id.toString());
    NodeId n = id.nodeId;
    if (!id.namespaceUri.empty()) n.setNamespaceIndex(namespaceIndex(id.namespaceUri, deadline));
    return n;
}

// ---- event loop ----------------------------------------------------------------------------

std::size_t Client::runIterate(milliseconds timeout) {
    Impl& s = *impl_;
    Clock::time_point end = Clock::now() + timeout;
    std::size_t n = 0;
    short revents = 0;  // of the socket, from the last poll()
    std::uint64_t watched = 0;
    for (;;) {
        Clock::time_point until;
        int fd = -1;
        {
            Completions done(s.completions);
            {
                std::lock_guard lock(s.mutex);
                s.ensureWakeFd();
                if (revents & (POLLRDHUP | POLLHUP | POLLERR)) s.peerHungUp(watched, done);
                until = s.housekeeping(done, (revents & POLLIN) && watched == s.generation);
                if (s.conn) {
                    fd = s.conn->nativeHandle();
                    watched = s.generation;
                }
            }
            n += done.run();
        }
        if (n > 0 || Clock::now() >= end) return n;
        revents = s.waitForEvents(fd, POLLIN | POLLRDHUP, std::min(end, until));
    }
}

void Client::startBackgroundThread() {
    Impl& s = *impl_;
    std::thread old;
    {
        std::lock_guard lock(s.mutex);
        if (s.thread.joinable()) {
            // Running, or asked to stop from its own callback and not joined yet.
            if (!s.stopRequested || s.thread.get_id() == std::this_thread::get_id()) return;
            old = std::move(s.thread);
        }
    }
    if (old.joinable()) old.join();
    std::lock_guard lock(s.mutex);
    if (s.thread.joinable()) return;
    s.ensureWakeFd();
    s.stopRequested = false;
    s.thread = std::thread([&s] { s.backgroundLoop(); });
}

void Client::stopBackgroundThread() {
    Impl& s = *impl_;
    std::thread t;
    {
        std::lock_guard lock(s.mutex);
        if (!s.thread.joinable()) return;
        s.stopRequested = true;
        s.signalWakeFd();
        // From a callback on the background thread itself: it ends when the callback
        // returns and is joined by the next start/stop or the destructor.
        if (s.thread.get_id() == std::this_thread::get_id()) return;
        t = std::move(s.thread);
    }
    t.join();
}

bool Client::backgroundThreadRunning() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->thread.joinable() && !impl_->stopRequested;
}

}  // namespace pnp::ua::client
