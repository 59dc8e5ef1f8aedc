// Call (OPC 10000-4 §5.11.2): method lookup, argument checks, synchronous and asynchronous
// handlers.
#include <chrono>
#include <future>
#include <optional>
#include <thread>

#include "test_util.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_methods.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server::test {
namespace {

struct Call : AddressSpaceFixture {
    NodeId calc;
    NodeId add;

    void SetUp() override {
        calc = space.addObject(ns0(ns0::ObjectsFolder), id("Calc"), name("Calc"));
        add = space.addMethod(
            calc, id("Calc.Add"), name("Add"),
            {argument("a", ns0::Int32), argument("b", ns0::Int32)}, {argument("sum", ns0::Int32)},
            makeMethodHandler([](const MethodCallContext&, const std::vector<Variant>& in,
                                 std::vector<Variant>& out) {
                out.push_back(Variant(*in[0].scalar<Int32>() + *in[1].scalar<Int32>()));
                return StatusCode{};
            }));
    }

    CallMethodRequest request(const NodeId& object, const NodeId& method, std::vector<Variant> in) {
        CallMethodRequest r;
        r.objectId = object;
        r.methodId = method;
        r.inputArguments = std::move(in);
        return r;
    }
    CallMethodResult callOne(CallMethodRequest r) {
        CallRequest req;
        req.methodsToCall.push_back(std::move(r));
        auto resp = space.callSync(req);
        EXPECT_EQ(resp.results.size(), 1u);
        return resp.results.empty() ? CallMethodResult{} : resp.results[0];
    }
};

TEST_F(Call, MethodNodeAndArgumentProperties) {
    EXPECT_EQ(space.nodeClass(add), std::optional<NodeClass>(NodeClass::Method));
    auto in = space.resolvePath(add, std::vector<QualifiedName>{{0, "InputArguments"}});
    ASSERT_TRUE(in.has_value());
    EXPECT_EQ(*in, id("Calc.Add.InputArguments"));
    auto v = space.readValue(*in);
    const auto* objs = v.value->array<ExtensionObject>();
    ASSERT_NE(objs, nullptr);
    ASSERT_EQ(objs->size(), 2u);
    EXPECT_EQ(fromExtensionObject<Argument>((*objs)[1])->name, "b");
    EXPECT_EQ(*space.readAttribute(*in, AttributeId::ArrayDimensions).value->array<UInt32>(),
              std::vector<UInt32>{2});
    EXPECT_TRUE(
        space.resolvePath(add, std::vector<QualifiedName>{{0, "OutputArguments"}}).has_value());
}

TEST_F(Call, SynchronousHandler) {
    auto r = callOne(request(calc, add, {Variant(Int32{2}), Variant(Int32{40})}));
    ASSERT_TRUE(r.statusCode.isGood()) << r.statusCode.toString();
    ASSERT_EQ(r.outputArguments.size(), 1u);
    EXPECT_EQ(*r.outputArguments[0].scalar<Int32>(), 42);
    EXPECT_TRUE(r.inputArgumentResults.empty());
}

TEST_F(Call, ArgumentChecks) {
    EXPECT_EQ(callOne(request(calc, add, {Variant(Int32{1})})).statusCode,
              status::BadArgumentsMissing);
    EXPECT_EQ(callOne(request(calc, add, {Variant(Int32{1}), Variant(Int32{1}), Variant(Int32{1})}))
                  .statusCode,
              status::BadTooManyArguments);
    auto r = callOne(request(calc, add, {Variant(Int32{1}), Variant(2.0)}));
    EXPECT_EQ(r.statusCode, status::BadInvalidArgument);
    ASSERT_EQ(r.inputArgumentResults.size(), 2u);
    EXPECT_TRUE(r.inputArgumentResults[0].isGood());
    EXPECT_EQ(r.inputArgumentResults[1], status::BadTypeMismatch);
    EXPECT_TRUE(r.outputArguments.empty());
    auto rank = callOne(request(calc, add, {Variant(std::vector<Int32>{1}), Variant()}));
    EXPECT_EQ(rank.statusCode, status::BadInvalidArgument);
    ASSERT_EQ(rank.inputArgumentResults.size(), 2u);
    EXPECT_EQ(rank.inputArgumentResults[0], status::BadTypeMismatch);  // array for a scalar
    EXPECT_EQ(rank.inputArgumentResults[1], status::BadTypeMismatch);  // null
}

TEST_F(Call, ArgumentSubtypesAndRanks) {
    NodeId m =
        space.addMethod(calc, id("Calc.Mixed"), name("Mixed"),
                        {argument("n", ns0::Number), argument("t", ns0::UtcTime),
                         argument("list", ns0::String, 1, {2}),
                         argument("any", ns0::BaseDataType, -2), argument("arg", ns0::Argument)},
                        {},
                        makeMethodHandler([](const MethodCallContext&, const std::vector<Variant>&,
                                             std::vector<Variant>&) { return StatusCode{}; }));
    auto ok = callOne(
        request(calc, m,
                {Variant(1.5), Variant(DateTime::now()), Variant(std::vector<String>{"a", "b"}),
                 Variant(), Variant(toExtensionObject(argument("x", ns0::Int32)))}));
    EXPECT_TRUE(ok.statusCode.isGood()) << ok.statusCode.toString();
    auto bad = callOne(request(
        calc, m,
        {Variant(String("1")), Variant(Int64{0}), Variant(std::vector<String>{"a", "b", "c"}),
         Variant(Int32{1}), Variant(toExtensionObject(EUInformation{}))}));
    EXPECT_EQ(bad.statusCode, status::BadInvalidArgument);
    ASSERT_EQ(bad.inputArgumentResults.size(), 5u);
    EXPECT_EQ(bad.inputArgumentResults[0], status::BadTypeMismatch);
    EXPECT_EQ(bad.inputArgumentResults[1], status::BadTypeMismatch);
    EXPECT_EQ(bad.inputArgumentResults[2], status::BadTypeMismatch);  // longer than dims
    EXPECT_TRUE(bad.inputArgumentResults[3].isGood());
    EXPECT_EQ(bad.inputArgumentResults[4], status::BadTypeMismatch);
}

TEST_F(Call, MethodLookup) {
    NodeId other = space.addObject(ns0(ns0::ObjectsFolder), id("Other"), name("Other"));
    EXPECT_EQ(callOne(request(other, add, {Variant(Int32{1}), Variant(Int32{1})})).statusCode,
              status::BadMethodInvalid);
    EXPECT_EQ(callOne(request(calc, id("nope"), {})).statusCode, status::BadMethodInvalid);
    EXPECT_EQ(callOne(request(calc, calc, {})).statusCode, status::BadMethodInvalid);
    EXPECT_EQ(callOne(request(id("nope"), add, {})).statusCode, status::BadNodeIdUnknown);
    NodeId var = addVar("Var", ns0::Int32, Variant(Int32{1}));
    EXPECT_EQ(callOne(request(var, add, {})).statusCode, status::BadNodeIdInvalid);
    // A namespace-0 method without an application handler.
    auto r = callOne(
        request(ns0(ns0::Server), ns0(ns0::Server_GetMonitoredItems), {Variant(UInt32{1})}));
    EXPECT_EQ(r.statusCode, status::BadNotImplemented);
    // ...whose arguments are still checked against its InputArguments property.
    EXPECT_EQ(callOne(request(ns0(ns0::Server), ns0(ns0::Server_GetMonitoredItems), {})).statusCode,
              status::BadArgumentsMissing);
    CallRequest empty;
    EXPECT_EQ(space.callSync(empty).responseHeader.serviceResult, status::BadNothingToDo);
}

TEST_F(Call, MethodOfTheObjectType) {
    NodeId type =
        space.addObjectType(ns0(ns0::BaseObjectType), id("DeviceType"), name("DeviceType"));
    NodeId sub = space.addObjectType(type, id("RobotType"), name("RobotType"));
    std::vector<NodeId> calledOn;
    NodeId reset =
        space.addMethod(type, id("DeviceType.Reset"), name("Reset"), {}, {},
                        makeMethodHandler([&](const MethodCallContext& c,
                                              const std::vector<Variant>&, std::vector<Variant>&) {
                            calledOn.push_back(c.objectId);
                            return StatusCode{};
                        }));
    NodeId robot = space.addObject(ns0(ns0::ObjectsFolder), id("Robot"), name("Robot"), {}, sub);
    EXPECT_TRUE(callOne(request(robot, reset, {})).statusCode.isGood());
    EXPECT_TRUE(callOne(request(sub, reset, {})).statusCode.isGood());   // on a subtype
    EXPECT_TRUE(callOne(request(type, reset, {})).statusCode.isGood());  // on the type itself
    EXPECT_EQ(calledOn, (std::vector<NodeId>{robot, sub, type}));
    EXPECT_EQ(callOne(request(calc, reset, {})).statusCode, status::BadMethodInvalid);
}

TEST_F(Call, ExecutableAndFailures) {
    MethodAttributes ma;
    ma.executable = false;
    NodeId off =
        space.addMethod(calc, id("Calc.Off"), name("Off"), {}, {},
                        makeMethodHandler([](auto&, auto&, auto&) { return StatusCode{}; }), ma);
    EXPECT_EQ(callOne(request(calc, off, {})).statusCode, status::BadNotExecutable);
    NodeId fails = space.addMethod(calc, id("Calc.Fails"), name("Fails"), {}, {},
                                   makeMethodHandler([](auto&, auto&, auto& out) {
                                       out.push_back(Variant(Int32{1}));  // dropped on failure
                                       return status::BadOutOfRange;
                                   }));
    auto r = callOne(request(calc, fails, {}));
    EXPECT_EQ(r.statusCode, status::BadOutOfRange);
    EXPECT_TRUE(r.outputArguments.empty());
    NodeId throws = space.addMethod(calc, id("Calc.Throws"), name("Throws"), {}, {},
                                    [](const MethodCallContext&, std::vector<Variant>,
                                       MethodCompletion) { throw std::runtime_error("boom"); });
    EXPECT_EQ(callOne(request(calc, throws, {})).statusCode, status::BadInternalError);
    NodeId forgets =
        space.addMethod(calc, id("Calc.Forgets"), name("Forgets"), {}, {},
                        [](const MethodCallContext&, std::vector<Variant>, MethodCompletion) {});
    EXPECT_EQ(callOne(request(calc, forgets, {})).statusCode, status::BadInternalError);
    // Removing the handler.
    space.setMethodHandler(fails, {});
    EXPECT_EQ(callOne(request(calc, fails, {})).statusCode, status::BadNotImplemented);
}

TEST_F(Call, AsynchronousCompletionFromAnotherThread) {
    std::vector<std::thread> workers;
    std::mutex m;
    std::thread::id completedOn;
    NodeId slow = space.addMethod(
        calc, id("Calc.Slow"), name("Slow"), {argument("ms", ns0::UInt32)},
        {argument("echo", ns0::UInt32)},
        [&](const MethodCallContext& ctx, std::vector<Variant> in, MethodCompletion done) {
            EXPECT_EQ(ctx.sessionId, NodeId(1, 77));
            UInt32 ms = *in[0].scalar<UInt32>();
            std::lock_guard lock(m);
            workers.emplace_back([&, ms, done] {
                std::this_thread::sleep_for(std::chrono::milliseconds(ms));
                completedOn = std::this_thread::get_id();
                done.succeed({Variant(ms)});
                done(status::BadInternalError);  // a second completion is ignored
            });
        });
    CallRequest req;
    req.methodsToCall = {request(calc, slow, {Variant(UInt32{60})}),
                         request(calc, add, {Variant(Int32{1}), Variant(Int32{2})}),
                         request(calc, slow, {Variant(UInt32{10})}),
                         request(calc, add, {Variant(Int32{1})})};
    std::promise<CallResponse> promise;
    auto future = promise.get_future();
    std::atomic<bool> delivered{false};
    const auto t0 = std::chrono::steady_clock::now();
    space.call(req, NodeId(1, 77), [&](CallResponse r) {
        delivered = true;
        promise.set_value(std::move(r));
    });
    // call() returned without waiting for the slow methods.
    EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::milliseconds(50));
    EXPECT_FALSE(delivered.load());
    ASSERT_EQ(future.wait_for(std::chrono::seconds(5)), std::future_status::ready);
    CallResponse resp = future.get();
    {
        std::lock_guard lock(m);
        for (auto& w : workers) w.join();
    }
    EXPECT_NE(completedOn, std::this_thread::get_id());
    ASSERT_EQ(resp.results.size(), 4u);
    EXPECT_TRUE(resp.results[0].statusCode.isGood());
    EXPECT_EQ(*resp.results[0].outputArguments[0].scalar<UInt32>(), 60u);
    EXPECT_EQ(*resp.results[1].outputArguments[0].scalar<Int32>(), 3);
    EXPECT_EQ(*resp.results[2].outputArguments[0].scalar<UInt32>(), 10u);
    EXPECT_EQ(resp.results[3].statusCode, status::BadArgumentsMissing);
}

TEST_F(Call, KeptCompletionsFailTheirMethodWhenTheLastCopyGoes) {
    std::vector<MethodCompletion> kept;
    NodeId keeps = space.addMethod(
        calc, id("Calc.Keeps"), name("Keeps"), {}, {},
        [&](const MethodCallContext&, std::vector<Variant>, MethodCompletion done) {
            kept.push_back(done);  // two copies outlive the handler, neither is invoked
            kept.push_back(done);
        });
    NodeId keepsAndThrows = space.addMethod(
        calc, id("Calc.KeepsAndThrows"), name("KeepsAndThrows"), {}, {},
        [&](const MethodCallContext&, std::vector<Variant>, MethodCompletion done) {
            kept.push_back(std::move(done));
            throw std::runtime_error("boom");  // fails the method at once despite the copy
        });
    CallRequest req;
    req.methodsToCall = {request(calc, keeps, {}), request(calc, keepsAndThrows, {}),
                         request(calc, add, {Variant(Int32{2}), Variant(Int32{3})})};
    std::optional<CallResponse> got;
    space.call(req, NodeId(), [&](CallResponse r) { got = std::move(r); });
    EXPECT_FALSE(got.has_value());  // Keeps is pending while a copy of its completion lives
    ASSERT_EQ(kept.size(), 3u);
    kept.pop_back();  // KeepsAndThrows' copy: already completed, nothing changes
    kept.pop_back();
    EXPECT_FALSE(got.has_value());
    std::thread([last = std::move(kept)]() mutable { last.clear(); }).join();
    ASSERT_TRUE(got.has_value());
    ASSERT_EQ(got->results.size(), 3u);
    EXPECT_EQ(got->results[0].statusCode, status::BadInternalError);
    EXPECT_EQ(got->results[1].statusCode, status::BadInternalError);
    ASSERT_EQ(got->results[2].outputArguments.size(), 1u);
    EXPECT_EQ(*got->results[2].outputArguments[0].scalar<Int32>(), 5);
}

TEST_F(Call, HandlerMayUseTheAddressSpace) {
    NodeId counter = addVar("Count", ns0::Int32, Variant(Int32{0}));
    NodeId inc = space.addMethod(calc, id("Calc.Inc"), name("Inc"), {}, {},
                                 makeMethodHandler([&](auto&, auto&, auto&) {
                                     Int32 v = *space.readValue(counter).value->scalar<Int32>();
                                     return space.setValue(counter, DataValue(Variant(v + 1)));
                                 }));
    for (int i = 0; i < 3; ++i) EXPECT_TRUE(callOne(request(calc, inc, {})).statusCode.isGood());
    EXPECT_EQ(*space.readValue(counter).value->scalar<Int32>(), 3);
}

}  // namespace
}  // namespace pnp::ua::server::test
