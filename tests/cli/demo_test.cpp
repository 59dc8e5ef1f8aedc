// In-process tests of the demo namespace (src/ua/demo): the nodes as demo_types.js specifies
// them, the methods, and the asynchronous Sleep with its limits and shutdown.
#include "ua/demo/demo.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <limits>
#include <mutex>
#include <thread>

#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::demo {
namespace {

using server::AddressSpace;
using server::AttributeId;
using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

// Collects the asynchronous completion of one AddressSpace::call.
struct Pending {
    std::mutex m;
    std::condition_variable cv;
    std::optional<CallResponse> response;

    std::function<void(CallResponse)> callback() {
        return [this](CallResponse r) {
            std::lock_guard l(m);
            response = std::move(r);
            cv.notify_all();
        };
    }
    bool done() {
        std::lock_guard l(m);
        return response.has_value();
    }
    StatusCode wait(milliseconds timeout = milliseconds(10000)) {
        std::unique_lock l(m);
        if (!cv.wait_for(l, timeout, [&] { return response.has_value(); }))
            return status::BadTimeout;
        if (response->results.size() != 1) return status::BadUnexpectedError;
        return response->results[0].statusCode;
    }
};

CallRequest request(UInt16 ns, const std::string& method, std::vector<Variant> inputs) {
    CallRequest r;
    CallMethodRequest m;
    m.objectId = NodeId(ns, "Demo");
    m.methodId = NodeId(ns, method);
    m.inputArguments = std::move(inputs);
    r.methodsToCall.push_back(std::move(m));
    return r;
}

CallMethodResult callSync(AddressSpace& as, UInt16 ns, const std::string& method,
                          std::vector<Variant> inputs) {
    CallResponse r = as.callSync(request(ns, method, std::move(inputs)));
    EXPECT_EQ(r.results.size(), 1u);
    return r.results.empty() ? CallMethodResult{} : r.results[0];
}

class DemoTest : public ::testing::Test {
  protected:
    AddressSpace as;
};

TEST_F(DemoTest, NamespaceAndObject) {
    UInt16 ns = addDemoNamespace(as);
    EXPECT_EQ(as.namespaceIndex(kNamespaceUri), ns);
    auto nsArray = as.namespaceArray();
    ASSERT_GT(nsArray.size(), ns);
    EXPECT_EQ(nsArray[ns], "urn:pnp:demo");
    const NodeId demo(ns, "Demo");
    EXPECT_EQ(as.nodeClass(demo), NodeClass::Object);
    QualifiedName name{ns, "Demo"};
    EXPECT_EQ(as.resolvePath(NodeId(0, ns0::ObjectsFolder), std::span(&name, 1)), demo);
}

TEST_F(DemoTest, EveryBuiltinTypeAsScalarAndArray) {
    UInt16 ns = addDemoNamespace(as);
    ASSERT_EQ(demoTypes().size(), 25u);
    for (BuiltinType t : demoTypes()) {
        for (bool array : {false, true}) {
            const std::string name = (array ? "Array." : "Scalar.") + std::string(toString(t));
            SCOPED_TRACE(name);
            const NodeId id(ns, name);
            ASSERT_EQ(as.nodeClass(id), NodeClass::Variable);
            DataValue dt = as.readAttribute(id, AttributeId::DataType);
            ASSERT_TRUE(dt.value && dt.value->scalar<NodeId>());
            EXPECT_EQ(*dt.value->scalar<NodeId>(), demoDataType(t));
            DataValue rank = as.readAttribute(id, AttributeId::ValueRank);
            ASSERT_TRUE(rank.value && rank.value->scalar<Int32>());
            EXPECT_EQ(*rank.value->scalar<Int32>(), array ? 1 : -1);
            DataValue access = as.readAttribute(id, AttributeId::AccessLevel);
            ASSERT_TRUE(access.value && access.value->scalar<Byte>());
            EXPECT_EQ(*access.value->scalar<Byte>() & 3, 3);
            DataValue v = as.readValue(id);
            ASSERT_TRUE(v.value);
            EXPECT_EQ(*v.value, array ? demoInitialArray(t) : demoInitialScalar(t));
            EXPECT_EQ(v.value->isArray(), array);
        }
    }
    EXPECT_EQ(demoDataType(BuiltinType::ExtensionObject), NodeId(0, ns0::Structure));
    EXPECT_EQ(demoDataType(BuiltinType::Variant), NodeId(0, ns0::BaseDataType));
    EXPECT_EQ(demoDataType(BuiltinType::DiagnosticInfo), NodeId(0, ns0::DiagnosticInfo));
    EXPECT_EQ(*demoInitialScalar(BuiltinType::Variant).scalar<Int32>(), 0);
    EXPECT_TRUE(demoInitialScalar(BuiltinType::ExtensionObject).scalar<ExtensionObject>());
}

TEST_F(DemoTest, AddAndEcho) {
    UInt16 ns = addDemoNamespace(as);
    CallMethodResult r = callSync(as, ns, "Demo.Add", {Int32{2}, Int32{3}});
    EXPECT_TRUE(r.statusCode.isGood()) << r.statusCode.toString();
    ASSERT_EQ(r.outputArguments.size(), 1u);
    EXPECT_EQ(r.outputArguments[0], Variant(Int32{5}));

    r = callSync(as, ns, "Demo.Add", {std::numeric_limits<Int32>::max(), Int32{1}});
    ASSERT_EQ(r.outputArguments.size(), 1u);
    EXPECT_EQ(r.outputArguments[0], Variant(std::numeric_limits<Int32>::min()));

    r = callSync(as, ns, "Demo.Add", {String("two"), Int32{3}});
    EXPECT_TRUE(r.statusCode == status::BadTypeMismatch ||
                r.statusCode == status::BadInvalidArgument)
        << r.statusCode.toString();

    const ByteString data(std::string("\x00PNP\xff", 5));
    r = callSync(as, ns, "Demo.Echo", {data});
    EXPECT_TRUE(r.statusCode.isGood()) << r.statusCode.toString();
    ASSERT_EQ(r.outputArguments.size(), 1u);
    EXPECT_EQ(r.outputArguments[0], Variant(data));
}

TEST_F(DemoTest, SleepCompletesLaterOnAnotherThread) {
    DemoNamespace demo(as);
    Pending p;
    const auto t0 = Clock::now();
    as.call(request(demo.namespaceIndex(), "Demo.Sleep", {UInt32{150}}), {}, p.callback());
    // call() returned at once: the worker completes it.
    EXPECT_LT(Clock::now() - t0, milliseconds(100));
    EXPECT_FALSE(p.done());
    EXPECT_EQ(demo.pendingSleeps(), 1u);
    EXPECT_EQ(p.wait(), status::Good);
    EXPECT_GE(Clock::now() - t0, milliseconds(150));
    EXPECT_EQ(demo.pendingSleeps(), 0u);
    EXPECT_TRUE(p.response->results[0].outputArguments.empty());
}

TEST_F(DemoTest, SleepsRunConcurrently) {
    DemoNamespace demo(as);
    std::vector<std::unique_ptr<Pending>> calls;
    const auto t0 = Clock::now();
    for (int i = 0; i < 10; ++i) {
        calls.push_back(std::make_unique<Pending>());
        // Different durations, issued longest first: the timer queue orders them.
        as.call(request(demo.namespaceIndex(), "Demo.Sleep", {UInt32(300 - 20 * i)}), {},
                calls.back()->callback());
    }
    for (auto& c : calls) EXPECT_EQ(c->wait(), status::Good);
    EXPECT_LT(Clock::now() - t0, milliseconds(2000));  // serialised: >= 2.1 s
}

TEST_F(DemoTest, SleepLimits) {
    DemoOptions o;
    o.maxPendingSleeps = 2;
    o.maxSleep = milliseconds(1000);
    DemoNamespace demo(as, o);
    const UInt16 ns = demo.namespaceIndex();
    EXPECT_EQ(callSync(as, ns, "Demo.Sleep", {UInt32{1001}}).statusCode, status::BadOutOfRange);
    Pending a, b, c;
    as.call(request(ns, "Demo.Sleep", {UInt32{200}}), {}, a.callback());
    as.call(request(ns, "Demo.Sleep", {UInt32{200}}), {}, b.callback());
    as.call(request(ns, "Demo.Sleep", {UInt32{200}}), {}, c.callback());
    EXPECT_EQ(c.wait(), status::BadTooManyOperations);
    EXPECT_EQ(a.wait(), status::Good);
    EXPECT_EQ(b.wait(), status::Good);
    EXPECT_EQ(callSync(as, ns, "Demo.Sleep", {UInt32{0}}).statusCode, status::Good);
}

TEST_F(DemoTest, DestroyingTheOwnerCompletesPendingSleeps) {
    Pending p;
    auto demo = std::make_unique<DemoNamespace>(as);
    const UInt16 ns = demo->namespaceIndex();
    as.call(request(ns, "Demo.Sleep", {UInt32{30000}}), {}, p.callback());
    const auto t0 = Clock::now();
    demo.reset();  // joins the worker
    EXPECT_EQ(p.wait(milliseconds(1000)), status::BadShutdown);
    EXPECT_LT(Clock::now() - t0, milliseconds(1000));
    // The method stays; later calls fail at once.
    EXPECT_EQ(callSync(as, ns, "Demo.Sleep", {UInt32{10}}).statusCode, status::BadShutdown);
}

TEST(DemoLifetime, AddressSpaceDestructionJoinsTheWorker) {
    Pending p;
    {
        AddressSpace as;
        UInt16 ns = addDemoNamespace(as);
        as.call(request(ns, "Demo.Sleep", {UInt32{30000}}), {}, p.callback());
    }
    EXPECT_EQ(p.wait(milliseconds(1000)), status::BadShutdown);
}

TEST(DemoServer, AddsToAServer) {
    server::ServerConfig c;
    c.host = "127.0.0.1";
    c.port = 0;
    server::Server s(c);
    DemoNamespace demo(s);
    EXPECT_EQ(s.addressSpace().namespaceIndex(kNamespaceUri), demo.namespaceIndex());
    EXPECT_EQ(demo.nodeId("Demo"), NodeId(demo.namespaceIndex(), "Demo"));
    EXPECT_THROW(addDemoNamespace(s), server::AddressSpaceError);  // nodes exist already
}

}  // namespace
}  // namespace pnp::ua::demo
