#include "ua/server/server.hpp"

#include <unistd.h>

#include <algorithm>
#include <random>

#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {

namespace {
constexpr const char* kTransportProfile =
    "http://opcfoundation.org/UA-Profile/Transport/uatcp-uasc-uabinary";
constexpr const char* kSecurityPolicyNone = "http://opcfoundation.org/UA/SecurityPolicy#None";
constexpr auto kSessionCheckPeriod = std::chrono::milliseconds(500);

ByteString randomBytes(std::size_t n) {
    thread_local std::mt19937_64 rng{std::random_device{}()};
    std::string s(n, '\0');
    for (std::size_t i = 0; i < n; i += 8) {
        UInt64 r = rng();
        for (std::size_t k = 0; k < 8 && i + k < n; ++k) s[i + k] = static_cast<char>(r >> (8 * k));
    }
    return ByteString(std::move(s));
}

std::string hostName() {
    char buf[256] = {0};
    if (gethostname(buf, sizeof buf - 1) != 0 || buf[0] == 0) return "localhost";
    return buf;
}

// Empty lists and lists beyond the server's limit are refused as a whole (Part 4 §7.34).
template <class T>
StatusCode checkOperationCount(const std::vector<T>& items, UInt32 limit) {
    if (items.empty()) return status::BadNothingToDo;
    if (limit != 0 && items.size() > limit) return status::BadTooManyOperations;
    return status::Good;
}

template <class Req>
std::size_t noOperations(const Req&) {
    return 1;
}
}  // namespace

struct Server::Session {
    NodeId sessionId;
    NodeId authenticationToken;
    std::string name;
    Double timeoutMs = 0;
    transport::TimePoint lastActivity;
    UInt32 channelId = 0;
    bool activated = false;
    SessionIdentity identity;
    ContinuationPointStore continuationPoints;

    explicit Session(std::size_t maxContinuationPoints)
        : continuationPoints(maxContinuationPoints) {}
    bool expired(transport::TimePoint now) const {
        return now - lastActivity > std::chrono::duration<Double, std::milli>(timeoutMs);
    }
};

struct Server::Ctx {
    const std::shared_ptr<transport::ServerConnection>& conn;
    Session* session = nullptr;
};

Server::Server(ServerConfig config) : config_(std::move(config)) {
    if (!config_.accessControl) config_.accessControl = std::make_shared<DefaultAccessControl>();
    if (config_.publicHost.empty()) config_.publicHost = hostName();
    AddressSpace::Options options;
    options.applicationUri = config_.applicationUri;
    addressSpace_ = std::make_unique<AddressSpace>(options);
    subscriptions_ = std::make_unique<SubscriptionEngine>(
        *addressSpace_, config_.subscriptionLimits, config_.decodeLimits);
    config_.transport.host = config_.host;
    config_.transport.port = config_.port;
    transport_ = std::make_unique<transport::TcpServer>(
        config_.transport, static_cast<transport::ServiceHandler&>(*this));
    startTime_ = DateTime::now();
    if (config_.discovery.localDiscoveryServer) {
        auto& caps = config_.discovery.serverCapabilities;
        if (std::find(caps.begin(), caps.end(), "LDS") == caps.end()) caps.push_back("LDS");
        discovery_ = std::make_unique<LocalDiscovery>(config_.discovery);
    }
    setUpServerObject();
}

Server::~Server() { stop(); }

UInt16 Server::addNamespace(const std::string& uri) { return addressSpace_->addNamespace(uri); }

void Server::start() {
    transport_->setTick(kSessionCheckPeriod, [this] { expireSessions(); });
    subscriptions_->start();
    transport_->start();
    if (discovery_) {
        // Our own FindServersOnNetwork record needs the bound port.
        discovery_->setSelf(
            {config_.applicationName, endpointUrl(), config_.discovery.serverCapabilities});
        discovery_->start();
    }
}

void Server::stop() {
    if (transport_) transport_->stop();
    if (subscriptions_) subscriptions_->stop();
    if (discovery_) discovery_->stop();
}

void Server::fireEvent(Event event) { subscriptions_->fireEvent(std::move(event)); }

bool Server::running() const { return transport_->running(); }
UInt16 Server::port() const { return transport_->port(); }

std::string Server::endpointUrl() const {
    return "opc.tcp://" + config_.publicHost + ":" + std::to_string(port()) + config_.endpointPath;
}

void Server::post(std::function<void()> fn) {
    if (transport_->isNetworkThread())
        fn();
    else
        transport_->post(std::move(fn));
}

bool Server::isNetworkThread() const { return transport_->isNetworkThread(); }

void Server::afterResponsesWritten(std::function<void()> fn) {
    transport_->afterResponsesWritten(std::move(fn));
}

// ---- Server object (Part 5 §6.3.1): live status and capabilities ------------------------
void Server::setUpServerObject() {
    auto& as = *addressSpace_;
    auto set = [&](UInt32 id, Variant v) { as.setValue(NodeId(0, id), DataValue(std::move(v))); };

    BuildInfo build;
    build.productUri = config_.productUri;
    build.manufacturerName = config_.manufacturerName;
    build.productName = config_.productName;
    build.softwareVersion = config_.softwareVersion;
    build.buildNumber = config_.buildNumber;
    build.buildDate = startTime_;

    set(ns0::Server_ServerStatus_StartTime, startTime_);
    set(ns0::Server_ServerStatus_State, static_cast<Int32>(ServerState::Running));
    set(ns0::Server_ServerStatus_BuildInfo, toExtensionObject(build));
    set(ns0::Server_ServerStatus_BuildInfo_ProductUri, build.productUri);
    set(ns0::Server_ServerStatus_BuildInfo_ManufacturerName, build.manufacturerName);
    set(ns0::Server_ServerStatus_BuildInfo_ProductName, build.productName);
    set(ns0::Server_ServerStatus_BuildInfo_SoftwareVersion, build.softwareVersion);
    set(ns0::Server_ServerStatus_BuildInfo_BuildNumber, build.buildNumber);
    set(ns0::Server_ServerStatus_BuildInfo_BuildDate, build.buildDate);
    set(ns0::Server_ServerStatus_SecondsTillShutdown, UInt32{0});
    set(ns0::Server_ServerStatus_ShutdownReason, LocalizedText());
    set(ns0::Server_ServiceLevel, Byte{255});
    set(ns0::Server_Auditing, false);
    set(ns0::Server_ServerArray, std::vector<String>{config_.applicationUri});

    as.setValueCallback(NodeId(0, ns0::Server_ServerStatus_CurrentTime),
                        {[](const NodeId&) { return DataValue(Variant(DateTime::now())); }, {}});
    as.setValueCallback(NodeId(0, ns0::Server_ServerStatus),
                        {[this, build](const NodeId&) {
                             ServerStatusDataType s;
                             s.startTime = startTime_;
                             s.currentTime = DateTime::now();
                             s.state = ServerState::Running;
                             s.buildInfo = build;
                             return DataValue(Variant(toExtensionObject(s)));
                         },
                         {}});
    as.setValueCallback(
        NodeId(0, ns0::Server_NamespaceArray),
        {[this](const NodeId&) { return DataValue(Variant(addressSpace_->namespaceArray())); },
         {}});

    const auto& lim = config_.limits;
    set(ns0::Server_ServerCapabilities_ServerProfileArray,
        std::vector<String>{"http://opcfoundation.org/UA-Profile/Server/MicroEmbeddedDevice2017"});
    set(ns0::Server_ServerCapabilities_LocaleIdArray, std::vector<String>{"en"});
    set(ns0::Server_ServerCapabilities_MinSupportedSampleRate, Double{0});
    set(ns0::Server_ServerCapabilities_MaxBrowseContinuationPoints,
        static_cast<UInt16>(lim.maxBrowseContinuationPoints));
    set(ns0::Server_ServerCapabilities_MaxQueryContinuationPoints, UInt16{0});
    set(ns0::Server_ServerCapabilities_MaxHistoryContinuationPoints, UInt16{0});
    set(ns0::Server_ServerCapabilities_MaxArrayLength,
        static_cast<UInt32>(config_.decodeLimits.maxArrayLength));
    set(ns0::Server_ServerCapabilities_MaxStringLength,
        static_cast<UInt32>(config_.decodeLimits.maxStringLength));
    set(ns0::Server_ServerCapabilities_MaxByteStringLength,
        static_cast<UInt32>(config_.decodeLimits.maxStringLength));
    set(ns0::Server_ServerCapabilities_OperationLimits_MaxNodesPerRead, lim.maxNodesPerRead);
    set(ns0::Server_ServerCapabilities_OperationLimits_MaxNodesPerWrite, lim.maxNodesPerWrite);
    set(ns0::Server_ServerCapabilities_OperationLimits_MaxNodesPerBrowse, lim.maxNodesPerBrowse);
    set(ns0::Server_ServerCapabilities_OperationLimits_MaxNodesPerMethodCall,
        lim.maxNodesPerMethodCall);
    set(ns0::Server_ServerCapabilities_OperationLimits_MaxNodesPerTranslateBrowsePathsToNodeIds,
        lim.maxNodesPerTranslateBrowsePathsToNodeIds);
    set(ns0::Server_ServerCapabilities_OperationLimits_MaxNodesPerRegisterNodes,
        lim.maxNodesPerRegisterNodes);
    const auto& sub = config_.subscriptionLimits;
    set(ns0::Server_ServerCapabilities_OperationLimits_MaxMonitoredItemsPerCall,
        sub.maxMonitoredItemsPerCall);
    set(ns0::Server_ServerCapabilities_MaxSubscriptionsPerSession, sub.maxSubscriptionsPerSession);
    set(ns0::Server_ServerCapabilities_MaxMonitoredItemsPerSubscription,
        sub.maxMonitoredItemsPerSubscription);
    set(ns0::Server_ServerCapabilities_MaxMonitoredItemsQueueSize, sub.maxQueueSize);
}

// ---- endpoints ------------------------------------------------------------------------------
ApplicationDescription Server::applicationDescription() const {
    ApplicationDescription d;
    d.applicationUri = config_.applicationUri;
    d.productUri = config_.productUri;
    d.applicationName = LocalizedText("en", config_.applicationName);
    d.applicationType = ApplicationType::Server;
    d.discoveryUrls = {endpointUrl()};
    return d;
}

std::vector<EndpointDescription> Server::endpointDescriptions(const std::string& url) const {
    EndpointDescription e;
    // Answer with the address the client used when it is ours (it reached us that way).
    e.endpointUrl = url.starts_with("opc.tcp://") ? url : endpointUrl();
    e.server = applicationDescription();
    e.securityMode = MessageSecurityMode::None;
    e.securityPolicyUri = kSecurityPolicyNone;
    e.userIdentityTokens = config_.accessControl->userTokenPolicies();
    e.transportProfileUri = kTransportProfile;
    e.securityLevel = 0;
    return {e};
}

// ---- dispatch -------------------------------------------------------------------------------
namespace {
template <class Resp>
void sendResponse(transport::ServerConnection& conn, UInt32 requestId, UInt32 requestHandle,
                  Resp& resp) {
    resp.responseHeader.requestHandle = requestHandle;
    resp.responseHeader.timestamp = DateTime::nowCoarse();
    if (resp.responseHeader.serviceResult.isBad()) {
        // A failed service carries no results (Part 4 §7.30): answer with a ServiceFault.
        conn.sendServiceFault(requestId, requestHandle, resp.responseHeader.serviceResult);
        return;
    }
    // Large byte runs (a 32 KiB ByteString) are not copied into the message: the response
    // itself is kept until they are written (moving it keeps their heap storage in place).
    Buffer b = transport::ServerConnection::newMessageBuffer();
    Splices splices;
    BinaryEncoder e(b, &splices);
    encode(e, NodeId(0, DataTypeInfo<Resp>::binaryEncodingId));
    encode(e, resp);
    if (splices.empty()) {
        conn.send(requestId, std::move(b));
        return;
    }
    auto keep = std::make_shared<Resp>(std::move(resp));
    conn.sendSpliced(requestId, std::move(b), std::move(splices), std::move(keep));
}
}  // namespace

template <class Req>
bool Server::accept(const std::shared_ptr<transport::ServerConnection>& conn,
                    const transport::IncomingRequest& in, bool needsSession, Req& req, Ctx& ctx) {
    try {
        BinaryDecoder d(in.body, in.size, config_.decodeLimits);
        if (in.block != nullptr) d.shareFrom(in.block);
        decode(d, req);
    } catch (const DecodeError& e) {
        conn->sendServiceFault(in.requestId, 0, e.status());
        return false;
    }
    if (!needsSession) return true;
    const RequestHeader& header = req.requestHeader;
    auto it = sessions_.find(header.authenticationToken);
    StatusCode bad;
    if (it == sessions_.end())
        bad = status::BadSessionIdInvalid;
    else if (!it->second->activated)
        bad = status::BadSessionNotActivated;
    else if (it->second->channelId != conn->channelId())
        bad = status::BadSecureChannelIdInvalid;
    if (bad.isBad()) {
        conn->sendServiceFault(in.requestId, header.requestHandle, bad);
        return false;
    }
    ctx.session = it->second.get();
    ctx.session->lastActivity = transport::coarseNow();
    return true;
}

template <class Req, class Resp>
void Server::serve(const std::shared_ptr<transport::ServerConnection>& conn,
                   const transport::IncomingRequest& in, bool needsSession,
                   void (Server::*handler)(Ctx&, const Req&, Resp&)) {
    Req req;
    Ctx ctx{conn};
    if (!accept(conn, in, needsSession, req, ctx)) return;
    Resp resp;
    try {
        (this->*handler)(ctx, req, resp);
    } catch (const std::exception&) {
        conn->sendServiceFault(in.requestId, req.requestHeader.requestHandle,
                               status::BadInternalError);
        return;
    }
    sendResponse(*conn, in.requestId, req.requestHeader.requestHandle, resp);
}

void Server::onRequest(const std::shared_ptr<transport::ServerConnection>& conn,
                       const transport::IncomingRequest& in) {
    if (in.typeId.namespaceIndex() != 0 || !in.typeId.isNumeric()) {
        conn->sendServiceFault(in.requestId, 0, status::BadServiceUnsupported);
        return;
    }
    switch (in.typeId.numeric()) {
        case DataTypeInfo<ReadRequest>::binaryEncodingId:
            return serve(conn, in, true, &Server::read);
        case DataTypeInfo<WriteRequest>::binaryEncodingId:
            return serve(conn, in, true, &Server::write);
        case DataTypeInfo<CallRequest>::binaryEncodingId:
            return call(conn, in);
        case DataTypeInfo<BrowseRequest>::binaryEncodingId:
            return serve(conn, in, true, &Server::browse);
        case DataTypeInfo<BrowseNextRequest>::binaryEncodingId:
            return serve(conn, in, true, &Server::browseNext);
        case DataTypeInfo<TranslateBrowsePathsToNodeIdsRequest>::binaryEncodingId:
            return serve(conn, in, true, &Server::translate);
        case DataTypeInfo<RegisterNodesRequest>::binaryEncodingId:
            return serve(conn, in, true, &Server::registerNodes);
        case DataTypeInfo<UnregisterNodesRequest>::binaryEncodingId:
            return serve(conn, in, true, &Server::unregisterNodes);
        case DataTypeInfo<PublishRequest>::binaryEncodingId:
            return publish(conn, in);
        case DataTypeInfo<CreateSubscriptionRequest>::binaryEncodingId:
            return serveSubscriptions(conn, in, &SubscriptionEngine::createSubscription,
                                      noOperations<CreateSubscriptionRequest>);
        case DataTypeInfo<ModifySubscriptionRequest>::binaryEncodingId:
            return serveSubscriptions(conn, in, &SubscriptionEngine::modifySubscription,
                                      noOperations<ModifySubscriptionRequest>);
        case DataTypeInfo<DeleteSubscriptionsRequest>::binaryEncodingId:
            return serveSubscriptions(
                conn, in, &SubscriptionEngine::deleteSubscriptions,
                +[](const DeleteSubscriptionsRequest& r) { return r.subscriptionIds.size(); });
        case DataTypeInfo<SetPublishingModeRequest>::binaryEncodingId:
            return serveSubscriptions(
                conn, in, &SubscriptionEngine::setPublishingMode,
                +[](const SetPublishingModeRequest& r) { return r.subscriptionIds.size(); });
        case DataTypeInfo<RepublishRequest>::binaryEncodingId:
            return serveSubscriptions(conn, in, &SubscriptionEngine::republish,
                                      noOperations<RepublishRequest>);
        case DataTypeInfo<CreateMonitoredItemsRequest>::binaryEncodingId:
            return serveSubscriptions(
                conn, in, &SubscriptionEngine::createMonitoredItems,
                +[](const CreateMonitoredItemsRequest& r) { return r.itemsToCreate.size(); });
        case DataTypeInfo<ModifyMonitoredItemsRequest>::binaryEncodingId:
            return serveSubscriptions(
                conn, in, &SubscriptionEngine::modifyMonitoredItems,
                +[](const ModifyMonitoredItemsRequest& r) { return r.itemsToModify.size(); });
        case DataTypeInfo<DeleteMonitoredItemsRequest>::binaryEncodingId:
            return serveSubscriptions(
                conn, in, &SubscriptionEngine::deleteMonitoredItems,
                +[](const DeleteMonitoredItemsRequest& r) { return r.monitoredItemIds.size(); });
        case DataTypeInfo<SetMonitoringModeRequest>::binaryEncodingId:
            return serveSubscriptions(
                conn, in, &SubscriptionEngine::setMonitoringMode,
                +[](const SetMonitoringModeRequest& r) { return r.monitoredItemIds.size(); });
        case DataTypeInfo<SetTriggeringRequest>::binaryEncodingId:
            return serveSubscriptions(
                conn, in, &SubscriptionEngine::setTriggering, +[](const SetTriggeringRequest& r) {
                    // Both lists empty is nothing to do; either may be empty alone.
                    return r.linksToAdd.size() + r.linksToRemove.size();
                });
        case DataTypeInfo<TransferSubscriptionsRequest>::binaryEncodingId:
            return serveSubscriptions(
                conn, in, &SubscriptionEngine::transferSubscriptions,
                +[](const TransferSubscriptionsRequest& r) { return r.subscriptionIds.size(); });
        case DataTypeInfo<GetEndpointsRequest>::binaryEncodingId:
            return serve(conn, in, false, &Server::getEndpoints);
        case DataTypeInfo<FindServersRequest>::binaryEncodingId:
            return serve(conn, in, false, &Server::findServers);
        case DataTypeInfo<CreateSessionRequest>::binaryEncodingId:
            return serve(conn, in, false, &Server::createSession);
        case DataTypeInfo<ActivateSessionRequest>::binaryEncodingId:
            return serve(conn, in, false, &Server::activateSession);
        case DataTypeInfo<CloseSessionRequest>::binaryEncodingId:
            return serve(conn, in, false, &Server::closeSession);
        // The LDS services exist only when the LDS is on (BadServiceUnsupported otherwise).
        case DataTypeInfo<RegisterServerRequest>::binaryEncodingId:
            if (discovery_) return serve(conn, in, false, &Server::registerServer);
            [[fallthrough]];
        case DataTypeInfo<RegisterServer2Request>::binaryEncodingId:
            if (discovery_) return serve(conn, in, false, &Server::registerServer2);
            [[fallthrough]];
        case DataTypeInfo<FindServersOnNetworkRequest>::binaryEncodingId:
            if (discovery_) return serve(conn, in, false, &Server::findServersOnNetwork);
            [[fallthrough]];
        default: {
            // Every request starts with a RequestHeader: echo its handle in the fault.
            UInt32 handle = 0;
            try {
                BinaryDecoder d(in.body, in.size, config_.decodeLimits);
                RequestHeader h;
                decode(d, h);
                handle = h.requestHandle;
            } catch (const DecodeError&) {
            }
            conn->sendServiceFault(in.requestId, handle, status::BadServiceUnsupported);
        }
    }
}

void Server::onConnectionClosed(const std::shared_ptr<transport::ServerConnection>&) {
    // Sessions outlive their channel until they time out, so that a client can reconnect
    // and re-activate its session on a new channel.
}

void Server::expireSessions() {
    auto now = transport::Clock::now();
    std::erase_if(sessions_, [&](const auto& kv) {
        if (!kv.second->expired(now)) return false;
        // A session that timed out leaves its subscriptions to their own lifetime, so that
        // the client can take them over from a new session (Part 4 §5.6.2).
        subscriptions_->removeSession(kv.second->sessionId, false);
        sessionClosed(kv.second->sessionId);
        return true;
    });
    updateSessionCount();
}

// ---- discovery and session services ------------------------------------------------------
void Server::getEndpoints(Ctx& ctx, const GetEndpointsRequest& req, GetEndpointsResponse& resp) {
    bool wantsTcp = req.profileUris.empty();
    for (const auto& p : req.profileUris) wantsTcp |= p == kTransportProfile;
    if (wantsTcp)
        resp.endpoints = endpointDescriptions(req.endpointUrl.empty() ? ctx.conn->endpointUrl()
                                                                      : req.endpointUrl);
}

void Server::findServers(Ctx&, const FindServersRequest& req, FindServersResponse& resp) {
    if (req.serverUris.empty() || std::find(req.serverUris.begin(), req.serverUris.end(),
                                            config_.applicationUri) != req.serverUris.end())
        resp.servers = {applicationDescription()};
    if (discovery_) discovery_->findServers(req, resp);
}

void Server::registerServer(Ctx&, const RegisterServerRequest& req, RegisterServerResponse& resp) {
    discovery_->registerServer(req, resp);
}

void Server::registerServer2(Ctx&, const RegisterServer2Request& req,
                             RegisterServer2Response& resp) {
    discovery_->registerServer2(req, resp);
}

void Server::findServersOnNetwork(Ctx&, const FindServersOnNetworkRequest& req,
                                  FindServersOnNetworkResponse& resp) {
    discovery_->findServersOnNetwork(req, resp);
}

void Server::createSession(Ctx& ctx, const CreateSessionRequest& req, CreateSessionResponse& resp) {
    if (sessions_.size() >= config_.maxSessions) {
        resp.responseHeader.serviceResult = status::BadTooManySessions;
        return;
    }
    auto s = std::make_unique<Session>(config_.limits.maxBrowseContinuationPoints);
    s->sessionId = NodeId(1, "session-" + std::to_string(nextSessionNumber_++));
    s->authenticationToken = NodeId(0, randomBytes(32));
    s->name = req.sessionName;
    Double requested = req.requestedSessionTimeout;
    if (!(requested >= config_.minSessionTimeoutMs)) requested = config_.minSessionTimeoutMs;
    s->timeoutMs = std::min(requested, config_.maxSessionTimeoutMs);
    s->lastActivity = transport::Clock::now();
    s->channelId = ctx.conn->channelId();

    resp.sessionId = s->sessionId;
    resp.authenticationToken = s->authenticationToken;
    resp.revisedSessionTimeout = s->timeoutMs;
    resp.serverNonce = randomBytes(32);
    resp.serverEndpoints =
        endpointDescriptions(req.endpointUrl.empty() ? ctx.conn->endpointUrl() : req.endpointUrl);
    resp.maxRequestMessageSize = config_.transport.maxMessageSize;
    sessions_.emplace(s->authenticationToken, std::move(s));
    updateSessionCount();
}

void Server::activateSession(Ctx& ctx, const ActivateSessionRequest& req,
                             ActivateSessionResponse& resp) {
    auto it = sessions_.find(req.requestHeader.authenticationToken);
    if (it == sessions_.end()) {
        resp.responseHeader.serviceResult = status::BadSessionIdInvalid;
        return;
    }
    Session& s = *it->second;
    SessionIdentity identity;
    StatusCode st = config_.accessControl->activateSession(req.userIdentityToken, identity);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    // Moving an activated session to another channel needs the same user (Part 4 §5.6.3.1).
    if (s.activated && s.channelId != ctx.conn->channelId() &&
        (identity.anonymous != s.identity.anonymous || identity.userName != s.identity.userName)) {
        resp.responseHeader.serviceResult = status::BadIdentityChangeNotSupported;
        return;
    }
    s.identity = identity;
    subscriptions_->setSessionUser(s.sessionId, identity);
    s.channelId = ctx.conn->channelId();
    s.activated = true;
    s.lastActivity = transport::Clock::now();
    resp.serverNonce = randomBytes(32);
}

void Server::closeSession(Ctx& ctx, const CloseSessionRequest& req, CloseSessionResponse& resp) {
    auto it = sessions_.find(req.requestHeader.authenticationToken);
    if (it == sessions_.end() || it->second->channelId != ctx.conn->channelId()) {
        resp.responseHeader.serviceResult = status::BadSessionIdInvalid;
        return;
    }
    // deleteSubscriptions false: the subscriptions live on until their lifetime expires or
    // another session of the same user transfers them (TransferSubscriptions).
    subscriptions_->removeSession(it->second->sessionId, req.deleteSubscriptions);
    const NodeId closed = it->second->sessionId;
    sessions_.erase(it);
    sessionClosed(closed);
    updateSessionCount();
}

// ---- address-space services -----------------------------------------------------------------
void Server::read(Ctx&, const ReadRequest& req, ReadResponse& resp) {
    StatusCode st = checkOperationCount(req.nodesToRead, config_.limits.maxNodesPerRead);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    resp = addressSpace_->read(req);
}

void Server::write(Ctx& ctx, const WriteRequest& req, WriteResponse& resp) {
    StatusCode st = checkOperationCount(req.nodesToWrite, config_.limits.maxNodesPerWrite);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    auto& ac = *config_.accessControl;
    const bool guarded = hasWriteGuards_.load(std::memory_order_acquire);
    std::shared_lock guards(guardsMutex_, std::defer_lock);
    if (guarded) guards.lock();
    auto check = [&](const WriteValue& w) -> StatusCode {
        if (!ac.allowWrite(ctx.session->identity, w.nodeId)) return status::BadUserAccessDenied;
        if (guarded) {
            auto g = writeGuards_.find(w.nodeId);
            if (g != writeGuards_.end()) return g->second(ctx.session->sessionId, w);
        }
        return status::Good;
    };
    bool allowedAll = true;
    for (const auto& w : req.nodesToWrite) allowedAll = allowedAll && check(w).isGood();
    if (allowedAll) {
        guards = {};
        resp = addressSpace_->write(req);
        return;
    }
    // Some items are refused: write the others one by one.
    resp.results.reserve(req.nodesToWrite.size());
    for (const auto& w : req.nodesToWrite) {
        StatusCode c = check(w);
        resp.results.push_back(c.isGood() ? addressSpace_->write(w) : c);
    }
}

void Server::setWriteGuard(const NodeId& node, WriteGuard guard) {
    std::unique_lock lock(guardsMutex_);
    if (guard)
        writeGuards_[node] = std::move(guard);
    else
        writeGuards_.erase(node);
    hasWriteGuards_.store(!writeGuards_.empty(), std::memory_order_release);
}

void Server::onSessionClosed(std::function<void(const NodeId& sessionId)> observer) {
    std::unique_lock lock(guardsMutex_);
    sessionClosedObservers_.push_back(std::move(observer));
}

void Server::sessionClosed(const NodeId& sessionId) {
    std::vector<std::function<void(const NodeId&)>> observers;
    {
        std::shared_lock lock(guardsMutex_);
        observers = sessionClosedObservers_;
    }
    for (const auto& o : observers) o(sessionId);
}

void Server::browse(Ctx& ctx, const BrowseRequest& req, BrowseResponse& resp) {
    StatusCode st = checkOperationCount(req.nodesToBrowse, config_.limits.maxNodesPerBrowse);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    resp = addressSpace_->browse(req, ctx.session->continuationPoints);
}

void Server::browseNext(Ctx& ctx, const BrowseNextRequest& req, BrowseNextResponse& resp) {
    StatusCode st = checkOperationCount(req.continuationPoints, config_.limits.maxNodesPerBrowse);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    resp = addressSpace_->browseNext(req, ctx.session->continuationPoints);
}

void Server::translate(Ctx&, const TranslateBrowsePathsToNodeIdsRequest& req,
                       TranslateBrowsePathsToNodeIdsResponse& resp) {
    StatusCode st = checkOperationCount(req.browsePaths,
                                        config_.limits.maxNodesPerTranslateBrowsePathsToNodeIds);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    resp = addressSpace_->translateBrowsePaths(req);
}

void Server::registerNodes(Ctx&, const RegisterNodesRequest& req, RegisterNodesResponse& resp) {
    StatusCode st =
        checkOperationCount(req.nodesToRegister, config_.limits.maxNodesPerRegisterNodes);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    resp = addressSpace_->registerNodes(req);
}

void Server::unregisterNodes(Ctx&, const UnregisterNodesRequest& req,
                             UnregisterNodesResponse& resp) {
    StatusCode st =
        checkOperationCount(req.nodesToUnregister, config_.limits.maxNodesPerRegisterNodes);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    resp = addressSpace_->unregisterNodes(req);
}

// Call completes asynchronously: the methods may finish later on other threads, and the
// response is sent from whichever thread completes the last one (send() is thread-safe).
void Server::call(const std::shared_ptr<transport::ServerConnection>& conn,
                  const transport::IncomingRequest& in) {
    // Decoded into a request of this thread: its method list and authentication token keep
    // their memory from one Call to the next (decode overwrites every field; the input
    // arguments, the only large part, move on to the handlers).
    thread_local CallRequest req;
    Ctx ctx{conn};
    if (!accept(conn, in, true, req, ctx)) return;
    StatusCode st = checkOperationCount(req.methodsToCall, config_.limits.maxNodesPerMethodCall);
    if (st.isBad()) {
        conn->sendServiceFault(in.requestId, req.requestHeader.requestHandle, st);
        return;
    }
    for (const auto& m : req.methodsToCall) {
        if (!config_.accessControl->allowCall(ctx.session->identity, m.methodId)) {
            conn->sendServiceFault(in.requestId, req.requestHeader.requestHandle,
                                   status::BadUserAccessDenied);
            return;
        }
    }
    auto respond = [conn, requestId = in.requestId, handle = req.requestHeader.requestHandle](
                       CallResponse resp) { sendResponse(*conn, requestId, handle, resp); };
    addressSpace_->call(std::move(req), ctx.session->sessionId, std::move(respond));
}

// Publish is answered later, by the subscription engine (a publishing cycle, a value change
// or an event), from whichever thread that happens on.
void Server::publish(const std::shared_ptr<transport::ServerConnection>& conn,
                     const transport::IncomingRequest& in) {
    PublishRequest req;
    Ctx ctx{conn};
    if (!accept(conn, in, true, req, ctx)) return;
    subscriptions_->publish(ctx.session->sessionId, conn, in.requestId, req);
}

// The other subscription services answer at once; `count` gives the operations of a request
// (bounded by maxMonitoredItemsPerCall).
template <class Req, class Resp>
void Server::serveSubscriptions(const std::shared_ptr<transport::ServerConnection>& conn,
                                const transport::IncomingRequest& in,
                                void (SubscriptionEngine::*handler)(const NodeId&, const Req&,
                                                                    Resp&),
                                std::size_t (*count)(const Req&)) {
    Req req;
    Ctx ctx{conn};
    if (!accept(conn, in, true, req, ctx)) return;
    Resp resp;
    std::size_t n = count(req);
    if (n == 0)
        resp.responseHeader.serviceResult = status::BadNothingToDo;
    else if (n > config_.subscriptionLimits.maxMonitoredItemsPerCall)
        resp.responseHeader.serviceResult = status::BadTooManyOperations;
    else {
        try {
            (subscriptions_.get()->*handler)(ctx.session->sessionId, req, resp);
        } catch (const std::exception&) {
            resp = Resp{};
            resp.responseHeader.serviceResult = status::BadInternalError;
        }
    }
    sendResponse(*conn, in.requestId, req.requestHeader.requestHandle, resp);
}

}  // namespace pnp::ua::server
