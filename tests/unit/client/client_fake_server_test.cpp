// The client against the scripted FakeServer: sessions, services, error mapping, deadlines,
// reconnect, asynchronous calls, the background thread.
#include <gtest/gtest.h>
#include <sys/socket.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <future>
#include <thread>

#include "fake_server.hpp"
#include "support/loopback.hpp"
#include "support/wait.hpp"
#include "ua/client/client.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::client {
namespace {

using namespace std::chrono_literals;
using pnp::testing::errorOf;
using testing::FakeServer;

using pnp::testing::waitUntil;

const NodeId kInt32(1, "Int32");

class ClientFake : public ::testing::Test {
  protected:
    FakeServer server;
};

TEST_F(ClientFake, ConnectAnonymousReadWrite) {
    Client c;
    c.connect(server.url());
    EXPECT_TRUE(c.isConnected());
    EXPECT_TRUE(c.isChannelOpen());
    EXPECT_GE(c.nativeHandle(), 0);
    EXPECT_EQ(c.sessionId(), NodeId(1, 1001));
    EXPECT_EQ(c.sessionTimeout(), 60000.0);
    EXPECT_EQ(c.endpointUrl(), server.url());
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    EXPECT_EQ(c.writeValue(kInt32, Int32{42}), StatusCode{});
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{42}));
    EXPECT_EQ(server.value(kInt32), Variant(Int32{42}));
    // Exactly: CreateSession, ActivateSession, then the calls; nothing else was read.
    EXPECT_EQ(server.count<CreateSessionRequest>(), 1u);
    EXPECT_EQ(server.count<ActivateSessionRequest>(), 1u);
    EXPECT_EQ(server.count<ReadRequest>(), 2u);
    EXPECT_EQ(server.count<GetEndpointsRequest>(), 0u);
    auto stats = c.stats();
    EXPECT_EQ(stats.sessionsCreated, 1u);
    EXPECT_EQ(stats.reconnects, 0u);
}

TEST_F(ClientFake, RequestHeaderIsFilled) {
    ClientConfig cfg;
    cfg.requestTimeout = 4s;
    Client c(cfg);
    c.connect(server.url());
    c.readValue(kInt32);
    c.readValue(kInt32, 1500ms);
    auto rs = server.received();
    ASSERT_EQ(rs.size(), 4u);
    NodeId token = rs[1].header.authenticationToken;  // ActivateSession
    EXPECT_FALSE(token.isNull());
    EXPECT_TRUE(rs[0].header.authenticationToken.isNull());  // CreateSession
    EXPECT_EQ(rs[2].header.authenticationToken, token);
    EXPECT_EQ(rs[3].header.authenticationToken, token);
    EXPECT_LT(rs[2].header.requestHandle, rs[3].header.requestHandle);
    EXPECT_GT(rs[2].header.timeoutHint, 3900u);
    EXPECT_LE(rs[2].header.timeoutHint, 4000u);
    EXPECT_GT(rs[3].header.timeoutHint, 1400u);
    EXPECT_LE(rs[3].header.timeoutHint, 1500u);
    EXPECT_GT(rs[3].header.timestamp.ticks, 0);
    // The application description.
    auto cs = rs[0].decodeAs<CreateSessionRequest>();
    EXPECT_EQ(cs.clientDescription.applicationUri, cfg.applicationUri);
    EXPECT_EQ(cs.clientDescription.applicationType, ApplicationType::Client);
    EXPECT_EQ(cs.endpointUrl, server.url());
    EXPECT_EQ(cs.clientNonce.size(), 32u);
    EXPECT_EQ(cs.requestedSessionTimeout, 60000.0);
    auto as = rs[1].decodeAs<ActivateSessionRequest>();
    auto anon = fromExtensionObject<AnonymousIdentityToken>(as.userIdentityToken);
    ASSERT_TRUE(anon);
    EXPECT_EQ(anon->policyId, FakeServer::kAnonymousPolicy);
}

TEST_F(ClientFake, UserNameIdentity) {
    Client c;
    c.connect(server.url(), UserName{"operator", "secret"});
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    auto as = server.received()[1].decodeAs<ActivateSessionRequest>();
    auto u = fromExtensionObject<UserNameIdentityToken>(as.userIdentityToken);
    ASSERT_TRUE(u);
    EXPECT_EQ(u->policyId, FakeServer::kUserPolicy);
    EXPECT_EQ(u->userName, "operator");
    EXPECT_EQ(u->password.view(), "secret");

    Client bad;
    EXPECT_EQ(errorOf([&] {
                  bad.connect(server.url(), UserName{"operator", "wrong"});
              }),
              status::BadUserAccessDenied);
    EXPECT_FALSE(bad.isConnected());
    EXPECT_EQ(errorOf([&] { bad.readValue(kInt32); }), status::BadNotConnected);
}

TEST_F(ClientFake, PerOperationStatusesAreReturned) {
    Client c;
    c.connect(server.url());
    ReadValueId a{};
    a.nodeId = kInt32;
    a.attributeId = 13;
    ReadValueId b{};
    b.nodeId = NodeId(1, "Nope");
    b.attributeId = 13;
    auto dvs = c.read({a, b});
    ASSERT_EQ(dvs.size(), 2u);
    EXPECT_TRUE(dvs[0].statusOrGood().isGood());
    EXPECT_EQ(dvs[1].statusOrGood(), status::BadNodeIdUnknown);

    DataValue dv = c.readAttribute(NodeId(1, "Nope"), AttributeId::Value);
    EXPECT_EQ(dv.statusOrGood(), status::BadNodeIdUnknown);
    EXPECT_EQ(errorOf([&] { c.readValue(NodeId(1, "Nope")); }), status::BadNodeIdUnknown);
    EXPECT_EQ(c.readAttribute(kInt32, AttributeId::DisplayName).statusOrGood(),
              status::BadAttributeIdInvalid);
    EXPECT_EQ(c.writeValue(NodeId(1, "Nope"), Int32{1}), status::BadNodeIdUnknown);
}

TEST_F(ClientFake, ServiceFaultAndBadServiceResultThrow) {
    server.setHook([](const FakeServer::Request& r) {
        if (!r.is<ReadRequest>()) return false;
        auto req = r.decodeAs<ReadRequest>();
        if (req.nodesToRead.at(0).nodeId == NodeId(1, "Fault")) {
            FakeServer::fault(r, status::BadTooManyOperations);
            return true;
        }
        if (req.nodesToRead.at(0).nodeId == NodeId(1, "BadResult")) {
            ReadResponse resp{};
            resp.responseHeader.serviceResult = status::BadNothingToDo;
            FakeServer::respond(r, resp);
            return true;
        }
        return false;
    });
    Client c;
    c.connect(server.url());
    EXPECT_EQ(errorOf([&] { c.readValue(NodeId(1, "Fault")); }), status::BadTooManyOperations);
    EXPECT_EQ(errorOf([&] { c.readValue(NodeId(1, "BadResult")); }), status::BadNothingToDo);
    // A service the server does not implement.
    EXPECT_EQ(errorOf([&] { c.request(HistoryReadRequest{}); }), status::BadServiceUnsupported);
    // Still usable.
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    EXPECT_EQ(c.stats().reconnects, 0u);
}

TEST_F(ClientFake, ResponseCountMismatchIsAnError) {
    server.setHook([](const FakeServer::Request& r) {
        if (!r.is<ReadRequest>()) return false;
        FakeServer::respond(r, ReadResponse{});  // no results
        return true;
    });
    Client c;
    c.connect(server.url());
    EXPECT_EQ(errorOf([&] { c.readValue(kInt32); }), status::BadUnexpectedError);
}

TEST_F(ClientFake, GenericRequest) {
    Client c;
    c.connect(server.url());
    ReadRequest req{};
    req.timestampsToReturn = TimestampsToReturn::Neither;
    ReadValueId id{};
    id.nodeId = kInt32;
    id.attributeId = 13;
    req.nodesToRead.push_back(id);
    ReadResponse resp = c.request(req);
    ASSERT_EQ(resp.results.size(), 1u);
    EXPECT_EQ(resp.results[0].value, Variant(Int32{7}));
    // Explicit response type.
    auto resp2 = c.request<ReadRequest, ReadResponse>(req, 2s);
    EXPECT_EQ(resp2.results, resp.results);
}

TEST_F(ClientFake, CallMethod) {
    Client c;
    c.connect(server.url());
    CallResult r = c.call(NodeId(1, "Obj"), NodeId(1, "Add"), {Int32{2}, Int32{40}});
    EXPECT_TRUE(r.ok());
    ASSERT_EQ(r.outputs.size(), 1u);
    EXPECT_EQ(r.outputs[0], Variant(Int32{42}));

    CallResult bad = c.call(NodeId(1, "Obj"), NodeId(1, "Add"), {String("x"), Int32{1}});
    EXPECT_FALSE(bad.ok());
    EXPECT_EQ(bad.status, status::BadInvalidArgument);
    ASSERT_EQ(bad.inputArgumentResults.size(), 2u);
    EXPECT_EQ(bad.inputArgumentResults[0], status::BadTypeMismatch);

    EXPECT_EQ(c.call(NodeId(1, "Obj"), NodeId(1, "Nope"), {}).status, status::BadMethodInvalid);
}

TEST_F(ClientFake, BrowseFollowsContinuationPoints) {
    server.setBrowseReferences(7);
    Client c;
    c.connect(server.url());
    BrowseOptions opt;
    opt.maxReferencesPerNode = 2;
    auto refs = c.browse(NodeId(0, 85), opt);
    ASSERT_EQ(refs.size(), 7u);
    for (std::size_t i = 0; i < refs.size(); ++i)
        EXPECT_EQ(refs[i].browseName.name, "Ref" + std::to_string(i));
    EXPECT_EQ(server.count<BrowseRequest>(), 1u);
    EXPECT_EQ(server.count<BrowseNextRequest>(), 3u);

    // Manual paging.
    BrowseDescription d{};
    d.nodeId = NodeId(0, 85);
    d.browseDirection = BrowseDirection::Forward;
    d.resultMask = 0x3F;
    BrowseResult first = c.browse(d, 3);
    EXPECT_EQ(first.references.size(), 3u);
    ASSERT_FALSE(first.continuationPoint.empty());
    BrowseResult next = c.browseNext(first.continuationPoint);
    EXPECT_EQ(next.references.size(), 3u);
    BrowseResult released = c.browseNext(next.continuationPoint, true);
    EXPECT_TRUE(released.references.empty());

    // A Bad operation status throws from the convenience form only.
    BrowseDescription unknown = d;
    unknown.nodeId = NodeId(1, "Nope");
    EXPECT_EQ(c.browse(unknown).statusCode, status::BadNodeIdUnknown);
    EXPECT_EQ(errorOf([&] { c.browse(NodeId(1, "Nope")); }), status::BadNodeIdUnknown);
}

TEST_F(ClientFake, ResolvePath) {
    Client c;
    c.connect(server.url());
    EXPECT_EQ(c.resolve("/Objects/Server/ServerStatus"), NodeId(0, 2256));
    EXPECT_EQ(errorOf([&] { c.resolve("/Objects/Nope"); }), status::BadNoMatch);
    EXPECT_EQ(errorOf([&] { c.resolve("<Bad"); }), status::BadSyntaxError);
    auto rs = server.received();
    auto tr = rs[2].decodeAs<TranslateBrowsePathsToNodeIdsRequest>();
    ASSERT_EQ(tr.browsePaths.size(), 1u);
    EXPECT_EQ(tr.browsePaths[0].startingNode, NodeId(0, 84));
    EXPECT_EQ(tr.browsePaths[0].relativePath.elements.size(), 3u);
}

TEST_F(ClientFake, NamespacesAreCached) {
    Client c;
    c.connect(server.url());
    EXPECT_EQ(server.readsOf(NodeId(0, 2255)), 0u);  // not read at connect
    EXPECT_EQ(c.namespaceIndex("urn:fake:demo"), 1);
    EXPECT_EQ(c.namespaceIndex("http://opcfoundation.org/UA/"), 0);
    EXPECT_EQ(server.readsOf(NodeId(0, 2255)), 1u);
    EXPECT_EQ(c.parseNodeId("nsu=urn:fake:demo;s=Int32"), kInt32);
    EXPECT_EQ(c.parseNodeId("ns=1;s=Int32"), kInt32);
    EXPECT_EQ(c.parseNodeId("i=85"), NodeId(0, 85));
    EXPECT_EQ(server.readsOf(NodeId(0, 2255)), 1u);
    // Unknown: read once more, then BadNotFound.
    EXPECT_EQ(errorOf([&] { c.namespaceIndex("urn:nope"); }), status::BadNotFound);
    EXPECT_EQ(server.readsOf(NodeId(0, 2255)), 2u);
    EXPECT_EQ(errorOf([&] { c.parseNodeId("garbage"); }), status::BadNodeIdInvalid);
    EXPECT_EQ(c.toNodeId(ExpandedNodeId(NodeId(0, "Int32"), "urn:fake:demo", 0)), kInt32);
    // A new server-side namespace shows up after a refresh.
    server.setValue(NodeId(0, 2255), Variant(std::vector<String>{"http://opcfoundation.org/UA/",
                                                                 "urn:fake:demo", "urn:new"}));
    EXPECT_EQ(c.namespaceIndex("urn:new"), 2);
    EXPECT_EQ(c.namespaceArray().size(), 3u);
}

TEST_F(ClientFake, RegisterNodes) {
    Client c;
    c.connect(server.url());
    auto ids = c.registerNodes({kInt32, NodeId(1, "Other")});
    ASSERT_EQ(ids.size(), 2u);
    EXPECT_EQ(c.readValue(ids[0]), Variant(Int32{7}));
    c.unregisterNodes(ids);
    EXPECT_EQ(server.count<UnregisterNodesRequest>(), 1u);
}

TEST_F(ClientFake, DiscoveryWithoutSession) {
    Client c;
    auto eps = c.getEndpoints(server.url());
    ASSERT_EQ(eps.size(), 1u);
    EXPECT_EQ(eps[0].endpointUrl, server.url());
    auto servers = c.findServers(server.url());
    ASSERT_EQ(servers.size(), 1u);
    EXPECT_EQ(servers[0].applicationUri, "urn:fake:server");
    EXPECT_EQ(server.count<CreateSessionRequest>(), 0u);
    EXPECT_FALSE(c.isConnected());
    // Connected: the current channel is used.
    c.connect(server.url());
    EXPECT_EQ(c.getEndpoints().size(), 1u);
    EXPECT_EQ(c.getEndpoints(server.url()).size(), 1u);
}

// A registrar renews every few hundred ms: with keepDiscoveryConnection its requests share one
// channel, and a channel the server closed meanwhile is replaced without an error.
TEST_F(ClientFake, KeptDiscoveryConnectionIsReusedAndReplacedWhenClosed) {
    ClientConfig config;
    config.keepDiscoveryConnection = true;
    Client c(config);
    for (int i = 0; i < 5; ++i) ASSERT_EQ(c.getEndpoints(server.url()).size(), 1u);
    EXPECT_EQ(server.connectionsSeen(), 1u);
    server.dropConnections();
    for (int i = 0; i < 3; ++i) ASSERT_EQ(c.findServers(server.url()).size(), 1u);
    EXPECT_EQ(server.connectionsSeen(), 2u);
    // Without it: one connection per request.
    Client once;
    for (int i = 0; i < 3; ++i) ASSERT_EQ(once.getEndpoints(server.url()).size(), 1u);
    EXPECT_EQ(server.connectionsSeen(), 5u);
}

TEST_F(ClientFake, DestructorAndDisconnectCloseTheSession) {
    {
        Client c;
        c.connect(server.url());
    }
    EXPECT_EQ(server.count<CloseSessionRequest>(), 1u);
    Client c;
    c.connect(server.url());
    c.disconnect();
    EXPECT_EQ(server.count<CloseSessionRequest>(), 2u);
    EXPECT_FALSE(c.isConnected());
    EXPECT_EQ(errorOf([&] { c.readValue(kInt32); }), status::BadNotConnected);
    c.disconnect();           // twice is fine
    c.connect(server.url());  // and again
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    // connect() while connected replaces the connection.
    c.connect(server.url());
    EXPECT_EQ(server.count<CloseSessionRequest>(), 3u);
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
}

TEST_F(ClientFake, MovedClientKeepsItsSession) {
    Client a;
    a.connect(server.url());
    Client b(std::move(a));
    EXPECT_EQ(b.readValue(kInt32), Variant(Int32{7}));
    Client c;
    c = std::move(b);
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    EXPECT_EQ(server.count<CreateSessionRequest>(), 1u);
}

// ---- deadlines -----------------------------------------------------------------------------

TEST_F(ClientFake, TimeoutKeepsTheClientUsableAndDiscardsTheLateResponse) {
    FakeServer* srv = &server;
    server.setValue(NodeId(1, "Slow"), Variant(Int32{1}));
    server.setHook([srv](const FakeServer::Request& r) {
        if (!r.is<ReadRequest>()) return false;
        if (r.decodeAs<ReadRequest>().nodesToRead.at(0).nodeId != NodeId(1, "Slow")) return false;
        srv->later(r, 300ms, [srv](const FakeServer::Request& rr) { srv->handleDefault(rr); });
        return true;
    });
    Client c;
    c.connect(server.url());
    auto t0 = Clock::now();
    EXPECT_EQ(errorOf([&] { c.readValue(NodeId(1, "Slow"), 100ms); }), status::BadTimeout);
    auto elapsed = Clock::now() - t0;
    EXPECT_GE(elapsed, 95ms);
    EXPECT_LT(elapsed, 250ms);
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    std::this_thread::sleep_for(350ms);
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));  // the late one arrives first
    auto stats = c.stats();
    EXPECT_EQ(stats.timeouts, 1u);
    EXPECT_EQ(stats.discardedResponses, 1u);
    EXPECT_EQ(stats.reconnects, 0u);
}

TEST_F(ClientFake, DefaultDeadlineIsTheConfiguredRequestTimeout) {
    server.setHook([](const FakeServer::Request& r) { return r.is<WriteRequest>(); });  // swallow
    ClientConfig cfg;
    cfg.requestTimeout = 120ms;
    Client c(cfg);
    c.connect(server.url());
    auto t0 = Clock::now();
    EXPECT_EQ(errorOf([&] { c.writeValue(kInt32, Int32{1}); }), status::BadTimeout);
    EXPECT_LT(Clock::now() - t0, 400ms);
    // Absolute deadline.
    t0 = Clock::now();
    EXPECT_EQ(errorOf([&] { c.writeValue(kInt32, Int32{1}, Clock::now() + 50ms); }),
              status::BadTimeout);
    EXPECT_LT(Clock::now() - t0, 300ms);
    // A deadline already passed: not even sent.
    std::size_t reads = server.count<ReadRequest>();
    EXPECT_EQ(errorOf([&] { c.readValue(kInt32, Clock::now() - 1s); }), status::BadTimeout);
    std::optional<Result<Variant>> got;
    c.readValueAsync(
        kInt32, [&](Result<Variant> r) { got = std::move(r); }, Clock::now() - 1s);
    ASSERT_TRUE(got);
    EXPECT_EQ(got->status(), status::BadTimeout);
    EXPECT_EQ(server.count<ReadRequest>(), reads);
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
}

// ---- reconnect -----------------------------------------------------------------------------

TEST_F(ClientFake, IdempotentCallIsRetriedOnANewChannelWithTheSameSession) {
    server.dropFirst<ReadRequest>();
    Client c;
    c.connect(server.url());
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    auto stats = c.stats();
    EXPECT_EQ(stats.connectionsLost, 1u);
    EXPECT_EQ(stats.reconnects, 1u);
    EXPECT_EQ(stats.retries, 1u);
    EXPECT_EQ(stats.sessionsCreated, 1u);
    EXPECT_EQ(stats.sessionsReactivated, 1u);
    auto tokens = server.activatedTokens();
    ASSERT_EQ(tokens.size(), 2u);
    EXPECT_EQ(tokens[0], tokens[1]);  // ActivateSession re-used the authentication token
    EXPECT_EQ(server.count<CreateSessionRequest>(), 1u);
}

TEST_F(ClientFake, NonIdempotentCallIsNotRetried) {
    server.dropFirst<WriteRequest>();
    Client c;
    c.connect(server.url());
    StatusCode s = errorOf([&] { c.writeValue(kInt32, Int32{5}); });
    EXPECT_EQ(s, status::BadConnectionClosed);
    EXPECT_EQ(server.count<WriteRequest>(), 1u);
    // The next call reconnects first.
    EXPECT_EQ(c.writeValue(kInt32, Int32{6}), StatusCode{});
    EXPECT_EQ(server.count<WriteRequest>(), 2u);
    EXPECT_EQ(server.value(kInt32), Variant(Int32{6}));
    EXPECT_EQ(c.stats().reconnects, 1u);
    EXPECT_EQ(c.stats().sessionsReactivated, 1u);
}

TEST_F(ClientFake, RetryIdempotentCanBeDisabled) {
    server.dropFirst<ReadRequest>();
    ClientConfig cfg;
    cfg.reconnect.retryIdempotent = false;
    Client c(cfg);
    c.connect(server.url());
    EXPECT_EQ(errorOf([&] { c.readValue(kInt32); }), status::BadConnectionClosed);
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
}

TEST_F(ClientFake, IdleDropIsDetectedBeforeSending) {
    ClientConfig cfg;
    cfg.idleCheckAfter = 1ms;
    Client c(cfg);
    c.connect(server.url());
    server.dropConnections();
    std::this_thread::sleep_for(100ms);
    // Not idempotent, but the drop is noticed before the Write goes out.
    EXPECT_EQ(c.writeValue(kInt32, Int32{9}), StatusCode{});
    EXPECT_EQ(server.value(kInt32), Variant(Int32{9}));
    EXPECT_EQ(c.stats().reconnects, 1u);
    EXPECT_EQ(server.count<WriteRequest>(), 1u);
}

TEST_F(ClientFake, LocallyBrokenSocketIsReconnected) {
    Client c;
    c.connect(server.url());
    ::shutdown(c.nativeHandle(), SHUT_RDWR);
    // The send fails, so even a Write is sent again on the new channel.
    EXPECT_EQ(c.writeValue(kInt32, Int32{11}), StatusCode{});
    EXPECT_EQ(server.value(kInt32), Variant(Int32{11}));
    EXPECT_EQ(c.stats().reconnects, 1u);
}

TEST_F(ClientFake, ForgottenSessionIsRecreatedOnReconnect) {
    Client c;
    c.connect(server.url());
    NodeId first = c.sessionId();
    server.forgetSessions();
    server.dropConnections();
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    EXPECT_NE(c.sessionId(), first);
    auto stats = c.stats();
    EXPECT_EQ(stats.sessionsCreated, 2u);
    EXPECT_EQ(stats.sessionsReactivated, 0u);
    EXPECT_EQ(stats.reconnects, 1u);
}

TEST_F(ClientFake, ForgottenSessionOnALiveChannelIsRecreated) {
    Client c;
    c.connect(server.url());
    server.forgetSessions();
    // BadSessionIdInvalid: the server did not execute the Write, so it is sent again.
    EXPECT_EQ(c.writeValue(kInt32, Int32{3}), StatusCode{});
    EXPECT_EQ(server.value(kInt32), Variant(Int32{3}));
    EXPECT_EQ(c.stats().sessionsCreated, 2u);
    EXPECT_EQ(c.stats().reconnects, 0u);
}

TEST_F(ClientFake, ReconnectDisabled) {
    ClientConfig cfg;
    cfg.reconnect.enabled = false;
    Client c(cfg);
    c.connect(server.url());
    server.dropConnections();
    std::this_thread::sleep_for(50ms);
    StatusCode s = errorOf([&] { c.readValue(kInt32); });
    EXPECT_TRUE(s.isBad());
    EXPECT_EQ(errorOf([&] { c.readValue(kInt32); }), status::BadNotConnected);
    EXPECT_TRUE(c.isConnected());  // until disconnect(): connect() again to recover
    c.connect(server.url());
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
}

TEST(ClientReconnect, ServerGoneFailsWithinTheDeadline) {
    auto server = std::make_unique<FakeServer>();
    Client c;
    c.connect(server->url());
    server.reset();
    auto t0 = Clock::now();
    StatusCode s = errorOf([&] { c.readValue(kInt32, 1s); });
    EXPECT_TRUE(s.isBad());
    EXPECT_LT(Clock::now() - t0, 1500ms);
    s = errorOf([&] { c.readValue(kInt32, 1s); });
    EXPECT_TRUE(s.isBad());
    EXPECT_LT(Clock::now() - t0, 3s);
}

// ---- asynchronous calls --------------------------------------------------------------------

TEST_F(ClientFake, AsyncCompletesInRunIterate) {
    Client c;
    c.connect(server.url());
    std::optional<Result<Variant>> got;
    c.readValueAsync(kInt32, [&](Result<Variant> r) { got = std::move(r); });
    EXPECT_FALSE(got);  // not before someone dispatches
    std::size_t n = 0;
    for (int i = 0; i < 100 && !got; ++i) n += c.runIterate(50ms);
    EXPECT_EQ(n, 1u);
    ASSERT_TRUE(got);
    ASSERT_TRUE(got->ok());
    EXPECT_EQ(got->value(), Variant(Int32{7}));

    std::optional<Result<CallResult>> call;
    c.callAsync(NodeId(1, "Obj"), NodeId(1, "Add"), {Int32{1}, Int32{2}},
                [&](Result<CallResult> r) { call = std::move(r); });
    std::optional<Result<std::vector<StatusCode>>> wrote;
    WriteValue w{};
    w.nodeId = kInt32;
    w.attributeId = 13;
    w.value = DataValue(Variant(Int32{8}));
    c.writeAsync({w}, [&](Result<std::vector<StatusCode>> r) { wrote = std::move(r); });
    std::optional<Result<std::vector<DataValue>>> read;
    ReadValueId id{};
    id.nodeId = NodeId(1, "Nope");
    id.attributeId = 13;
    c.readAsync({id}, [&](Result<std::vector<DataValue>> r) { read = std::move(r); });
    for (int i = 0; i < 100 && !(call && wrote && read); ++i) c.runIterate(50ms);
    ASSERT_TRUE(call && wrote && read);
    EXPECT_EQ(call->value().outputs.at(0), Variant(Int32{3}));
    EXPECT_EQ(wrote->value().at(0), StatusCode{});
    EXPECT_EQ(read->value().at(0).statusOrGood(), status::BadNodeIdUnknown);
}

TEST_F(ClientFake, AsyncCompletesInsideABlockingCall) {
    Client c;
    c.connect(server.url());
    bool done = false;
    c.readValueAsync(kInt32, [&](Result<Variant> r) { done = r.ok(); });
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    EXPECT_TRUE(done);  // its response came first and was dispatched before readValue returned
}

TEST_F(ClientFake, AsyncBadOperationStatusIsAnError) {
    Client c;
    c.connect(server.url());
    std::optional<Result<Variant>> got;
    c.readValueAsync(NodeId(1, "Nope"), [&](Result<Variant> r) { got = std::move(r); });
    for (int i = 0; i < 100 && !got; ++i) c.runIterate(50ms);
    ASSERT_TRUE(got);
    EXPECT_EQ(got->status(), status::BadNodeIdUnknown);
}

TEST_F(ClientFake, AsyncTimeout) {
    server.setHook([](const FakeServer::Request& r) { return r.is<ReadRequest>(); });  // swallow
    Client c;
    c.connect(server.url());
    std::optional<Result<Variant>> got;
    auto t0 = Clock::now();
    c.readValueAsync(
        kInt32, [&](Result<Variant> r) { got = std::move(r); }, 80ms);
    for (int i = 0; i < 100 && !got; ++i) c.runIterate(20ms);
    ASSERT_TRUE(got);
    EXPECT_EQ(got->status(), status::BadTimeout);
    EXPECT_LT(Clock::now() - t0, 500ms);
    EXPECT_GE(Clock::now() - t0, 75ms);
}

TEST_F(ClientFake, AsyncFailuresReachTheCallback) {
    Client c;
    std::optional<Result<Variant>> got;
    c.readValueAsync(kInt32, [&](Result<Variant> r) { got = std::move(r); });
    ASSERT_TRUE(got);  // at once: there is no connection
    EXPECT_EQ(got->status(), status::BadNotConnected);

    // Pending calls complete with BadShutdown on disconnect().
    server.setHook([](const FakeServer::Request& r) { return r.is<ReadRequest>(); });
    c.connect(server.url());
    got.reset();
    c.readValueAsync(kInt32, [&](Result<Variant> r) { got = std::move(r); });
    c.disconnect();
    ASSERT_TRUE(got);
    EXPECT_EQ(got->status(), status::BadShutdown);
}

TEST_F(ClientFake, AsyncConnectionLoss) {
    server.setHook([](const FakeServer::Request& r) {
        if (!r.is<ReadRequest>()) return false;
        r.conn->close();
        return true;
    });
    Client c;
    c.connect(server.url());
    std::optional<Result<Variant>> got;
    c.readValueAsync(kInt32, [&](Result<Variant> r) { got = std::move(r); });
    for (int i = 0; i < 100 && !got; ++i) c.runIterate(20ms);
    ASSERT_TRUE(got);
    EXPECT_EQ(got->status(), status::BadConnectionClosed);
}

TEST_F(ClientFake, FutureWithBackgroundThread) {
    Client c;
    c.connect(server.url());
    c.startBackgroundThread();
    EXPECT_TRUE(c.backgroundThreadRunning());
    ReadRequest req{};
    req.timestampsToReturn = TimestampsToReturn::Neither;
    ReadValueId id{};
    id.nodeId = kInt32;
    id.attributeId = 13;
    req.nodesToRead.push_back(id);
    std::future<ReadResponse> f = c.requestAsync(req);
    ASSERT_EQ(f.wait_for(3s), std::future_status::ready);
    EXPECT_EQ(f.get().results.at(0).value, Variant(Int32{7}));

    // Errors arrive as the exception of the future.
    HistoryReadRequest h{};
    auto f2 = c.requestAsync(h);
    ASSERT_EQ(f2.wait_for(3s), std::future_status::ready);
    try {
        f2.get();
        FAIL();
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadServiceUnsupported);
    }
    // Blocking calls work beside the background thread.
    for (int i = 0; i < 20; ++i) EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
    c.stopBackgroundThread();
    EXPECT_FALSE(c.backgroundThreadRunning());
}

TEST_F(ClientFake, CallbackMayCallTheClient) {
    Client c;
    c.connect(server.url());
    c.startBackgroundThread();
    std::promise<Variant> p;
    c.readValueAsync(kInt32, [&](Result<Variant>) {
        p.set_value(c.readValue(kInt32));  // a blocking call from the background thread
    });
    auto f = p.get_future();
    ASSERT_EQ(f.wait_for(3s), std::future_status::ready);
    EXPECT_EQ(f.get(), Variant(Int32{7}));
}

TEST_F(ClientFake, ConcurrentBlockingCalls) {
    Client c;
    c.connect(server.url());
    c.startBackgroundThread();
    std::atomic<int> ok{0};
    std::vector<std::thread> ts;
    for (int t = 0; t < 4; ++t) {
        ts.emplace_back([&] {
            for (int i = 0; i < 50; ++i)
                if (c.readValue(kInt32) == Variant(Int32{7})) ++ok;
        });
    }
    std::atomic<int> asyncOk{0};
    for (int i = 0; i < 50; ++i)
        c.readValueAsync(kInt32, [&](Result<Variant> r) {
            if (r.ok()) ++asyncOk;
        });
    for (auto& t : ts) t.join();
    EXPECT_EQ(ok, 200);
    EXPECT_TRUE(waitUntil([&] { return asyncOk == 50; }));
}

// ---- background thread ---------------------------------------------------------------------
// A callback on the background thread sends the next request (as the subscription engine
// does with Publish and Republish): its response is read at once. The background thread does
// not wake itself through its eventfd, so it must look at what it waits for again after the
// callbacks; it used to poll with the socket events and deadline computed before them (no
// request pending: only a hang-up watched) and left each response unread for up to a second
// (a republished notification arrived after the interop test had checked for gaps).
TEST_F(ClientFake, RequestSentByABackgroundCallbackIsAnsweredPromptly) {
    Client c;
    c.connect(server.url());
    c.startBackgroundThread();
    constexpr int kHops = 5;
    std::promise<int> done;
    std::function<void(int, Result<Variant>)> hop = [&](int n, Result<Variant> r) {
        if (!r.ok() || n == kHops) {
            done.set_value(r.ok() ? n : -n);
            return;
        }
        // The only request pending when its response was routed: the next one is sent with
        // nothing pending, from the background thread itself.
        c.readValueAsync(kInt32, [&, n](Result<Variant> next) { hop(n + 1, std::move(next)); });
    };
    auto start = Clock::now();
    c.readValueAsync(kInt32, [&](Result<Variant> r) { hop(1, std::move(r)); });
    auto f = done.get_future();
    ASSERT_EQ(f.wait_for(10s), std::future_status::ready);
    EXPECT_EQ(f.get(), kHops);
    // Each hop took about a second before; a loopback round trip takes milliseconds, even
    // under sanitizers on a loaded machine.
    auto took = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start);
    EXPECT_LT(took, 2s) << kHops << " chained requests took " << took.count() << " ms";
}

TEST_F(ClientFake, KeepAliveWhileIdle) {
    ClientConfig cfg;
    cfg.keepAliveInterval = 50ms;
    Client c(cfg);
    c.connect(server.url());
    c.startBackgroundThread();
    EXPECT_TRUE(waitUntil([&] { return server.readsOf(NodeId(0, 2258)) >= 3; }));
    EXPECT_GE(c.stats().keepAlives, 3u);
}

TEST_F(ClientFake, NoKeepAliveWhileBusy) {
    ClientConfig cfg;
    cfg.keepAliveInterval = 200ms;
    Client c(cfg);
    c.connect(server.url());
    c.startBackgroundThread();
    auto end = Clock::now() + 500ms;
    while (Clock::now() < end) {
        c.readValue(kInt32);
        std::this_thread::sleep_for(10ms);
    }
    EXPECT_EQ(server.readsOf(NodeId(0, 2258)), 0u);
}

TEST_F(ClientFake, BackgroundThreadReconnects) {
    Client c;
    c.connect(server.url());
    c.startBackgroundThread();
    server.dropConnections();
    EXPECT_TRUE(waitUntil([&] { return c.stats().reconnects == 1; }));
    EXPECT_TRUE(c.isChannelOpen());
    EXPECT_EQ(c.stats().sessionsReactivated, 1u);
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
}

TEST(ClientBackground, ReconnectBacksOffWhileTheServerIsDown) {
    auto server = std::make_unique<FakeServer>();
    ClientConfig cfg;
    cfg.reconnect.initialDelay = 20ms;
    cfg.reconnect.maxDelay = 100ms;
    Client c(cfg);
    c.connect(server->url());
    c.startBackgroundThread();
    server.reset();
    std::this_thread::sleep_for(400ms);
    EXPECT_FALSE(c.isChannelOpen());
    EXPECT_TRUE(c.isConnected());
    EXPECT_EQ(c.stats().reconnects, 0u);
    // The client and its thread shut down cleanly.
}

TEST_F(ClientFake, StopFromInsideACallback) {
    Client c;
    c.connect(server.url());
    c.startBackgroundThread();
    std::promise<void> p;
    c.readValueAsync(kInt32, [&](Result<Variant>) {
        c.stopBackgroundThread();
        p.set_value();
    });
    ASSERT_EQ(p.get_future().wait_for(3s), std::future_status::ready);
    std::this_thread::sleep_for(50ms);
    EXPECT_FALSE(c.backgroundThreadRunning());
    EXPECT_EQ(c.readValue(kInt32), Variant(Int32{7}));
}

}  // namespace
}  // namespace pnp::ua::client
