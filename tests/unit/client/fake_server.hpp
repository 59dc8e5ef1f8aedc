// A scripted OPC UA server for the client's unit tests: the real transport (TcpServer) with
// a tiny service layer (sessions, Read/Write of an in-memory map, Call "Add", Browse with
// continuation points, TranslateBrowsePaths, RegisterNodes) and hooks that let a test
// delay, drop, fault or swallow individual requests.
#pragma once

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "support/loopback.hpp"
#include "ua/transport/tcp_server.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::testing {

class FakeServer : public transport::ServiceHandler {
  public:
    // One received request, as a hook sees it.
    struct Request {
        std::shared_ptr<transport::ServerConnection> conn;
        UInt32 requestId = 0;
        UInt32 typeId = 0;  // binary encoding id
        RequestHeader header;
        std::vector<Byte> body;  // after the type NodeId (header included)

        template <class T>
        T decodeAs() const {
            return decodeFromBuffer<T>(body.data(), body.size(), false);
        }
        template <class T>
        bool is() const {
            return typeId == DataTypeInfo<T>::binaryEncodingId;
        }
    };

    // Returns true when it handled the request (responded, or chose not to).
    using Hook = std::function<bool(const Request&)>;

    static constexpr const char* kAnonymousPolicy = "anon-policy";
    static constexpr const char* kUserPolicy = "user-policy";

    FakeServer() {
        transport::ServerTransportConfig cfg;
        cfg.host = "127.0.0.1";
        cfg.port = 0;
        server_ = std::make_unique<transport::TcpServer>(cfg, *this);
        server_->start();
        values_[NodeId(1, "Int32")] = Variant(Int32{7});
        values_[NodeId(0, 2255)] =
            Variant(std::vector<String>{"http://opcfoundation.org/UA/", "urn:fake:demo"});
        values_[NodeId(0, 2258)] = Variant(DateTime::now());
    }
    ~FakeServer() override {
        server_->stop();
        std::vector<std::thread> ts;
        {
            std::lock_guard lock(mutex_);
            ts.swap(threads_);
        }
        for (auto& t : ts) t.join();
    }

    std::string url() const { return pnp::testing::url(server_->port()); }
    UInt16 port() const { return server_->port(); }

    void setHook(Hook h) {
        std::lock_guard lock(mutex_);
        hook_ = std::move(h);
    }
    // The first request of type Req closes its connection instead of being answered.
    template <class Req>
    void dropFirst() {
        auto dropped = std::make_shared<std::atomic<bool>>(false);
        setHook([dropped](const Request& r) {
            if (!r.is<Req>() || dropped->exchange(true)) return false;
            r.conn->close();
            return true;
        });
    }
    void setValue(const NodeId& id, Variant v) {
        std::lock_guard lock(mutex_);
        values_[id] = std::move(v);
    }
    Variant value(const NodeId& id) {
        std::lock_guard lock(mutex_);
        return values_[id];
    }
    // The server "restarts" its session layer: every session is forgotten.
    void forgetSessions() {
        std::lock_guard lock(mutex_);
        sessions_.clear();
    }
    // Closes every open connection (the server side drops the client).
    void dropConnections() {
        std::vector<std::shared_ptr<transport::ServerConnection>> cs;
        {
            std::lock_guard lock(mutex_);
            cs = connections_;
        }
        for (auto& c : cs) c->close();
    }
    void setBrowseReferences(std::size_t n) {
        std::lock_guard lock(mutex_);
        browseRefs_ = n;
    }

    // Connections that sent a request so far (closed ones included).
    std::size_t connectionsSeen() {
        std::lock_guard lock(mutex_);
        return connectionsSeen_;
    }

    // Counters by request encoding id.
    std::size_t count(UInt32 typeId) {
        std::lock_guard lock(mutex_);
        auto it = counts_.find(typeId);
        return it == counts_.end() ? 0 : it->second;
    }
    template <class T>
    std::size_t count() {
        return count(DataTypeInfo<T>::binaryEncodingId);
    }
    std::vector<NodeId> activatedTokens() {
        std::lock_guard lock(mutex_);
        return activatedTokens_;
    }
    std::vector<Request> received() {
        std::lock_guard lock(mutex_);
        return received_;
    }
    std::size_t readsOf(const NodeId& id) {
        std::lock_guard lock(mutex_);
        auto it = readsOf_.find(id);
        return it == readsOf_.end() ? 0 : it->second;
    }

    // ---- response helpers (any thread) -------------------------------------------------
    template <class Resp>
    static void respond(const Request& r, Resp resp) {
        resp.responseHeader.requestHandle = r.header.requestHandle;
        resp.responseHeader.timestamp = DateTime::now();
        Buffer b = transport::ServerConnection::newMessageBuffer();
        BinaryEncoder e(b);
        encode(e, NodeId(0, DataTypeInfo<Resp>::binaryEncodingId));
        encode(e, resp);
        r.conn->send(r.requestId, std::move(b));
    }
    static void fault(const Request& r, StatusCode s) {
        r.conn->sendServiceFault(r.requestId, r.header.requestHandle, s);
    }
    // Runs fn(request) after `delay` on another thread.
    void later(const Request& r, std::chrono::milliseconds delay,
               std::function<void(const Request&)> fn) {
        std::lock_guard lock(mutex_);
        threads_.emplace_back([r, delay, fn = std::move(fn)] {
            std::this_thread::sleep_for(delay);
            fn(r);
        });
    }
    // The default handling of a request (a hook may call it to respond normally later).
    void handleDefault(const Request& r);

    // ---- ServiceHandler ------------------------------------------------------------------
    void onRequest(const std::shared_ptr<transport::ServerConnection>& conn,
                   const transport::IncomingRequest& in) override {
        Request r;
        r.conn = conn;
        r.requestId = in.requestId;
        r.typeId = in.typeId.isNumeric() ? in.typeId.numeric() : 0;
        r.body.assign(in.body, in.body + in.size);
        try {
            r.header = decodeFromBuffer<RequestHeader>(in.body, in.size, false);
        } catch (const DecodeError&) {
        }
        Hook hook;
        {
            std::lock_guard lock(mutex_);
            ++counts_[r.typeId];
            received_.push_back(r);
            if (std::find(connections_.begin(), connections_.end(), conn) == connections_.end()) {
                connections_.push_back(conn);
                ++connectionsSeen_;
            }
            hook = hook_;
        }
        if (hook && hook(r)) return;
        handleDefault(r);
    }
    void onConnectionClosed(const std::shared_ptr<transport::ServerConnection>& conn) override {
        std::lock_guard lock(mutex_);
        std::erase(connections_, conn);
    }

  private:
    struct Session {
        NodeId id;
        bool active = false;
    };

    bool sessionOk(const Request& r) {
        std::lock_guard lock(mutex_);
        auto it = sessions_.find(r.header.authenticationToken);
        return it != sessions_.end() && it->second.active;
    }

    std::unique_ptr<transport::TcpServer> server_;
    std::mutex mutex_;
    Hook hook_;
    std::map<NodeId, Variant> values_;
    std::map<NodeId, Session> sessions_;  // by authentication token
    UInt32 nextSession_ = 1;
    std::map<UInt32, std::size_t> counts_;
    std::map<NodeId, std::size_t> readsOf_;
    std::vector<NodeId> activatedTokens_;
    std::vector<Request> received_;
    std::vector<std::shared_ptr<transport::ServerConnection>> connections_;
    std::size_t connectionsSeen_ = 0;
    std::vector<std::thread> threads_;
    std::size_t browseRefs_ = 5;
};

inline void FakeServer::handleDefault(const Request& r) {
    namespace st = status;
    if (r.is<GetEndpointsRequest>()) {
        auto req = r.decodeAs<GetEndpointsRequest>();
        GetEndpointsResponse resp{};
        EndpointDescription ep{};
        ep.endpointUrl = req.endpointUrl;
        ep.securityMode = MessageSecurityMode::None;
        ep.securityPolicyUri = "http://opcfoundation.org/UA/SecurityPolicy#None";
        ep.server.applicationUri = "urn:fake:server";
        resp.endpoints.push_back(ep);
        respond(r, std::move(resp));
    } else if (r.is<FindServersRequest>()) {
        FindServersResponse resp{};
        ApplicationDescription a{};
        a.applicationUri = "urn:fake:server";
        a.applicationType = ApplicationType::Server;
        resp.servers.push_back(a);
        respond(r, std::move(resp));
    } else if (r.is<CreateSessionRequest>()) {
        auto req = r.decodeAs<CreateSessionRequest>();
        CreateSessionResponse resp{};
        {
            std::lock_guard lock(mutex_);
            UInt32 n = nextSession_++;
            resp.sessionId = NodeId(1, 1000 + n);
            resp.authenticationToken = NodeId(1, ByteString("token-" + std::to_string(n)));
            sessions_[resp.authenticationToken] = Session{resp.sessionId, false};
        }
        resp.revisedSessionTimeout = req.requestedSessionTimeout;
        resp.serverNonce = ByteString(std::string(32, 'n'));
        EndpointDescription ep{};
        ep.endpointUrl = req.endpointUrl;
        ep.securityMode = MessageSecurityMode::None;
        ep.securityPolicyUri = "http://opcfoundation.org/UA/SecurityPolicy#None";
        UserTokenPolicy anon{};
        anon.policyId = kAnonymousPolicy;
        anon.tokenType = UserTokenType::Anonymous;
        UserTokenPolicy user{};
        user.policyId = kUserPolicy;
        user.tokenType = UserTokenType::UserName;
        ep.userIdentityTokens = {anon, user};
        resp.serverEndpoints.push_back(ep);
        respond(r, std::move(resp));
    } else if (r.is<ActivateSessionRequest>()) {
        auto req = r.decodeAs<ActivateSessionRequest>();
        StatusCode s;
        if (auto a = fromExtensionObject<AnonymousIdentityToken>(req.userIdentityToken)) {
            if (a->policyId != kAnonymousPolicy) s = st::BadIdentityTokenInvalid;
        } else if (auto u = fromExtensionObject<UserNameIdentityToken>(req.userIdentityToken)) {
            if (u->policyId != kUserPolicy)
                s = st::BadIdentityTokenInvalid;
            else if (u->userName != "operator" || u->password.view() != "secret")
                s = st::BadUserAccessDenied;
        } else {
            s = st::BadIdentityTokenInvalid;
        }
        if (!s.isBad()) {
            std::lock_guard lock(mutex_);
            auto it = sessions_.find(r.header.authenticationToken);
            if (it == sessions_.end()) {
                s = st::BadSessionIdInvalid;
            } else {
                it->second.active = true;
                activatedTokens_.push_back(r.header.authenticationToken);
            }
        }
        if (s.isBad()) return fault(r, s);
        ActivateSessionResponse resp{};
        resp.serverNonce = ByteString(std::string(32, 'm'));
        respond(r, std::move(resp));
    } else if (!sessionOk(r)) {
        fault(r, st::BadSessionIdInvalid);
    } else if (r.is<CloseSessionRequest>()) {
        {
            std::lock_guard lock(mutex_);
            sessions_.erase(r.header.authenticationToken);
        }
        respond(r, CloseSessionResponse{});
    } else if (r.is<ReadRequest>()) {
        auto req = r.decodeAs<ReadRequest>();
        ReadResponse resp{};
        std::lock_guard lock(mutex_);
        for (const auto& n : req.nodesToRead) {
            ++readsOf_[n.nodeId];
            DataValue dv;
            auto it = values_.find(n.nodeId);
            if (it == values_.end())
                dv.status = st::BadNodeIdUnknown;
            else if (n.attributeId != 13)
                dv.status = st::BadAttributeIdInvalid;
            else
                dv.value = it->second;
            resp.results.push_back(std::move(dv));
        }
        respond(r, std::move(resp));
    } else if (r.is<WriteRequest>()) {
        auto req = r.decodeAs<WriteRequest>();
        WriteResponse resp{};
        std::lock_guard lock(mutex_);
        for (const auto& w : req.nodesToWrite) {
            auto it = values_.find(w.nodeId);
            if (it == values_.end()) {
                resp.results.push_back(st::BadNodeIdUnknown);
            } else {
                it->second = w.value.value.value_or(Variant());
                resp.results.push_back(StatusCode{});
            }
        }
        respond(r, std::move(resp));
    } else if (r.is<CallRequest>()) {
        auto req = r.decodeAs<CallRequest>();
        CallResponse resp{};
        for (const auto& m : req.methodsToCall) {
            CallMethodResult res{};
            if (m.methodId != NodeId(1, "Add")) {
                res.statusCode = st::BadMethodInvalid;
            } else if (m.inputArguments.size() != 2 || !m.inputArguments[0].scalar<Int32>() ||
                       !m.inputArguments[1].scalar<Int32>()) {
                res.statusCode = st::BadInvalidArgument;
                for (const auto& a : m.inputArguments)
                    res.inputArgumentResults.push_back(a.scalar<Int32>() ? StatusCode{}
                                                                         : st::BadTypeMismatch);
            } else {
                res.outputArguments.push_back(Variant(Int32(*m.inputArguments[0].scalar<Int32>() +
                                                            *m.inputArguments[1].scalar<Int32>())));
            }
            resp.results.push_back(std::move(res));
        }
        respond(r, std::move(resp));
    } else if (r.is<BrowseRequest>() || r.is<BrowseNextRequest>()) {
        // Node i=85 has browseRefs_ references "Ref0".."RefN"; the continuation point is
        // the index of the next one.
        std::size_t total;
        {
            std::lock_guard lock(mutex_);
            total = browseRefs_;
        }
        auto page = [&](std::size_t from, std::size_t max) {
            BrowseResult br{};
            std::size_t to = max == 0 ? total : std::min(total, from + max);
            for (std::size_t i = from; i < to; ++i) {
                ReferenceDescription rd{};
                rd.referenceTypeId = NodeId(0, 35);
                rd.isForward = true;
                rd.nodeId = ExpandedNodeId(NodeId(1, static_cast<UInt32>(i)));
                rd.browseName = QualifiedName{1, "Ref" + std::to_string(i)};
                br.references.push_back(std::move(rd));
            }
            if (to < total)
                br.continuationPoint = ByteString(std::to_string(to) + "|" + std::to_string(max));
            return br;
        };
        if (r.is<BrowseRequest>()) {
            auto req = r.decodeAs<BrowseRequest>();
            BrowseResponse resp{};
            for (const auto& d : req.nodesToBrowse) {
                if (d.nodeId != NodeId(0, 85)) {
                    BrowseResult br{};
                    br.statusCode = st::BadNodeIdUnknown;
                    resp.results.push_back(br);
                } else {
                    resp.results.push_back(page(0, req.requestedMaxReferencesPerNode));
                }
            }
            respond(r, std::move(resp));
        } else {
            auto req = r.decodeAs<BrowseNextRequest>();
            BrowseNextResponse resp{};
            for (const auto& cp : req.continuationPoints) {
                auto bar = cp.view().find('|');
                std::size_t from = std::stoul(std::string(cp.view().substr(0, bar)));
                std::size_t max = std::stoul(std::string(cp.view().substr(bar + 1)));
                resp.results.push_back(req.releaseContinuationPoints ? BrowseResult{}
                                                                     : page(from, max));
            }
            respond(r, std::move(resp));
        }
    } else if (r.is<TranslateBrowsePathsToNodeIdsRequest>()) {
        auto req = r.decodeAs<TranslateBrowsePathsToNodeIdsRequest>();
        TranslateBrowsePathsToNodeIdsResponse resp{};
        for (const auto& p : req.browsePaths) {
            BrowsePathResult res{};
            std::string joined;
            for (const auto& e : p.relativePath.elements) joined += "/" + e.targetName.toString();
            if (p.startingNode == NodeId(0, 84) && joined == "/Objects/Server/ServerStatus") {
                BrowsePathTarget t{};
                t.targetId = ExpandedNodeId(NodeId(0, 2256));
                t.remainingPathIndex = 0xFFFFFFFFu;
                res.targets.push_back(t);
            } else {
                res.statusCode = st::BadNoMatch;
            }
            resp.results.push_back(std::move(res));
        }
        respond(r, std::move(resp));
    } else if (r.is<RegisterNodesRequest>()) {
        auto req = r.decodeAs<RegisterNodesRequest>();
        RegisterNodesResponse resp{};
        resp.registeredNodeIds = req.nodesToRegister;
        respond(r, std::move(resp));
    } else if (r.is<UnregisterNodesRequest>()) {
        respond(r, UnregisterNodesResponse{});
    } else {
        fault(r, st::BadServiceUnsupported);
    }
}

}  // namespace pnp::ua::testing
