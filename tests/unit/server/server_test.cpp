// The server's session and dispatch layer, exercised by our client over real sockets.
#include "ua/server/server.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>

#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp::ua;
using namespace std::chrono_literals;
using client::Client;
using pnp::testing::errorOf;
using pnp::testing::url;

namespace {

server::ServerConfig testConfig() {
    server::ServerConfig c = pnp::testing::loopbackConfig();
    c.applicationUri = "urn:pnp:test";
    return c;
}

}  // namespace

TEST(Server, ServesTheServerObject) {
    server::Server server(testConfig());
    server.start();
    Client c;
    c.connect(url(server));

    auto status = c.readValue(NodeId(0, ns0::Server_ServerStatus));
    ASSERT_NE(status.scalar<ExtensionObject>(), nullptr);
    auto decoded = fromExtensionObject<ServerStatusDataType>(*status.scalar<ExtensionObject>());
    ASSERT_TRUE(decoded);
    EXPECT_EQ(decoded->state, ServerState::Running);
    auto skew = decoded->currentTime.toUnixNanos() - DateTime::now().toUnixNanos();
    EXPECT_LT(std::abs(skew), 5'000'000'000LL);

    auto ns = c.namespaceArray();
    ASSERT_GE(ns.size(), 2u);
    EXPECT_EQ(ns[0], "http://opcfoundation.org/UA/");
    EXPECT_EQ(ns[1], "urn:pnp:test");

    auto state = c.readValue(NodeId(0, ns0::Server_ServerStatus_State));
    ASSERT_NE(state.scalar<Int32>(), nullptr);
    EXPECT_EQ(*state.scalar<Int32>(), 0);
    auto maxRead =
        c.readValue(NodeId(0, ns0::Server_ServerCapabilities_OperationLimits_MaxNodesPerRead));
    ASSERT_NE(maxRead.scalar<UInt32>(), nullptr);
    EXPECT_EQ(*maxRead.scalar<UInt32>(), testConfig().limits.maxNodesPerRead);

    auto refs = c.browse(NodeId(0, ns0::ObjectsFolder));
    bool hasServer = false;
    for (const auto& r : refs) hasServer |= r.nodeId.nodeId == NodeId(0, ns0::Server);
    EXPECT_TRUE(hasServer);

    auto endpoints = c.getEndpoints();
    ASSERT_EQ(endpoints.size(), 1u);
    EXPECT_EQ(endpoints[0].securityMode, MessageSecurityMode::None);
    EXPECT_EQ(endpoints[0].server.applicationUri, "urn:pnp:test");
    auto servers = c.findServers();
    ASSERT_EQ(servers.size(), 1u);
    EXPECT_EQ(servers[0].applicationType, ApplicationType::Server);
}

TEST(Server, EnforcesOperationLimits) {
    auto cfg = testConfig();
    cfg.limits.maxNodesPerRead = 2;
    server::Server server(cfg);
    server.start();
    Client c;
    c.connect(url(server));
    ReadValueId id;
    id.nodeId = NodeId(0, ns0::Server_ServerStatus_State);
    id.attributeId = 13;
    EXPECT_EQ(errorOf([&] { c.read({id, id, id}); }), status::BadTooManyOperations);
    EXPECT_EQ(errorOf([&] { c.read({}); }), status::BadNothingToDo);
    EXPECT_EQ(c.read({id, id}).size(), 2u);
}

TEST(Server, UnsupportedServiceAnswersBadServiceUnsupported) {
    server::Server server(testConfig());
    server.start();
    Client c;
    c.connect(url(server));
    AddNodesRequest req;
    req.nodesToAdd.resize(1);
    EXPECT_EQ(errorOf([&] { c.request(req); }), status::BadServiceUnsupported);
    // The session keeps working afterwards.
    EXPECT_NO_THROW(c.readValue(NodeId(0, ns0::Server_ServerStatus_CurrentTime)));
}

TEST(Server, RefusesSessionsBeyondTheLimit) {
    auto cfg = testConfig();
    cfg.maxSessions = 2;
    server::Server server(cfg);
    server.start();
    Client a, b, c;
    a.connect(url(server));
    b.connect(url(server));
    EXPECT_EQ(errorOf([&] { c.connect(url(server)); }), status::BadTooManySessions);
    a.disconnect();
    // CloseSession frees the slot.
    EXPECT_NO_THROW(c.connect(url(server)));
}

TEST(Server, UserNameAccessControl) {
    auto cfg = testConfig();
    cfg.accessControl = std::make_shared<server::DefaultAccessControl>(
        false, std::map<std::string, std::string>{{"operator", "secret"}});
    server::Server server(cfg);
    server.start();
    Client c;
    EXPECT_EQ(errorOf([&] { c.connect(url(server)); }), status::BadIdentityTokenRejected);
    EXPECT_EQ(errorOf([&] {
                  c.connect(url(server), client::UserName{"operator", "wrong"});
              }),
              status::BadUserAccessDenied);
    EXPECT_EQ(errorOf([&] {
                  c.connect(url(server), client::UserName{"nobody", "secret"});
              }),
              status::BadUserAccessDenied);
    EXPECT_NO_THROW(c.connect(url(server), client::UserName{"operator", "secret"}));
    EXPECT_NO_THROW(c.readValue(NodeId(0, ns0::Server_ServerStatus_CurrentTime)));
    auto policies = c.getEndpoints().at(0).userIdentityTokens;
    ASSERT_EQ(policies.size(), 1u);
    EXPECT_EQ(policies[0].tokenType, UserTokenType::UserName);
}

TEST(Server, SessionsTimeOut) {
    auto cfg = testConfig();
    cfg.minSessionTimeoutMs = 300;
    server::Server server(cfg);
    server.start();
    client::ClientConfig cc;
    cc.requestedSessionTimeout = 300ms;
    Client c(cc);
    c.connect(url(server));
    EXPECT_EQ(c.sessionTimeout(), 300);
    EXPECT_EQ(server.sessionCount(), 1u);
    // Idle beyond the timeout (plus the server's check period): the session is gone.
    auto until = std::chrono::steady_clock::now() + 5s;
    while (server.sessionCount() != 0 && std::chrono::steady_clock::now() < until)
        std::this_thread::sleep_for(50ms);
    EXPECT_EQ(server.sessionCount(), 0u);
}

TEST(Server, WriteChecksTypesAndAccess) {
    server::Server server(testConfig());
    auto& as = server.addressSpace();
    UInt16 ns = server.addNamespace("urn:pnp:test:nodes");
    server::VariableAttributes rw;
    rw.dataType = NodeId(0, ns0::Int32);
    rw.value = DataValue(Variant(Int32(1)));
    rw.accessLevel = server::access_level::CurrentRead | server::access_level::CurrentWrite;
    as.addVariable(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "rw"), QualifiedName{ns, "rw"}, rw);
    auto ro = rw;
    ro.accessLevel = server::access_level::CurrentRead;
    as.addVariable(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "ro"), QualifiedName{ns, "ro"}, ro);
    server.start();
    Client c;
    c.connect(url(server));
    EXPECT_EQ(c.writeValue(NodeId(ns, "rw"), Int32(5)), status::Good);
    EXPECT_EQ(*c.readValue(NodeId(ns, "rw")).scalar<Int32>(), 5);
    EXPECT_EQ(c.writeValue(NodeId(ns, "rw"), Double(5)), status::BadTypeMismatch);
    EXPECT_EQ(c.writeValue(NodeId(ns, "ro"), Int32(5)), status::BadNotWritable);
    EXPECT_EQ(c.writeValue(NodeId(ns, "nope"), Int32(5)), status::BadNodeIdUnknown);
}

TEST(Server, SlowMethodDoesNotBlockOtherClients) {
    server::Server server(testConfig());
    auto& as = server.addressSpace();
    UInt16 ns = server.addNamespace("urn:pnp:test:nodes");
    std::vector<std::thread> workers;
    as.addMethod(
        NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Slow"), QualifiedName{ns, "Slow"}, {}, {},
        [&](const server::MethodCallContext&, std::vector<Variant>, server::MethodCompletion done) {
            workers.emplace_back([done] {
                std::this_thread::sleep_for(500ms);
                done.succeed({});
            });
        });
    server.start();
    Client slow, fast;
    slow.connect(url(server));
    fast.connect(url(server));
    auto begin = std::chrono::steady_clock::now();
    std::thread caller([&] {
        auto r = slow.call(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Slow"), {});
        EXPECT_TRUE(r.ok()) << r.status.toString();
    });
    std::this_thread::sleep_for(50ms);
    auto readStart = std::chrono::steady_clock::now();
    fast.readValue(NodeId(0, ns0::Server_ServerStatus_CurrentTime));
    auto readTime = std::chrono::steady_clock::now() - readStart;
    caller.join();
    auto total = std::chrono::steady_clock::now() - begin;
    EXPECT_LT(readTime, 200ms);
    EXPECT_GE(total, 500ms);
    server.post([&] {});  // workers were created on the network thread; join them here
    for (auto& w : workers) w.join();
}

// afterResponsesWritten(): in a handler, fn runs later on the handler's own thread (after the
// handler returned and its response was written); elsewhere at once.
TEST(Server, AfterResponsesWrittenRunsOnTheHandlersThreadAfterTheResponse) {
    server::Server server(testConfig());
    auto& as = server.addressSpace();
    UInt16 ns = server.addNamespace("urn:pnp:test:nodes");
    std::mutex m;
    std::condition_variable cv;
    std::thread::id handlerThread, fnThread;
    bool handlerReturned = false, ranInline = false, ranAfterReturn = false, ran = false;
    as.addMethod(
        NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Then"), QualifiedName{ns, "Then"}, {}, {},
        [&](const server::MethodCallContext&, std::vector<Variant>, server::MethodCompletion done) {
            std::lock_guard l(m);
            handlerThread = std::this_thread::get_id();
            server.afterResponsesWritten([&] {
                std::lock_guard l2(m);
                fnThread = std::this_thread::get_id();
                ranAfterReturn = handlerReturned;
                ran = true;
                cv.notify_all();
            });
            ranInline = ran;
            done.succeed({});
            handlerReturned = true;
        });
    server.start();
    Client c;
    c.connect(url(server));
    auto r = c.call(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Then"), {});
    EXPECT_TRUE(r.ok()) << r.status.toString();
    std::unique_lock l(m);
    ASSERT_TRUE(cv.wait_for(l, 5s, [&] { return ran; }));
    EXPECT_FALSE(ranInline);
    EXPECT_TRUE(ranAfterReturn);
    EXPECT_EQ(fnThread, handlerThread);
    l.unlock();

    bool atOnce = false;
    server.afterResponsesWritten([&] { atOnce = true; });  // not the network thread
    EXPECT_TRUE(atOnce);
}

// Large ByteStrings travel as splices (referenced, not copied) in requests and responses: a
// single chunk is written from where the bytes are, several chunks are joined first. Either
// way the bytes arrive unchanged, also when the method completes later on another thread.
TEST(Server, LargeByteStringsArriveIntactInOneOrManyChunks) {
    server::Server server(testConfig());
    auto& as = server.addressSpace();
    UInt16 ns = server.addNamespace("urn:pnp:test:nodes");
    std::vector<std::thread> workers;
    std::mutex workersMutex;
    auto echo = [&](const server::MethodCallContext&, std::vector<Variant> in,
                    server::MethodCompletion done) {
        bool later = !in.empty() && in[0].scalar<ByteString>() != nullptr &&
                     in[0].scalar<ByteString>()->size() % 2 == 1;
        if (!later) {
            done.succeed(std::move(in));
            return;
        }
        std::lock_guard lock(workersMutex);
        workers.emplace_back([done, in = std::move(in)]() mutable {
            std::this_thread::sleep_for(5ms);
            done.succeed(std::move(in));
        });
    };
    auto arg = [](const char* name, UInt32 type, Int32 valueRank) {
        Argument a;
        a.name = name;
        a.dataType = NodeId(0, type);
        a.valueRank = valueRank;
        return a;
    };
    std::vector<Argument> args{arg("A", ns0::ByteString, -1), arg("B", ns0::Int32, -1),
                               arg("C", ns0::ByteString, 1)};
    as.addMethod(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Echo"), QualifiedName{ns, "Echo"}, args,
                 args, echo);
    server.start();
    Client c;
    c.connect(url(server));
    auto bytes = [](std::size_t n, char seed) {
        std::string s(n, '\0');
        for (std::size_t i = 0; i < n; ++i) s[i] = static_cast<char>(seed + i * 7 + (i >> 9));
        return ByteString(std::move(s));
    };
    // Below and at the splice threshold, one chunk and several chunks.
    for (std::size_t n : std::initializer_list<std::size_t>{
             4096, kDefaultSpliceMin - 1, kDefaultSpliceMin, 20001, 65000, 200000, 200001}) {
        std::vector<Variant> in{
            Variant(bytes(n, 'a')), Variant(Int32(7)),
            Variant(std::vector<ByteString>{bytes(5000, 'b'), bytes(10, 'c'), bytes(n, 'd')})};
        std::vector<Variant> expected = in;
        auto r = c.call(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Echo"), std::move(in));
        ASSERT_TRUE(r.ok()) << n << ": " << r.status.toString();
        EXPECT_EQ(r.outputs, expected) << n << " bytes";
    }
    {
        std::lock_guard lock(workersMutex);
        for (auto& w : workers) w.join();
    }
}
