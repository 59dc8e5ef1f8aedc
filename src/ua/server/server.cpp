#include "ua/server/server.hpp"

#include <unistd.h>

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <random>
#include <thread>

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

// Session ids, authentication tokens and nonces must not be guessable: from the system's
// cryptographic random source.
ByteString randomBytes(std::size_t n) {
    const auto bytes = crypto::randomBytes(n);
    return ByteString(bytes.data(), bytes.size());
}

crypto::ByteView bytesOf(const ByteString& b) { return {b.data(), b.size()}; }

// The bytes a session signature covers: a certificate followed by a nonce.
crypto::Bytes certificateAndNonce(crypto::ByteView certificate, crypto::ByteView nonce) {
    crypto::Bytes data(certificate.begin(), certificate.end());
    data.insert(data.end(), nonce.begin(), nonce.end());
    return data;
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
    ByteString serverNonce;                             // the last one sent (signatures, passwords)
    std::optional<pki::Certificate> clientCertificate;  // of a secured session
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
    if (config_.security) {
        auto& sec = *config_.security;
        if (sec.policies.empty())
            for (const auto& p : crypto::securityPolicies()) sec.policies.push_back(&p);
        auto channel = std::make_shared<transport::ServerSecurityConfig>();
        channel->identity = sec.identity;
        channel->policies = sec.policies;
        if (auto trust = sec.trust) {
            channel->validateClient =
                [trust, refused = sec.onClientRefused](const std::vector<pki::Certificate>& chain) {
                    const StatusCode st = trust->validate(chain, pki::ValidationOptions{});
                    if (st.isBad() && refused && !chain.empty()) refused(chain.front(), st);
                    return st;
                };
        }
        config_.transport.security = std::move(channel);
    }
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
    // After the network threads (which start it): joined; logins still queued are dropped,
    // an answer of one that was running is posted to the stopped transport and never runs.
    authWorker_.reset();
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
    EndpointDescription base;
    // Answer with the address the client used when it is ours (it reached us that way).
    base.endpointUrl = url.starts_with("opc.tcp://") ? url : endpointUrl();
    base.server = applicationDescription();
    base.transportProfileUri = kTransportProfile;
    std::vector<EndpointDescription> out;
    auto add = [&](std::string_view policyUri, MessageSecurityMode mode, Byte level) {
        EndpointDescription e = base;
        e.securityMode = mode;
        e.securityPolicyUri = std::string(policyUri);
        e.userIdentityTokens = config_.accessControl->userTokenPolicies(policyUri, mode);
        e.securityLevel = level;
        if (config_.security)
            e.serverCertificate = ByteString(config_.security->identity.certificate.der().data(),
                                             config_.security->identity.certificate.der().size());
        out.push_back(std::move(e));
    };
    if (!config_.security) {
        add(kSecurityPolicyNone, MessageSecurityMode::None, 0);
        return out;
    }
    // SecurityLevel: SignAndEncrypt above Sign, then the policies in their order (most secure
    // first), so a client that takes the highest level gets the strongest protection.
    const auto& policies = config_.security->policies;
    for (std::size_t i = 0; i < policies.size(); ++i) {
        const auto rank = static_cast<Byte>(policies.size() - i);
        add(policies[i]->uri, MessageSecurityMode::SignAndEncrypt, static_cast<Byte>(100 + rank));
        if (config_.security->offerSign)
            add(policies[i]->uri, MessageSecurityMode::Sign, static_cast<Byte>(50 + rank));
    }
    if (config_.security->offerNone) add(kSecurityPolicyNone, MessageSecurityMode::None, 0);
    return out;
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
            return activate(conn, in);
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

namespace {
RegistrationChannel registrationChannel(const transport::ServerConnection& conn) {
    RegistrationChannel c;
    if (const transport::ChannelSecurity* sec = conn.security();
        sec && sec->mode() != MessageSecurityMode::None) {
        c.secured = true;
        c.certificateUris = sec->remoteCertificate().uris();
    }
    return c;
}
}  // namespace

void Server::registerServer(Ctx& ctx, const RegisterServerRequest& req,
                            RegisterServerResponse& resp) {
    discovery_->registerServer(req, resp, registrationChannel(*ctx.conn));
}

void Server::registerServer2(Ctx& ctx, const RegisterServer2Request& req,
                             RegisterServer2Response& resp) {
    discovery_->registerServer2(req, resp, registrationChannel(*ctx.conn));
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
    const transport::ChannelSecurity* channel = ctx.conn->security();
    if (!channel && config_.security && !config_.security->offerNone) {
        // A None channel of a secured server serves discovery only.
        resp.responseHeader.serviceResult = status::BadSecurityPolicyRejected;
        return;
    }
    std::optional<pki::Certificate> clientCertificate;
    if (channel) {
        // The session belongs to the application that opened the channel (Part 4 §5.6.2):
        // the same certificate, whose URI is the ApplicationUri it claims.
        const auto& der = channel->remoteCertificate().der();
        if (req.clientCertificate.size() < der.size() ||
            !std::equal(der.begin(), der.end(), req.clientCertificate.data())) {
            resp.responseHeader.serviceResult = status::BadSecurityChecksFailed;
            return;
        }
        const auto uris = channel->remoteCertificate().uris();
        if (std::find(uris.begin(), uris.end(), req.clientDescription.applicationUri) ==
            uris.end()) {
            resp.responseHeader.serviceResult = status::BadCertificateUriInvalid;
            return;
        }
        if (req.clientNonce.size() < 32) {
            resp.responseHeader.serviceResult = status::BadNonceInvalid;
            return;
        }
        clientCertificate = channel->remoteCertificate();
    }
    auto s = std::make_unique<Session>(config_.limits.maxBrowseContinuationPoints);
    s->clientCertificate = std::move(clientCertificate);
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
    s->serverNonce = resp.serverNonce;
    resp.serverEndpoints =
        endpointDescriptions(req.endpointUrl.empty() ? ctx.conn->endpointUrl() : req.endpointUrl);
    if (channel) {
        // Proof that we hold the key of our certificate: sign(clientCertificate + clientNonce).
        const auto& own = channel->ownIdentity();
        resp.serverCertificate =
            ByteString(own.certificate.der().data(), own.certificate.der().size());
        resp.serverSignature.algorithm = std::string(channel->policy().asymmetricSignatureUri);
        const auto sig = crypto::sign(
            own.key, channel->policy().asymmetricSignature,
            certificateAndNonce(bytesOf(req.clientCertificate), bytesOf(req.clientNonce)));
        resp.serverSignature.signature = ByteString(sig.data(), sig.size());
    }
    resp.maxRequestMessageSize = config_.transport.maxMessageSize;
    sessions_.emplace(s->authenticationToken, std::move(s));
    updateSessionCount();
}

// One thread for the identity checks that take long (a password's PBKDF2 hash), so that no
// other client waits for them; a bounded queue (logins beyond it are refused at once).
class Server::AuthWorker {
  public:
    static constexpr std::size_t kMaxQueued = 64;
    AuthWorker() : thread_([this] { run(); }) {}
    ~AuthWorker() {
        {
            std::lock_guard lock(mutex_);
            stop_ = true;
        }
        cv_.notify_one();
        thread_.join();
    }
    bool push(std::function<void()> task) {
        {
            std::lock_guard lock(mutex_);
            if (stop_ || queue_.size() >= kMaxQueued) return false;
            queue_.push_back(std::move(task));
            ++unfinished_;
        }
        cv_.notify_one();
        return true;
    }
    // No check queued or running (their answers are post()ed by then).
    bool idle() {
        std::lock_guard lock(mutex_);
        return unfinished_ == 0;
    }

  private:
    void run() {
        for (;;) {
            std::function<void()> task;
            {
                std::unique_lock lock(mutex_);
                cv_.wait(lock, [this] { return stop_ || !queue_.empty(); });
                if (stop_) return;  // pending logins are dropped: the server is stopping
                task = std::move(queue_.front());
                queue_.pop_front();
            }
            task();
            std::lock_guard lock(mutex_);
            --unfinished_;
        }
    }
    std::mutex mutex_;
    std::condition_variable cv_;
    std::deque<std::function<void()>> queue_;
    std::size_t unfinished_ = 0;
    bool stop_ = false;
    std::thread thread_;
};

bool Server::runPostedWork(std::chrono::steady_clock::time_point deadline) {
    if (transport_->running()) return false;
    for (;;) {
        const bool idle = !authWorker_ || authWorker_->idle();
        const std::size_t ran = transport_->runPosted();
        if (idle && ran == 0) return true;
        if (std::chrono::steady_clock::now() >= deadline) return false;
        if (ran == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
}

Server::Session* Server::checkActivation(Ctx& ctx, const ActivateSessionRequest& req,
                                         ActivateSessionResponse& resp,
                                         ActivationContext& context) {
    auto it = sessions_.find(req.requestHeader.authenticationToken);
    if (it == sessions_.end()) {
        resp.responseHeader.serviceResult = status::BadSessionIdInvalid;
        return nullptr;
    }
    Session& s = *it->second;
    const transport::ChannelSecurity* channel = ctx.conn->security();
    if (s.clientCertificate) {
        // A secured session stays with its application: a channel with the same certificate,
        // and the client's proof that it holds the key: sign(serverCertificate + serverNonce).
        if (!channel || !(channel->remoteCertificate() == *s.clientCertificate)) {
            resp.responseHeader.serviceResult = status::BadSecurityChecksFailed;
            return nullptr;
        }
        const auto& own = channel->ownIdentity().certificate.der();
        const bool valid =
            req.clientSignature.algorithm == channel->policy().asymmetricSignatureUri &&
            crypto::verify(s.clientCertificate->publicKey(), channel->policy().asymmetricSignature,
                           certificateAndNonce(own, bytesOf(s.serverNonce)),
                           bytesOf(req.clientSignature.signature));
        if (!valid) {
            resp.responseHeader.serviceResult = status::BadApplicationSignatureInvalid;
            return nullptr;
        }
    } else if (channel) {
        // A session created without security cannot be taken over by a secured channel.
        resp.responseHeader.serviceResult = status::BadSecurityChecksFailed;
        return nullptr;
    }
    context.channelPolicyUri =
        channel ? channel->policy().uri : std::string_view(kSecurityPolicyNone);
    context.channelMode = channel ? channel->mode() : MessageSecurityMode::None;
    if (channel) {
        context.serverKey = &channel->ownIdentity().key;
        context.serverCertificate = channel->ownIdentity().certificate.der();
    } else if (config_.security) {
        context.serverKey = &config_.security->identity.key;
        context.serverCertificate = config_.security->identity.certificate.der();
    }
    context.serverNonce = bytesOf(s.serverNonce);
    context.userTokenSignature = &req.userTokenSignature;
    return &s;
}

void Server::completeActivation(const transport::ServerConnection& conn, Session& s,
                                const SessionIdentity& identity, ActivateSessionResponse& resp) {
    // Moving an activated session to another channel needs the same user (Part 4 §5.6.3.1).
    if (s.activated && s.channelId != conn.channelId() &&
        (identity.anonymous != s.identity.anonymous || identity.userName != s.identity.userName)) {
        resp.responseHeader.serviceResult = status::BadIdentityChangeNotSupported;
        return;
    }
    s.identity = identity;
    subscriptions_->setSessionUser(s.sessionId, identity);
    s.channelId = conn.channelId();
    s.activated = true;
    s.lastActivity = transport::Clock::now();
    resp.serverNonce = randomBytes(32);
    s.serverNonce = resp.serverNonce;
}

void Server::activate(const std::shared_ptr<transport::ServerConnection>& conn,
                      const transport::IncomingRequest& in) {
    ActivateSessionRequest req;
    Ctx ctx{conn};
    if (!accept(conn, in, false, req, ctx)) return;
    const UInt32 handle = req.requestHeader.requestHandle;
    ActivateSessionResponse resp;
    ActivationContext context;
    Session* s = checkActivation(ctx, req, resp, context);
    const bool encrypted =
        conn->security() && conn->security()->mode() == MessageSecurityMode::SignAndEncrypt;
    const bool password = req.userIdentityToken.typeId ==
                          NodeId(0, DataTypeInfo<UserNameIdentityToken>::binaryEncodingId);
    if (s && !password) {
        SessionIdentity identity;
        const StatusCode st =
            config_.accessControl->activateSession(req.userIdentityToken, context, identity);
        identity.encryptedChannel = encrypted;
        if (st.isBad())
            resp.responseHeader.serviceResult = st;
        else
            completeActivation(*conn, *s, identity, resp);
    }
    if (!s || !password) {
        sendResponse(*conn, in.requestId, handle, resp);
        return;
    }
    // The password is checked on the auth worker with copies of what the context points to;
    // the session is looked up again when the answer is back on the network thread (it may
    // have been closed meanwhile).
    if (!authWorker_) authWorker_ = std::make_unique<AuthWorker>();
    auto task =
        [this, conn, requestId = in.requestId, handle, encrypted, token = req.userIdentityToken,
         signature = req.userTokenSignature, authToken = req.requestHeader.authenticationToken,
         policy = std::string(context.channelPolicyUri), mode = context.channelMode,
         nonce = s->serverNonce,
         // A copy: Part 12 ApplyChanges may replace the identity meanwhile.
         own = conn->security()   ? std::optional<pki::Identity>(conn->security()->ownIdentity())
               : config_.security ? std::optional<pki::Identity>(config_.security->identity)
                                  : std::nullopt]() {
            ActivationContext c;
            c.channelPolicyUri = policy;
            c.channelMode = mode;
            if (own) {
                c.serverKey = &own->key;
                c.serverCertificate = own->certificate.der();
            }
            c.serverNonce = bytesOf(nonce);
            c.userTokenSignature = &signature;
            SessionIdentity identity;
            StatusCode st;
            try {
                st = config_.accessControl->activateSession(token, c, identity);
            } catch (const std::exception&) {
                st = status::BadInternalError;
            }
            identity.encryptedChannel = encrypted;
            post([this, conn, requestId, handle, authToken, st, identity = std::move(identity)] {
                if (conn->isClosed()) return;
                ActivateSessionResponse r;
                auto it = sessions_.find(authToken);
                if (it == sessions_.end())
                    r.responseHeader.serviceResult = status::BadSessionIdInvalid;
                else if (st.isBad())
                    r.responseHeader.serviceResult = st;
                else
                    completeActivation(*conn, *it->second, identity, r);
                sendResponse(*conn, requestId, handle, r);
            });
        };
    if (!authWorker_->push(std::move(task)))
        conn->sendServiceFault(in.requestId, handle, status::BadResourceUnavailable);
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
void Server::read(Ctx& ctx, const ReadRequest& req, ReadResponse& resp) {
    StatusCode st = checkOperationCount(req.nodesToRead, config_.limits.maxNodesPerRead);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    resp = addressSpace_->read(req, &ctx.session->identity);
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
        resp = addressSpace_->write(req, &ctx.session->identity);
        return;
    }
    // Some items are refused: write the others one by one.
    resp.results.reserve(req.nodesToWrite.size());
    for (const auto& w : req.nodesToWrite) {
        StatusCode c = check(w);
        resp.results.push_back(c.isGood() ? addressSpace_->write(w, &ctx.session->identity) : c);
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
    resp = addressSpace_->browse(req, ctx.session->continuationPoints, &ctx.session->identity);
}

void Server::browseNext(Ctx& ctx, const BrowseNextRequest& req, BrowseNextResponse& resp) {
    StatusCode st = checkOperationCount(req.continuationPoints, config_.limits.maxNodesPerBrowse);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    resp = addressSpace_->browseNext(req, ctx.session->continuationPoints, &ctx.session->identity);
}

void Server::translate(Ctx& ctx, const TranslateBrowsePathsToNodeIdsRequest& req,
                       TranslateBrowsePathsToNodeIdsResponse& resp) {
    StatusCode st = checkOperationCount(req.browsePaths,
                                        config_.limits.maxNodesPerTranslateBrowsePathsToNodeIds);
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    resp = addressSpace_->translateBrowsePaths(req, &ctx.session->identity);
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
    addressSpace_->call(std::move(req), ctx.session->sessionId, std::move(respond),
                        &ctx.session->identity);
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

// The transport's channel configuration was made from config_.security at construction and
// is shared by every channel, which reads it only under the network lock (an OpenSecureChannel
// Issue): changed there, it applies to the channels opened next; an open channel has its own
// copy of the identity.
void Server::setSecurityIdentity(pki::Identity identity) {
    if (!config_.security || !config_.transport.security)
        throw std::logic_error("setSecurityIdentity: the server has no security");
    post([this, identity = std::move(identity)] {
        config_.security->identity = identity;
        std::const_pointer_cast<transport::ServerSecurityConfig>(config_.transport.security)
            ->identity = identity;
    });
}

}  // namespace pnp::ua::server
