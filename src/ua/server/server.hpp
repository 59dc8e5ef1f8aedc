// The OPC UA server: endpoints, sessions and service dispatch on top of the opc.tcp
// transport and the address space.
//
// Threading: the transport's event loops (one per core) read the connections; services run
// on them under the transport's network lock, one at a time across the server (see
// transport/tcp_server.hpp),
// so services must be quick; long-running work (a method that moves a robot) completes later
// from any thread through the method's completion callback. Applications change the address
// space from their own threads through Server::post() or the address space's thread-safe
// value setters. "The network thread" below: whichever thread holds the network lock.
#pragma once

#include <atomic>
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <shared_mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "ua/crypto/crypto.hpp"
#include "ua/pki/pki.hpp"
#include "ua/server/access_control.hpp"
#include "ua/server/address_space.hpp"
#include "ua/server/discovery.hpp"
#include "ua/server/subscriptions.hpp"
#include "ua/transport/tcp_server.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

// Per-service operation limits (advertised in ServerCapabilities/OperationLimits).
struct OperationLimits {
    UInt32 maxNodesPerRead = 10000;
    UInt32 maxNodesPerWrite = 10000;
    UInt32 maxNodesPerBrowse = 10000;
    UInt32 maxNodesPerMethodCall = 1000;
    UInt32 maxNodesPerTranslateBrowsePathsToNodeIds = 10000;
    UInt32 maxNodesPerRegisterNodes = 10000;
    UInt32 maxBrowseContinuationPoints = 16;  // per session
};

// A server's security (docs/security.md): its application instance certificate, the trust
// list that decides which clients may open a secured channel, and the endpoints offered.
struct ServerSecurity {
    pki::Identity identity;
    // Validates client certificates (untrusted ones land in its rejected/ folder). Null:
    // every well-formed certificate is accepted — for tests only.
    std::shared_ptr<pki::CertificateStore> trust;
    // Offered policies, most secure first; empty: every supported one.
    std::vector<const crypto::SecurityPolicy*> policies;
    bool offerSign = true;  // endpoints with MessageSecurityMode Sign besides SignAndEncrypt
    // A None endpoint for sessions. Without it a None channel serves discovery only
    // (FindServers, GetEndpoints, FindServersOnNetwork).
    bool offerNone = false;
    // The name of the identity's files in the trust store's own/ (own/certs/<name>.der), where
    // Part 12 UpdateCertificate writes a new one; empty: found by looking at every file.
    std::string certificateName;
    // Told about a client certificate that failed validation (on the network thread: keep it
    // short), e.g. to tell the operator how to approve it.
    std::function<void(const pki::Certificate&, StatusCode)> onClientRefused;
};

struct ServerConfig {
    std::string applicationUri = "urn:pnp:server";
    std::string productUri = "urn:pnp";
    std::string applicationName = "pnp OPC UA server";
    std::string manufacturerName = "pnp";
    std::string productName = "pnp";
    std::string softwareVersion = "0.1.0";
    std::string buildNumber = "1";

    std::string host = "0.0.0.0";  // listen address
    std::string publicHost;        // host name put into endpoint URLs; default: hostname
    UInt16 port = 4840;            // 0: ephemeral
    std::string endpointPath;      // e.g. "/pnp"

    transport::ServerTransportConfig transport;
    OperationLimits limits;
    SubscriptionLimits subscriptionLimits;
    DecodeLimits decodeLimits;

    UInt32 maxSessions = 100;
    Double minSessionTimeoutMs = 1000;
    Double maxSessionTimeoutMs = 3600000;

    std::shared_ptr<AccessControl> accessControl;  // default: anonymous only
    // Secured endpoints; absent: SecurityPolicy None only.
    std::optional<ServerSecurity> security;

    // The Local Discovery Server (docs/discovery.md); off by default.
    DiscoveryConfig discovery;
};

class Server : public transport::ServiceHandler {
  public:
    explicit Server(ServerConfig config = {});
    ~Server() override;
    Server(const Server&) = delete;
    Server& operator=(const Server&) = delete;

    // The nodes. Build the address space before start(), or change it later on the network
    // thread (post()).
    AddressSpace& addressSpace() { return *addressSpace_; }
    UInt16 addNamespace(const std::string& uri);

    void start();  // binds and starts the transport's threads; throws on bind failure
    void stop();   // closes every connection and joins the transport's threads
    bool running() const;
    UInt16 port() const;
    std::string endpointUrl() const;  // opc.tcp://publicHost:port/path
    const ServerConfig& config() const { return config_; }

    // Runs fn on the network thread, i.e. under the network lock (immediately if called
    // under it).
    void post(std::function<void()> fn);
    // Only while not started (a server driven by calling its ServiceHandler directly: tests,
    // fuzzing): waits, at most until `deadline`, for the password checks under way and runs
    // what they and others post()ed, on this thread. False if work was still pending.
    bool runPostedWork(std::chrono::steady_clock::time_point deadline);
    // In a service or method handler (the network thread): runs fn on this thread once it has
    // left the network lock and written the responses queued so far, e.g. to wake a worker
    // that would otherwise compete with the response for the CPU. Elsewhere: at once.
    void afterResponsesWritten(std::function<void()> fn);
    // True in a service or method handler: this thread holds the network lock, and no other
    // request is served until the handler returns.
    bool isNetworkThread() const;

    // Fires an event (any thread): monitored items on its SourceNode and on every notifier
    // above it up to the Server object receive it (see SubscriptionEngine::fireEvent).
    void fireEvent(Event event);
    SubscriptionEngine& subscriptions() { return *subscriptions_; }

    // The embedded Local Discovery Server: the plug-in surface for the mDNS glue (any
    // thread). nullptr unless config.discovery.localDiscoveryServer.
    LocalDiscovery* localDiscovery() { return discovery_.get(); }

    // Open sessions (any thread).
    std::size_t sessionCount() const { return sessionCount_.load(std::memory_order_relaxed); }

    // A per-node check of the Write service that knows the writing session (e.g. a DI lock:
    // only the lock holder may write a skill's parameters). Runs on the network thread after
    // access control and before the address space's own checks; a Bad result is that item's
    // result. Any thread; an empty guard removes the node's guard.
    using WriteGuard = std::function<StatusCode(const NodeId& sessionId, const WriteValue& item)>;
    void setWriteGuard(const NodeId& node, WriteGuard guard);
    // Told of every session that ends (CloseSession, timeout, server stop), on the network
    // thread: must be quick. Observers cannot be removed (they live as long as the server,
    // so capture weak references). Any thread.
    void onSessionClosed(std::function<void(const NodeId& sessionId)> observer);

    // Replaces the application instance certificate and key of a secured server (Part 12
    // ApplyChanges). Any thread; takes effect on the network thread (at once when called on
    // it): secure channels opened from then on, GetEndpoints and CreateSession use the new
    // certificate; channels already open keep theirs. Throws std::logic_error without
    // config.security.
    void setSecurityIdentity(pki::Identity identity);

  private:
    struct Session;
    struct Ctx;
    class AuthWorker;

    void onRequest(const std::shared_ptr<transport::ServerConnection>& conn,
                   const transport::IncomingRequest& req) override;
    void onConnectionClosed(const std::shared_ptr<transport::ServerConnection>& conn) override;

    template <class Req, class Resp>
    void serve(const std::shared_ptr<transport::ServerConnection>& conn,
               const transport::IncomingRequest& in, bool needsSession,
               void (Server::*handler)(Ctx&, const Req&, Resp&));
    template <class Req>
    bool accept(const std::shared_ptr<transport::ServerConnection>& conn,
                const transport::IncomingRequest& in, bool needsSession, Req& req, Ctx& ctx);

    // Services.
    void getEndpoints(Ctx&, const GetEndpointsRequest&, GetEndpointsResponse&);
    void findServers(Ctx&, const FindServersRequest&, FindServersResponse&);
    void registerServer(Ctx&, const RegisterServerRequest&, RegisterServerResponse&);
    void registerServer2(Ctx&, const RegisterServer2Request&, RegisterServer2Response&);
    void findServersOnNetwork(Ctx&, const FindServersOnNetworkRequest&,
                              FindServersOnNetworkResponse&);
    void createSession(Ctx&, const CreateSessionRequest&, CreateSessionResponse&);
    // ActivateSession: the channel and signature checks on the network thread; a password
    // check (a salted hash: tens of ms) on the auth worker, answered from the network thread.
    void activate(const std::shared_ptr<transport::ServerConnection>& conn,
                  const transport::IncomingRequest& in);
    // The checks before the identity token: the session is returned, or null with `resp`'s
    // result set.
    Session* checkActivation(Ctx&, const ActivateSessionRequest&, ActivateSessionResponse&,
                             ActivationContext& context);
    // After a Good token check: binds the session to the channel and the user.
    void completeActivation(const transport::ServerConnection& conn, Session& s,
                            const SessionIdentity& identity, ActivateSessionResponse& resp);
    void closeSession(Ctx&, const CloseSessionRequest&, CloseSessionResponse&);
    void read(Ctx&, const ReadRequest&, ReadResponse&);
    void write(Ctx&, const WriteRequest&, WriteResponse&);
    void browse(Ctx&, const BrowseRequest&, BrowseResponse&);
    void browseNext(Ctx&, const BrowseNextRequest&, BrowseNextResponse&);
    void translate(Ctx&, const TranslateBrowsePathsToNodeIdsRequest&,
                   TranslateBrowsePathsToNodeIdsResponse&);
    void registerNodes(Ctx&, const RegisterNodesRequest&, RegisterNodesResponse&);
    void unregisterNodes(Ctx&, const UnregisterNodesRequest&, UnregisterNodesResponse&);
    void call(const std::shared_ptr<transport::ServerConnection>& conn,
              const transport::IncomingRequest& in);
    void publish(const std::shared_ptr<transport::ServerConnection>& conn,
                 const transport::IncomingRequest& in);
    template <class Req, class Resp>
    void serveSubscriptions(const std::shared_ptr<transport::ServerConnection>& conn,
                            const transport::IncomingRequest& in,
                            void (SubscriptionEngine::*handler)(const NodeId&, const Req&, Resp&),
                            std::size_t (*count)(const Req&));

    std::vector<EndpointDescription> endpointDescriptions(const std::string& url) const;
    ApplicationDescription applicationDescription() const;
    void setUpServerObject();
    void expireSessions();

    ServerConfig config_;
    std::unique_ptr<AddressSpace> addressSpace_;
    std::unique_ptr<SubscriptionEngine> subscriptions_;
    std::unique_ptr<transport::TcpServer> transport_;
    std::unique_ptr<LocalDiscovery> discovery_;  // when config_.discovery enables it
    std::unique_ptr<AuthWorker> authWorker_;     // started by the first password login
    DateTime startTime_;
    std::unordered_map<NodeId, std::unique_ptr<Session>> sessions_;  // by authentication token
    UInt32 nextSessionNumber_ = 1;
    std::atomic<std::size_t> sessionCount_{0};
    mutable std::shared_mutex guardsMutex_;
    std::unordered_map<NodeId, WriteGuard> writeGuards_;
    std::atomic<bool> hasWriteGuards_{false};
    std::vector<std::function<void(const NodeId&)>> sessionClosedObservers_;  // guardsMutex_
    void sessionClosed(const NodeId& sessionId);
    void updateSessionCount() { sessionCount_.store(sessions_.size(), std::memory_order_relaxed); }
};

}  // namespace pnp::ua::server
