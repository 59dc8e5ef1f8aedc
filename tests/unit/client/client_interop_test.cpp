// The client against the node-opcua reference server (tests/interop/node_server.js), started
// once for the whole program as a child process. Skipped (not failed) only when `node` or the
// script is missing.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <future>
#include <limits>
#include <thread>

#include "support/child_process.hpp"
#include "support/loopback.hpp"
#include "ua/client/browse_path.hpp"
#include "ua/client/client.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

#ifndef PNP_SOURCE_DIR
#error "PNP_SOURCE_DIR must be defined"
#endif

namespace pnp::ua::client {
namespace {

using namespace std::chrono_literals;
using pnp::testing::errorOf;

constexpr const char* kDemoUri = "urn:pnp:demo";

UInt16 freePort() { return pnp::testing::freeLoopbackPort(); }

// Starts the node-opcua server once for all tests.
class NodeServer : public ::testing::Environment {
  public:
    void SetUp() override {
        std::string node = pnp::testing::findInPath("node");
        std::string script = std::string(PNP_SOURCE_DIR) + "/tests/interop/node_server.js";
        if (node.empty()) {
            skipReason_ = "`node` is not installed";
            return;
        }
        if (!pnp::testing::fileExists(script)) {
            skipReason_ = script + " is missing";
            return;
        }
        UInt16 port = freePort();
        url_ = pnp::testing::url(port);
        std::string log = ::testing::TempDir() + "pnp_client_interop_node_server_" +
                          std::to_string(::getpid()) + ".log";
        if (!process_.start({node, script, std::to_string(port)}, log, error_) ||
            !process_.waitForLine("READY", 90s, error_)) {
            error_ =
                "node_server.js did not start: " + error_ + "\n--- log ---\n" + process_.logTail();
            process_.stop();
            return;
        }
        std::printf("[ interop  ] node-opcua server pid %d on %s\n",
                    static_cast<int>(process_.pid()), url_.c_str());
        ready_ = true;
    }
    void TearDown() override { process_.stop(); }

    bool ready() const { return ready_; }
    const std::string& skipReason() const { return skipReason_; }
    const std::string& error() const { return error_; }
    const std::string& url() const { return url_; }

  private:
    pnp::testing::ChildProcess process_;
    std::string url_;
    std::string skipReason_;
    std::string error_;
    bool ready_ = false;
};

NodeServer* g_server = nullptr;

class Interop : public ::testing::Test {
  protected:
    void SetUp() override {
        if (!g_server->skipReason().empty()) GTEST_SKIP() << g_server->skipReason();
        ASSERT_TRUE(g_server->ready()) << g_server->error();
        url = g_server->url();
    }
    // A connected anonymous client and the demo namespace index.
    void connect(Client& c) {
        c.connect(url);
        demo = c.namespaceIndex(kDemoUri);
    }
    std::string url;
    UInt16 demo = 0;
};

// ---- the demo values (mirror tests/interop/demo_types.js) ------------------------------------

DateTime iso(const char* s) {
    auto d = DateTime::parseIso8601(s);
    EXPECT_TRUE(d) << s;
    return d.value_or(DateTime{});
}
Guid guid(const char* s) {
    auto g = Guid::parse(s);
    EXPECT_TRUE(g) << s;
    return g.value_or(Guid{});
}
NodeId nodeId(const char* s) {
    auto n = NodeId::parse(s);
    EXPECT_TRUE(n) << s;
    return n.value_or(NodeId{});
}
ByteString bytes(std::initializer_list<int> b) {
    std::string s;
    for (int x : b) s.push_back(static_cast<char>(x));
    return ByteString(s);
}
DiagnosticInfo diag(std::optional<Int32> symbolicId, std::optional<Int32> localizedText,
                    std::optional<String> info, std::optional<StatusCode> inner) {
    DiagnosticInfo d;
    d.symbolicId = symbolicId;
    d.localizedText = localizedText;
    d.additionalInfo = std::move(info);
    d.innerStatusCode = inner;
    return d;
}

struct DemoValue {
    std::string type;
    Variant scalar;
    Variant array;
};

std::vector<DemoValue> demoValues() {
    std::vector<DemoValue> v;
    v.push_back({"Boolean", true, std::vector<Boolean>{true, false, true}});
    v.push_back({"SByte", SByte{-42}, std::vector<SByte>{-128, 0, 127}});
    v.push_back({"Byte", Byte{200}, std::vector<Byte>{0, 1, 255}});
    v.push_back({"Int16", Int16{-1234}, std::vector<Int16>{-32768, 0, 32767}});
    v.push_back({"UInt16", UInt16{54321}, std::vector<UInt16>{0, 1, 65535}});
    v.push_back({"Int32", Int32{-123456789},
                 std::vector<Int32>{std::numeric_limits<Int32>::min(), 0,
                                    std::numeric_limits<Int32>::max()}});
    v.push_back({"UInt32", UInt32{4000000000u}, std::vector<UInt32>{0, 1, 4294967295u}});
    v.push_back({"Int64", Int64{0x123456789abcdef0LL},
                 std::vector<Int64>{-5, 0, std::numeric_limits<Int64>::max()}});
    v.push_back({"UInt64", UInt64{0xfedcba9876543210ULL},
                 std::vector<UInt64>{0, 1, std::numeric_limits<UInt64>::max()}});
    v.push_back({"Float", Float{3.5f}, std::vector<Float>{-2.25f, 0.5f, 1024.75f}});
    v.push_back({"Double", Double{M_PI}, std::vector<Double>{1.5, -1e300, 6.02214076e23}});
    v.push_back({"String", String("h\u00e9llo \u2713 pnp"),
                 std::vector<String>{"a", "", "\u00fc\u00f1\u00ed"}});
    v.push_back(
        {"DateTime", iso("2024-05-06T07:08:09.123Z"),
         std::vector<DateTime>{iso("2001-01-01T00:00:00.000Z"), iso("2030-12-31T23:59:59.999Z")}});
    v.push_back({"Guid", guid("72962B91-FA75-4AE6-8D28-B404DC7DAF63"),
                 std::vector<Guid>{guid("00000000-0000-0000-0000-000000000001"),
                                   guid("0123ABCD-4567-89EF-0123-456789ABCDEF")}});
    v.push_back(
        {"ByteString", bytes({0x00, 0x01, 0x02, 0xfe, 0xff}),
         std::vector<ByteString>{ByteString("abc"), bytes({0}), bytes({0xde, 0xad, 0xbe, 0xef})}});
    v.push_back({"XmlElement", XmlElement{"<pnp a=\"1\">demo</pnp>"},
                 std::vector<XmlElement>{XmlElement{"<a/>"}, XmlElement{"<b>x</b>"}}});
    v.push_back({"NodeId", nodeId("ns=1;s=pnp.Scalar"),
                 std::vector<NodeId>{nodeId("i=2253"), nodeId("ns=1;s=hello"),
                                     nodeId("ns=1;g=72962B91-FA75-4AE6-8D28-B404DC7DAF63"),
                                     nodeId("ns=1;b=AQID"), nodeId("ns=3;i=70000")}});
    v.push_back({"ExpandedNodeId", ExpandedNodeId(NodeId(0, 1234), "urn:pnp:other", 0),
                 std::vector<ExpandedNodeId>{ExpandedNodeId(NodeId(0, 85)),
                                             ExpandedNodeId(NodeId(1, "x.y"), "", 2)}});
    v.push_back(
        {"StatusCode", status::BadOutOfRange,
         std::vector<StatusCode>{StatusCode{}, status::UncertainInitialValue, status::BadTimeout}});
    v.push_back({"QualifiedName", QualifiedName{1, "Qn"},
                 std::vector<QualifiedName>{QualifiedName{0, "A"}, QualifiedName{1, "B"}}});
    v.push_back(
        {"LocalizedText", LocalizedText("en-US", "hello"),
         std::vector<LocalizedText>{LocalizedText("de", "hallo"), LocalizedText("", "no locale")}});
    v.push_back({"ExtensionObject", toExtensionObject(Range{-1.5, 99.25}),
                 std::vector<ExtensionObject>{toExtensionObject(Range{0, 1}),
                                              toExtensionObject(Range{-10, 10})}});
    DataValue dv(Variant(Double{1.25}));
    dv.status = status::UncertainLastUsableValue;
    dv.sourceTimestamp = iso("2024-01-02T03:04:05.678Z");
    DataValue dv1(Variant(Int32{7}));
    DataValue dv2(Variant(String("dv")));
    dv2.status = status::BadNoData;
    v.push_back({"DataValue", dv, std::vector<DataValue>{dv1, dv2}});
    v.push_back({"Variant", Double{2.5},
                 std::vector<Variant>{Variant(Int32{1}), Variant(String("two")), Variant(true)}});
    v.push_back({"DiagnosticInfo", diag(3, 5, "info", status::BadTimeout),
                 std::vector<DiagnosticInfo>{diag(1, {}, {}, {}), diag({}, {}, "x", {})}});
    return v;
}

// ---- tests ------------------------------------------------------------------------------------

TEST_F(Interop, GetEndpointsAndFindServersWithoutSession) {
    Client c;
    auto eps = c.getEndpoints(url);
    ASSERT_FALSE(eps.empty());
    bool none = false, anon = false, user = false;
    for (const auto& ep : eps) {
        if (ep.securityPolicyUri != "http://opcfoundation.org/UA/SecurityPolicy#None") continue;
        none = true;
        for (const auto& t : ep.userIdentityTokens) {
            anon |= t.tokenType == UserTokenType::Anonymous;
            user |= t.tokenType == UserTokenType::UserName;
        }
    }
    EXPECT_TRUE(none && anon && user);
    auto servers = c.findServers(url);
    ASSERT_FALSE(servers.empty());
    EXPECT_EQ(servers[0].applicationUri, "urn:pnp:node-opcua-reference-server");
    EXPECT_FALSE(c.isConnected());
}

TEST_F(Interop, AnonymousSession) {
    auto t0 = Clock::now();
    Client c;
    c.connect(url);
    Variant state = c.readValue(NodeId(0, ns0::Server_ServerStatus_State));
    auto elapsed = Clock::now() - t0;
    std::printf("[ interop  ] connect + session + first Read: %.3f ms\n",
                std::chrono::duration<double, std::milli>(elapsed).count());
    EXPECT_FALSE(c.sessionId().isNull());
    EXPECT_GT(c.sessionTimeout(), 0.0);
    ASSERT_TRUE(state.scalar<Int32>());
    EXPECT_EQ(*state.scalar<Int32>(), 0);  // Running
    // Discovery over the session's channel.
    EXPECT_FALSE(c.getEndpoints().empty());
}

TEST_F(Interop, UserNameSession) {
    Client c;
    c.connect(url, UserName{"operator", "secret"});
    demo = c.namespaceIndex(kDemoUri);
    EXPECT_EQ(c.writeValue(NodeId(demo, "Scalar.Int32"), Int32{4711}), StatusCode{});
    EXPECT_EQ(c.readValue(NodeId(demo, "Scalar.Int32")), Variant(Int32{4711}));

    Client bad;
    StatusCode s = errorOf([&] { bad.connect(url, UserName{"operator", "wrong"}); });
    EXPECT_TRUE(s.isBad()) << s.toString();
    EXPECT_FALSE(bad.isConnected());
}

TEST_F(Interop, BrowseObjects) {
    Client c;
    connect(c);
    auto refs = c.browse(NodeId(0, ns0::ObjectsFolder));
    bool server = false, demoObj = false;
    for (const auto& r : refs) {
        if (r.browseName == QualifiedName{0, "Server"}) {
            server = true;
            EXPECT_EQ(r.nodeId.nodeId, NodeId(0, ns0::Server));
            EXPECT_TRUE(r.isForward);
            EXPECT_EQ(r.nodeClass, NodeClass::Object);
        }
        if (r.browseName == QualifiedName{demo, "Demo"}) {
            demoObj = true;
            EXPECT_EQ(r.nodeId.nodeId, NodeId(demo, "Demo"));
        }
    }
    EXPECT_TRUE(server);
    EXPECT_TRUE(demoObj);
}

TEST_F(Interop, BrowseNextWithSmallMaxReferences) {
    Client c;
    connect(c);
    NodeId demoNode(demo, "Demo");
    auto all = c.browse(demoNode);
    ASSERT_GT(all.size(), 50u);  // 2 x 25 variables + 2 methods
    BrowseOptions small;
    small.maxReferencesPerNode = 4;
    auto paged = c.browse(demoNode, small);
    ASSERT_EQ(paged.size(), all.size());
    for (std::size_t i = 0; i < all.size(); ++i) EXPECT_EQ(paged[i].nodeId, all[i].nodeId);

    BrowseDescription d{};
    d.nodeId = demoNode;
    d.browseDirection = BrowseDirection::Forward;
    d.referenceTypeId = NodeId(0, ns0::HierarchicalReferences);
    d.includeSubtypes = true;
    d.resultMask = 0x3F;
    BrowseResult first = c.browse(d, 3);
    EXPECT_EQ(first.references.size(), 3u);
    ASSERT_FALSE(first.continuationPoint.empty());
    BrowseResult second = c.browseNext(first.continuationPoint);
    EXPECT_EQ(second.statusCode, StatusCode{});
    EXPECT_EQ(second.references.size(), 3u);
    EXPECT_NE(second.references[0].nodeId, first.references[0].nodeId);
    ASSERT_FALSE(second.continuationPoint.empty());
    BrowseResult released = c.browseNext(second.continuationPoint, true);
    EXPECT_TRUE(released.references.empty());
    // A released continuation point is gone.
    BrowseResult stale = c.browseNext(second.continuationPoint);
    EXPECT_TRUE(stale.statusCode.isBad());
}

TEST_F(Interop, TranslateBrowsePaths) {
    Client c;
    connect(c);
    EXPECT_EQ(c.resolve("/Objects/Server/ServerStatus"), NodeId(0, ns0::Server_ServerStatus));
    EXPECT_EQ(c.resolve("/Objects/Server.ServerStatus.CurrentTime"),
              NodeId(0, ns0::Server_ServerStatus_CurrentTime));
    EXPECT_EQ(c.resolve("/Objects/urn:pnp:demo:Demo"), NodeId(demo, "Demo"));
    std::string path =
        "/Objects/" + std::to_string(demo) + ":Demo/" + std::to_string(demo) + ":Scalar&.Int32";
    EXPECT_EQ(c.resolve(path), NodeId(demo, "Scalar.Int32"));
    EXPECT_EQ(c.resolve(NodeId(0, ns0::Server), "ServerStatus/BuildInfo"),
              NodeId(0, ns0::Server_ServerStatus_BuildInfo));
    EXPECT_EQ(errorOf([&] { c.resolve("/Objects/NoSuchThing"); }), status::BadNoMatch);

    BrowsePath bp{};
    bp.startingNode = NodeId(0, ns0::RootFolder);
    bp.relativePath = parseRelativePath("/Objects/Server");
    BrowsePath bad = bp;
    bad.relativePath = parseRelativePath("/Objects/Nope");
    auto results = c.translateBrowsePaths({bp, bad});
    ASSERT_EQ(results.size(), 2u);
    EXPECT_EQ(results[0].statusCode, StatusCode{});
    ASSERT_EQ(results[0].targets.size(), 1u);
    EXPECT_EQ(results[0].targets[0].targetId.nodeId, NodeId(0, ns0::Server));
    EXPECT_EQ(results[1].statusCode, status::BadNoMatch);
}

TEST_F(Interop, ReadServerStatus) {
    Client c;
    c.connect(url);
    Variant v = c.readValue(NodeId(0, ns0::Server_ServerStatus));
    const ExtensionObject* x = v.scalar<ExtensionObject>();
    ASSERT_NE(x, nullptr) << v.toString();
    auto status = fromExtensionObject<ServerStatusDataType>(*x);
    ASSERT_TRUE(status);
    EXPECT_EQ(status->state, ServerState::Running);
    EXPECT_EQ(status->buildInfo.productName, "pnp-node-reference");
    auto skew = status->currentTime.toUnixNanos() - DateTime::now().toUnixNanos();
    EXPECT_LT(std::abs(skew), 60'000'000'000LL);
    EXPECT_GE(status->currentTime.ticks, status->startTime.ticks);

    // Several attributes with timestamps.
    ReadValueId value{};
    value.nodeId = NodeId(0, ns0::Server_ServerStatus_CurrentTime);
    value.attributeId = 13;
    ReadValueId name = value;
    name.attributeId = static_cast<UInt32>(AttributeId::BrowseName);
    auto dvs = c.read({value, name});
    ASSERT_EQ(dvs.size(), 2u);
    EXPECT_TRUE(dvs[0].value && dvs[0].value->scalar<DateTime>());
    EXPECT_TRUE(dvs[0].serverTimestamp.has_value());
    ASSERT_TRUE(dvs[1].value && dvs[1].value->scalar<QualifiedName>());
    EXPECT_EQ(dvs[1].value->scalar<QualifiedName>()->name, "CurrentTime");
    DataValue dn = c.readAttribute(NodeId(0, ns0::Server), AttributeId::DisplayName);
    ASSERT_TRUE(dn.value && dn.value->scalar<LocalizedText>());
    EXPECT_EQ(dn.value->scalar<LocalizedText>()->text, "Server");
}

TEST_F(Interop, NamespaceArray) {
    Client c;
    c.connect(url);
    auto ns = c.namespaceArray();
    ASSERT_GE(ns.size(), 2u);
    EXPECT_EQ(ns[0], "http://opcfoundation.org/UA/");
    UInt16 i = c.namespaceIndex(kDemoUri);
    EXPECT_GE(i, 1);
    EXPECT_EQ(ns.at(i), kDemoUri);
    EXPECT_EQ(c.parseNodeId("nsu=urn:pnp:demo;s=Demo"), NodeId(i, "Demo"));
    EXPECT_EQ(errorOf([&] { c.namespaceIndex("urn:not:there"); }), status::BadNotFound);
}

TEST_F(Interop, WriteAndReadBackEveryScalar) {
    Client c;
    connect(c);
    for (const auto& d : demoValues()) {
        SCOPED_TRACE("Scalar." + d.type);
        NodeId id(demo, "Scalar." + d.type);
        EXPECT_EQ(c.writeValue(id, d.scalar), StatusCode{});
        Variant back = c.readValue(id);
        EXPECT_EQ(back, d.scalar) << "wrote " << d.scalar.toString() << "\nread  "
                                  << back.toString();
    }
}

TEST_F(Interop, WriteAndReadBackEveryArray) {
    Client c;
    connect(c);
    for (const auto& d : demoValues()) {
        SCOPED_TRACE("Array." + d.type);
        NodeId id(demo, "Array." + d.type);
        EXPECT_EQ(c.writeValue(id, d.array), StatusCode{});
        Variant back = c.readValue(id);
        EXPECT_EQ(back, d.array) << "wrote " << d.array.toString() << "\nread  " << back.toString();
    }
}

TEST_F(Interop, WriteManyAtOnce) {
    Client c;
    connect(c);
    std::vector<WriteValue> ws;
    for (const auto& d : demoValues()) {
        WriteValue w{};
        w.nodeId = NodeId(demo, "Scalar." + d.type);
        w.attributeId = 13;
        w.value = DataValue(d.scalar);
        ws.push_back(std::move(w));
    }
    WriteValue bad{};
    bad.nodeId = NodeId(demo, "Scalar.Int32");
    bad.attributeId = 13;
    bad.value = DataValue(Variant(String("not an Int32")));
    ws.push_back(bad);
    auto results = c.write(ws);
    ASSERT_EQ(results.size(), ws.size());
    for (std::size_t i = 0; i + 1 < results.size(); ++i) EXPECT_EQ(results[i], StatusCode{}) << i;
    EXPECT_TRUE(results.back().isBad()) << results.back().toString();  // BadTypeMismatch
}

TEST_F(Interop, CallEchoAndAdd) {
    Client c;
    connect(c);
    NodeId obj(demo, "Demo");
    std::string payload;
    for (int i = 0; i < 1000; ++i) payload.push_back(static_cast<char>(i % 256));
    CallResult echo = c.call(obj, NodeId(demo, "Demo.Echo"), {ByteString(payload)});
    ASSERT_TRUE(echo.ok()) << echo.status.toString();
    ASSERT_EQ(echo.outputs.size(), 1u);
    EXPECT_EQ(echo.outputs[0], Variant(ByteString(payload)));
    // Large payloads leave our client by scatter-gather (one chunk) or joined (several).
    for (std::size_t n : {20000u, 300000u}) {
        std::string big(n, '\0');
        for (std::size_t i = 0; i < n; ++i) big[i] = static_cast<char>((i * 31) >> 3);
        CallResult r = c.call(obj, NodeId(demo, "Demo.Echo"), {ByteString(big)});
        ASSERT_TRUE(r.ok()) << n << ": " << r.status.toString();
        ASSERT_EQ(r.outputs.size(), 1u);
        EXPECT_EQ(r.outputs[0], Variant(ByteString(big))) << n << " bytes";
    }

    CallResult add = c.call(obj, NodeId(demo, "Demo.Add"), {Int32{2}, Int32{3}});
    ASSERT_TRUE(add.ok()) << add.status.toString();
    ASSERT_EQ(add.outputs.size(), 1u);
    EXPECT_EQ(add.outputs[0], Variant(Int32{5}));
    CallResult wrap =
        c.call(obj, NodeId(demo, "Demo.Add"), {Int32{std::numeric_limits<Int32>::max()}, Int32{1}});
    EXPECT_EQ(wrap.outputs.at(0), Variant(Int32{std::numeric_limits<Int32>::min()}));

    // Wrong types: a Bad status in the result, not an exception.
    CallResult wrong = c.call(obj, NodeId(demo, "Demo.Add"), {String("2"), Int32{3}});
    EXPECT_FALSE(wrong.ok());
    EXPECT_TRUE(wrong.status == status::BadInvalidArgument ||
                wrong.status == status::BadTypeMismatch)
        << wrong.status.toString();
    CallResult missing = c.call(obj, NodeId(demo, "Demo.Add"), {Int32{1}});
    EXPECT_FALSE(missing.ok());
    EXPECT_EQ(missing.status, status::BadArgumentsMissing);

    // Several calls in one request.
    CallMethodRequest m1{};
    m1.objectId = obj;
    m1.methodId = NodeId(demo, "Demo.Add");
    m1.inputArguments = {Int32{10}, Int32{20}};
    CallMethodRequest m2 = m1;
    m2.methodId = NodeId(demo, "Demo.Nope");
    auto rs = c.call({m1, m2});
    ASSERT_EQ(rs.size(), 2u);
    EXPECT_EQ(rs[0].outputArguments.at(0), Variant(Int32{30}));
    EXPECT_TRUE(rs[1].statusCode.isBad());
}

TEST_F(Interop, UnknownNode) {
    Client c;
    connect(c);
    NodeId nope(demo, "NoSuchNode");
    EXPECT_EQ(c.readAttribute(nope, AttributeId::Value).statusOrGood(), status::BadNodeIdUnknown);
    EXPECT_EQ(errorOf([&] { c.readValue(nope); }), status::BadNodeIdUnknown);
    EXPECT_EQ(c.writeValue(nope, Int32{1}), status::BadNodeIdUnknown);
    EXPECT_EQ(errorOf([&] { c.browse(nope); }), status::BadNodeIdUnknown);
    EXPECT_TRUE(c.call(nope, NodeId(demo, "Demo.Add"), {Int32{1}, Int32{2}}).status.isBad());
    // The session is still fine.
    EXPECT_NO_THROW(c.readValue(NodeId(0, ns0::Server_ServerStatus_CurrentTime)));
}

TEST_F(Interop, RegisterAndUnregisterNodes) {
    Client c;
    connect(c);
    auto ids = c.registerNodes({NodeId(demo, "Scalar.Int32"), NodeId(demo, "Scalar.Double")});
    ASSERT_EQ(ids.size(), 2u);
    EXPECT_EQ(c.writeValue(ids[0], Int32{99}), StatusCode{});
    EXPECT_EQ(c.readValue(ids[0]), Variant(Int32{99}));
    EXPECT_EQ(c.readValue(NodeId(demo, "Scalar.Int32")), Variant(Int32{99}));
    EXPECT_NO_THROW(c.unregisterNodes(ids));
}

TEST_F(Interop, ReconnectAfterTheConnectionDropped) {
    Client c;
    connect(c);
    NodeId sessionBefore = c.sessionId();
    NodeId node(demo, "Scalar.Int32");
    EXPECT_EQ(c.writeValue(node, Int32{1}), StatusCode{});

    // Break the socket under the client: the Read is retried on a new channel.
    ::shutdown(c.nativeHandle(), SHUT_RDWR);
    EXPECT_EQ(c.readValue(node), Variant(Int32{1}));
    auto st = c.stats();
    EXPECT_EQ(st.reconnects, 1u);
    EXPECT_EQ(st.sessionsReactivated + (st.sessionsCreated - 1), 1u);
    EXPECT_EQ(st.sessionsReactivated, 1u) << "node-opcua should accept ActivateSession of the "
                                             "existing session on a new channel";
    EXPECT_EQ(c.sessionId(), sessionBefore);

    // A Write whose send fails is sent again too.
    ::shutdown(c.nativeHandle(), SHUT_RDWR);
    EXPECT_EQ(c.writeValue(node, Int32{2}), StatusCode{});
    EXPECT_EQ(c.readValue(node), Variant(Int32{2}));
    EXPECT_EQ(c.stats().reconnects, 2u);

    // With the background thread, the drop is repaired without any call.
    c.startBackgroundThread();
    ::shutdown(c.nativeHandle(), SHUT_RDWR);
    auto end = Clock::now() + 5s;
    while (Clock::now() < end && c.stats().reconnects < 3) std::this_thread::sleep_for(10ms);
    EXPECT_EQ(c.stats().reconnects, 3u);
    EXPECT_EQ(c.readValue(node), Variant(Int32{2}));
}

TEST_F(Interop, RequestDeadlines) {
    Client c;
    connect(c);
    NodeId t(0, ns0::Server_ServerStatus_CurrentTime);
    // A deadline that passed before sending: BadTimeout at once, nothing is sent.
    auto sent = c.stats().requestsSent;
    auto t0 = Clock::now();
    EXPECT_EQ(errorOf([&] { c.readValue(t, Clock::now() - 1s); }), status::BadTimeout);
    EXPECT_EQ(errorOf([&] { c.readValue(t, std::chrono::nanoseconds(1)); }), status::BadTimeout);
    EXPECT_LT(Clock::now() - t0, 50ms);
    EXPECT_EQ(c.stats().requestsSent, sent);
    // A deadline shorter than node-opcua's response time: sent, then BadTimeout.
    int timedOut = 0;
    for (int i = 0; i < 50 && timedOut == 0; ++i)
        if (errorOf([&] { c.readValue(t, std::chrono::microseconds(50)); }) == status::BadTimeout)
            ++timedOut;
    ASSERT_EQ(timedOut, 1);
    // Usable afterwards; the late response is discarded.
    std::this_thread::sleep_for(50ms);
    for (int i = 0; i < 5; ++i) EXPECT_NO_THROW(c.readValue(t));
    EXPECT_GE(c.stats().discardedResponses, 1u);
    EXPECT_EQ(c.stats().reconnects, 0u);
}

TEST_F(Interop, AsyncCalls) {
    Client c;
    connect(c);
    NodeId node(demo, "Scalar.Int32");
    c.writeValue(node, Int32{123});
    std::optional<Result<Variant>> got;
    c.readValueAsync(node, [&](Result<Variant> r) { got = std::move(r); });
    for (int i = 0; i < 200 && !got; ++i) c.runIterate(20ms);
    ASSERT_TRUE(got);
    EXPECT_EQ(got->value(), Variant(Int32{123}));

    std::optional<Result<CallResult>> call;
    c.callAsync(NodeId(demo, "Demo"), NodeId(demo, "Demo.Add"), {Int32{20}, Int32{22}},
                [&](Result<CallResult> r) { call = std::move(r); });
    for (int i = 0; i < 200 && !call; ++i) c.runIterate(20ms);
    ASSERT_TRUE(call);
    EXPECT_EQ(call->value().outputs.at(0), Variant(Int32{42}));

    c.startBackgroundThread();
    std::vector<std::future<ReadResponse>> fs;
    for (int i = 0; i < 10; ++i) {
        ReadRequest req{};
        req.timestampsToReturn = TimestampsToReturn::Neither;
        ReadValueId id{};
        id.nodeId = node;
        id.attributeId = 13;
        req.nodesToRead.push_back(id);
        fs.push_back(c.requestAsync(std::move(req)));
    }
    for (auto& f : fs) {
        ASSERT_EQ(f.wait_for(5s), std::future_status::ready);
        EXPECT_EQ(f.get().results.at(0).value, Variant(Int32{123}));
    }
}

TEST_F(Interop, DisconnectAndDestructorCloseCleanly) {
    Client c;
    c.connect(url);
    c.disconnect();
    EXPECT_FALSE(c.isConnected());
    c.connect(url, UserName{"operator", "secret"});
    EXPECT_NO_THROW(c.readValue(NodeId(0, ns0::Server_ServerStatus_CurrentTime)));
    // The destructor closes the session and the channel.
}

}  // namespace
}  // namespace pnp::ua::client

int main(int argc, char** argv) {
    ::testing::InitGoogleTest(&argc, argv);
    pnp::ua::client::g_server = new pnp::ua::client::NodeServer;
    ::testing::AddGlobalTestEnvironment(pnp::ua::client::g_server);  // owned by gtest
    return RUN_ALL_TESTS();
}
