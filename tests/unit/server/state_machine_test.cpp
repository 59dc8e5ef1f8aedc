// FiniteStateMachine (OPC 10000-16, Programs of OPC 10000-10) against our client over real
// sockets: a ProgramStateMachineType instance driven through its lifecycle by method calls,
// CurrentState / LastTransition read back, Executable per state, refused transitions,
// transition events and data changes; a custom machine from an explicit description; bad
// setups.
#include "ua/server/state_machine.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "support/inbox.hpp"
#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"
#include "ua/server/server.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp::ua;
using namespace std::chrono_literals;
using pnp::testing::Inbox;
using pnp::testing::loopbackConfig;
using server::FiniteStateMachine;

namespace {

QualifiedName n0(const char* name) { return QualifiedName{0, name}; }

// A server with ns=1;s=Program (ProgramStateMachineType, with AvailableStates/Transitions)
// bound to a FiniteStateMachine, and a connected client.
struct ProgramFixture {
    server::Server server{loopbackConfig()};
    NodeId program{1, "Program"};
    std::unique_ptr<FiniteStateMachine> fsm;
    client::Client c;

    explicit ProgramFixture(FiniteStateMachine::Options options = {}) {
        server::InstantiateOptions o;
        o.optionalChildren = {n0("AvailableStates"), n0("AvailableTransitions")};
        server.addressSpace().instantiate(NodeId(0, ns0::ObjectsFolder),
                                          NodeId(0, ns0::ProgramStateMachineType), program,
                                          QualifiedName{1, "Program"}, o);
        fsm = std::make_unique<FiniteStateMachine>(server, program, options);
        server.start();
        c.connect(server.endpointUrl());
        c.startBackgroundThread();
    }

    NodeId node(std::initializer_list<const char*> path) {
        std::vector<QualifiedName> names;
        for (const char* p : path) names.push_back(n0(p));
        auto id = server.addressSpace().resolvePath(program, names);
        EXPECT_TRUE(id.has_value());
        return id.value_or(NodeId());
    }
    Variant read(std::initializer_list<const char*> path) { return c.readValue(node(path)); }
    std::string text(std::initializer_list<const char*> path) {
        Variant v = read(path);
        return v.scalar<LocalizedText>() ? v.scalar<LocalizedText>()->text : "<not text>";
    }
    NodeId id(std::initializer_list<const char*> path) {
        Variant v = read(path);
        return v.scalar<NodeId>() ? *v.scalar<NodeId>() : NodeId();
    }
    UInt32 number(std::initializer_list<const char*> path) {
        Variant v = read(path);
        return v.scalar<UInt32>() ? *v.scalar<UInt32>() : 9999;
    }
    StatusCode call(const char* method) {
        const NodeId m = fsm->method(method);
        EXPECT_FALSE(m.isNull()) << method;
        return c.call(program, m, {}).status;
    }
    bool executable(const char* method) {
        Variant v =
            c.readAttribute(fsm->method(method), AttributeId::Executable).value.value_or(Variant());
        return v.scalar<Boolean>() && *v.scalar<Boolean>();
    }
    void expectState(const char* name, UInt32 stateId, UInt32 number_) {
        EXPECT_EQ(text({"CurrentState"}), name);
        EXPECT_EQ(id({"CurrentState", "Id"}), NodeId(0, stateId)) << name;
        EXPECT_EQ(number({"CurrentState", "Number"}), number_) << name;
    }
    void expectLast(const char* name, UInt32 transitionId, UInt32 number_) {
        EXPECT_EQ(text({"LastTransition"}), name);
        EXPECT_EQ(id({"LastTransition", "Id"}), NodeId(0, transitionId)) << name;
        EXPECT_EQ(number({"LastTransition", "Number"}), number_) << name;
        Variant t = read({"LastTransition", "TransitionTime"});
        ASSERT_NE(t.scalar<DateTime>(), nullptr) << name;
        EXPECT_GT(t.scalar<DateTime>()->ticks, 0) << name;
    }
};

// The lifecycle of the test: Ready -Start-> Running -Suspend-> Suspended -Resume-> Running
// -Halt-> Halted -Reset-> Ready.
struct Step {
    const char* method;
    const char* from;
    const char* to;
    const char* transition;
    UInt32 transitionId;
};
constexpr Step kLifecycle[] = {
    {"Start", "Ready", "Running", "ReadyToRunning", 2410},
    {"Suspend", "Running", "Suspended", "RunningToSuspended", 2416},
    {"Resume", "Suspended", "Running", "SuspendedToRunning", 2418},
    {"Halt", "Running", "Halted", "RunningToHalted", 2412},
    {"Reset", "Halted", "Ready", "HaltedToReady", 2408},
};

}  // namespace

TEST(StateMachine, DerivesStatesAndTransitionsFromProgramStateMachineType) {
    ProgramFixture f;
    EXPECT_EQ(f.fsm->states().size(), 4u);
    EXPECT_EQ(f.fsm->transitions().size(), 9u);
    for (const char* m : {"Start", "Suspend", "Resume", "Halt", "Reset"})
        EXPECT_FALSE(f.fsm->method(m).isNull()) << m << " created on the instance";
    EXPECT_EQ(f.fsm->currentState().browseName.name, "Ready");
    EXPECT_FALSE(f.fsm->lastTransition().has_value());
    f.expectState("Ready", ns0::ProgramStateMachineType_Ready, 12);
}

TEST(StateMachine, ProgramLifecycleThroughMethodCalls) {
    ProgramFixture f;
    const std::vector<std::tuple<const char*, UInt32, UInt32, UInt32>> after = {
        {"Running", 2402, 13, 2}, {"Suspended", 2404, 14, 5}, {"Running", 2402, 13, 6},
        {"Halted", 2406, 11, 3},  {"Ready", 2400, 12, 1},
    };
    for (std::size_t i = 0; i < std::size(kLifecycle); ++i) {
        const Step& s = kLifecycle[i];
        ASSERT_EQ(f.call(s.method), status::Good) << s.method;
        auto [name, stateId, stateNumber, transitionNumber] = after[i];
        f.expectState(name, stateId, stateNumber);
        f.expectLast(s.transition, s.transitionId, transitionNumber);
        EXPECT_EQ(f.fsm->currentState().browseName.name, s.to);
    }
}

TEST(StateMachine, AvailableStatesAndTransitionsFollowTheState) {
    ProgramFixture f;
    auto ids = [&](const char* name) {
        Variant v = f.read({name});
        const auto* arr = v.array<NodeId>();
        return arr ? *arr : std::vector<NodeId>{};
    };
    // Ready: ReadyToRunning (Running), ReadyToHalted (Halted).
    EXPECT_EQ(ids("AvailableTransitions"), (std::vector<NodeId>{NodeId(0, 2410), NodeId(0, 2424)}));
    EXPECT_EQ(ids("AvailableStates"), (std::vector<NodeId>{NodeId(0, 2402), NodeId(0, 2406)}));
    ASSERT_EQ(f.call("Halt"), status::Good);
    EXPECT_EQ(ids("AvailableTransitions"), (std::vector<NodeId>{NodeId(0, 2408)}));
    EXPECT_EQ(ids("AvailableStates"), (std::vector<NodeId>{NodeId(0, 2400)}));
}

TEST(StateMachine, InvalidTransitionIsRefusedAndChangesNothing) {
    ProgramFixture f;
    Inbox<std::vector<Variant>> events;
    client::Subscription sub(f.c, {.publishingInterval = 10});
    auto item = sub.monitorEvents(
        NodeId(0, ns0::Server),
        {.select = {"Message"}, .where = client::whereOfType(NodeId(0, ns0::TransitionEventType))},
        [&](client::EventFields& e) { events.put(e.take()); });

    EXPECT_EQ(f.fsm->transitionTo("Suspended"), status::BadInvalidState);  // Ready -/-> Suspended
    EXPECT_EQ(f.fsm->fire("Resume"), status::BadInvalidState);
    EXPECT_EQ(f.fsm->fire("SuspendedToRunning"), status::BadInvalidState);
    EXPECT_EQ(f.fsm->transitionTo("NoSuchState"), status::BadNotFound);
    EXPECT_EQ(f.fsm->fire("NoSuchTransition"), status::BadNotFound);
    f.expectState("Ready", 2400, 12);
    EXPECT_TRUE(f.read({"LastTransition"}).isEmpty());
    EXPECT_FALSE(events.waitForCount(1, 300ms)) << "no event for a refused transition";

    // A valid one by name and by target state.
    EXPECT_EQ(f.fsm->fire("ReadyToRunning"), status::Good);
    EXPECT_EQ(f.fsm->transitionTo("Suspended"), status::Good);
    f.expectState("Suspended", 2404, 14);
    EXPECT_TRUE(events.waitForCount(2));
}

TEST(StateMachine, MethodExecutableFollowsTheState) {
    ProgramFixture f;
    // State -> the methods executable in it.
    auto check = [&](const char* state, std::vector<const char*> on) {
        for (const char* m : {"Start", "Suspend", "Resume", "Halt", "Reset"}) {
            const bool expected = std::find_if(on.begin(), on.end(), [&](const char* x) {
                                      return std::string(x) == m;
                                  }) != on.end();
            EXPECT_EQ(f.executable(m), expected) << m << " in " << state;
            Variant user = f.c.readAttribute(f.fsm->method(m), AttributeId::UserExecutable)
                               .value.value_or(Variant());
            ASSERT_NE(user.scalar<Boolean>(), nullptr);
            EXPECT_EQ(*user.scalar<Boolean>(), expected) << m << " (user) in " << state;
        }
    };
    check("Ready", {"Start", "Halt"});
    ASSERT_EQ(f.call("Start"), status::Good);
    check("Running", {"Suspend", "Halt"});
    ASSERT_EQ(f.call("Suspend"), status::Good);
    check("Suspended", {"Resume", "Halt", "Reset"});
    ASSERT_EQ(f.call("Halt"), status::Good);
    check("Halted", {"Reset"});
}

TEST(StateMachine, MethodInTheWrongStateIsRefused) {
    {
        ProgramFixture f;
        ASSERT_EQ(f.call("Start"), status::Good);
        // Executable is false in Running: the Call service refuses (OPC 10000-4 §5.11.2).
        EXPECT_EQ(f.call("Start"), status::BadNotExecutable);
        // The application's own request is checked against the state.
        EXPECT_EQ(f.fsm->fire("Start"), status::BadInvalidState);
        f.expectState("Running", 2402, 13);
    }
    {
        // Methods always executable: the handler itself refuses with Bad_InvalidState.
        ProgramFixture f(FiniteStateMachine::Options{.trackExecutable = false});
        EXPECT_TRUE(f.executable("Resume"));
        ASSERT_EQ(f.call("Start"), status::Good);
        EXPECT_EQ(f.call("Start"), status::BadInvalidState);
        EXPECT_EQ(f.call("Reset"), status::BadInvalidState);
        f.expectState("Running", 2402, 13);
        f.expectLast("ReadyToRunning", 2410, 2);
    }
}

TEST(StateMachine, TransitionEventPerTransition) {
    ProgramFixture f;
    Inbox<std::vector<Variant>> events;
    client::Subscription sub(f.c, {.publishingInterval = 10});
    auto item = sub.monitorEvents(
        NodeId(0, ns0::Server),
        {.select = {"EventType", "SourceNode", "Transition", "Transition/Id", "FromState",
                    "FromState/Id", "ToState", "ToState/Id", "Message"},
         .eventType = NodeId(0, ns0::TransitionEventType),
         .where = client::whereOfType(NodeId(0, ns0::TransitionEventType))},
        [&](client::EventFields& e) { events.put(e.take()); });

    // One transition in flight at a time: each event is awaited before the next call.
    for (std::size_t i = 0; i < std::size(kLifecycle); ++i) {
        ASSERT_EQ(f.call(kLifecycle[i].method), status::Good) << kLifecycle[i].method;
        ASSERT_TRUE(events.waitForCount(i + 1)) << kLifecycle[i].method;
    }
    auto got = events.items();
    ASSERT_EQ(got.size(), std::size(kLifecycle));
    auto text = [](const Variant& v) {
        return v.scalar<LocalizedText>() ? v.scalar<LocalizedText>()->text : "<not text>";
    };
    auto id = [](const Variant& v) { return v.scalar<NodeId>() ? *v.scalar<NodeId>() : NodeId(); };
    const auto& states = f.fsm->states();
    auto stateNode = [&](const char* name) {
        for (const auto& s : states)
            if (s.browseName.name == name) return s.node;
        return NodeId();
    };
    for (std::size_t i = 0; i < got.size(); ++i) {
        const Step& s = kLifecycle[i];
        const auto& e = got[i];
        ASSERT_EQ(e.size(), 9u);
        // ProgramStateMachineType's transitions name ProgramTransitionEventType (HasEffect).
        EXPECT_EQ(id(e[0]), NodeId(0, ns0::ProgramTransitionEventType)) << i;
        EXPECT_EQ(id(e[1]), f.program);
        EXPECT_EQ(text(e[2]), s.transition);
        EXPECT_EQ(id(e[3]), NodeId(0, s.transitionId));
        EXPECT_EQ(text(e[4]), s.from);
        EXPECT_EQ(id(e[5]), stateNode(s.from));
        EXPECT_EQ(text(e[6]), s.to);
        EXPECT_EQ(id(e[7]), stateNode(s.to));
        EXPECT_NE(text(e[8]).find(s.to), std::string::npos) << text(e[8]);
    }
}

// A transition's event leaves before its state variables are written when a method caused it
// (the network lock keeps every other request out meanwhile), after them when an application
// thread did: either way, a client that has the event and reads CurrentState at once, on
// another connection, reads the event's ToState, and LastTransition/TransitionTime is the
// event's Time.
TEST(StateMachine, AReaderThatHasTheEventSeesItsState) {
    ProgramFixture f;
    client::Client reader;
    reader.connect(f.server.endpointUrl());
    const NodeId current = f.node({"CurrentState", "Id"});
    const NodeId transitionTime = f.node({"LastTransition", "TransitionTime"});
    struct Seen {
        NodeId toState, readState;
        DateTime time, readTime;
    };
    Inbox<Seen> seen;
    client::Subscription sub(f.c, {.publishingInterval = 0});
    auto item = sub.monitorEvents(
        NodeId(0, ns0::Server),
        {.select = {"ToState/Id", "Time"},
         .eventType = NodeId(0, ns0::TransitionEventType),
         .where = client::whereOfType(NodeId(0, ns0::TransitionEventType))},
        [&](client::EventFields& e) {
            Seen s;
            if (const auto* v = e.get("ToState/Id"); v && v->scalar<NodeId>())
                s.toState = *v->scalar<NodeId>();
            if (const auto* v = e.get("Time"); v && v->scalar<DateTime>())
                s.time = *v->scalar<DateTime>();
            // A blocking Read from the callback, on the other client's connection.
            std::vector<ReadValueId> nodes(2);
            nodes[0].nodeId = current;
            nodes[1].nodeId = transitionTime;
            for (auto& n : nodes) n.attributeId = static_cast<UInt32>(AttributeId::Value);
            const auto values = reader.read(std::move(nodes));
            if (values.size() == 2 && values[0].value && values[0].value->scalar<NodeId>())
                s.readState = *values[0].value->scalar<NodeId>();
            if (values.size() == 2 && values[1].value && values[1].value->scalar<DateTime>())
                s.readTime = *values[1].value->scalar<DateTime>();
            seen.put(s);
        });
    constexpr int kRounds = 20;
    std::size_t expected = 0;
    for (int round = 0; round < kRounds; ++round) {
        for (const Step& step : kLifecycle) {
            // Alternately caused by a client's method call and by the application.
            if (round % 2 == 0)
                ASSERT_EQ(f.call(step.method), status::Good) << step.method;
            else
                ASSERT_EQ(f.fsm->fire(step.transition), status::Good) << step.transition;
            ASSERT_TRUE(seen.waitForCount(++expected)) << step.transition;
        }
    }
    const auto got = seen.items();
    for (std::size_t i = 0; i < got.size(); ++i) {
        EXPECT_FALSE(got[i].toState.isNull()) << i;
        EXPECT_EQ(got[i].readState, got[i].toState) << "event " << i << " read an older state";
        EXPECT_EQ(got[i].readTime.ticks, got[i].time.ticks) << "event " << i;
    }
}

TEST(StateMachine, DataChangesOnCurrentState) {
    ProgramFixture f;
    Inbox<std::string> values;
    client::Subscription sub(f.c, {.publishingInterval = 10});
    auto item = sub.monitorValue(f.node({"CurrentState"}),
                                 [&](const DataValue& v) {
                                     const auto* lt =
                                         v.value ? v.value->scalar<LocalizedText>() : nullptr;
                                     values.put(lt ? lt->text : "<not text>");
                                 },
                                 {.samplingInterval = 0, .queueSize = 20});
    ASSERT_TRUE(values.waitForCount(1)) << "initial value";
    for (std::size_t i = 0; i < std::size(kLifecycle); ++i) {
        ASSERT_EQ(f.call(kLifecycle[i].method), status::Good) << kLifecycle[i].method;
        ASSERT_TRUE(values.waitForCount(i + 2)) << kLifecycle[i].method;
    }
    std::vector<std::string> expected = {"Ready"};
    for (const Step& s : kLifecycle) expected.push_back(s.to);
    EXPECT_EQ(values.items(), expected);
}

TEST(StateMachine, CustomMachineFromADescription) {
    server::Server srv(loopbackConfig());
    auto& as = srv.addressSpace();
    const NodeId type = as.addObjectType(NodeId(0, ns0::FiniteStateMachineType),
                                         NodeId(1, "GripperStateMachineType"),
                                         QualifiedName{1, "GripperStateMachineType"});
    server::InstantiateOptions o;
    o.optionalChildren = {n0("LastTransition")};
    const NodeId gripper = as.instantiate(NodeId(0, ns0::ObjectsFolder), type, NodeId(1, "Gripper"),
                                          QualifiedName{1, "Gripper"}, o);

    server::StateMachineDescription d;
    d.states = {{.name = "Opened", .number = 1, .initial = true},
                {.name = "Closed", .number = 2},
                {.name = "Fault", .number = 3}};
    d.transitions = {{.name = "OpenedToClosed",
                      .number = 1,
                      .from = "Opened",
                      .to = "Closed",
                      .causes = {"Close"}},
                     {.name = "ClosedToOpened",
                      .number = 2,
                      .from = "Closed",
                      .to = "Opened",
                      .causes = {"Open"}},
                     {.name = "ClosedToFault", .number = 3, .from = "Closed", .to = "Fault"}};
    FiniteStateMachine fsm(srv, gripper, d);
    Inbox<std::string> observed;
    fsm.onTransition([&](const FiniteStateMachine::State& from,
                         const FiniteStateMachine::Transition& via,
                         const FiniteStateMachine::State& to) {
        observed.put(from.browseName.name + ">" + via.browseName.name + ">" + to.browseName.name);
    });
    int refusals = 1;  // the first Close is refused by the application
    ASSERT_EQ(
        fsm.onMethod("Close",
                     [&](const server::MethodCallContext&, const FiniteStateMachine::Transition& t,
                         const std::vector<Variant>&) -> StatusCode {
                         EXPECT_EQ(t.browseName.name, "OpenedToClosed");
                         return refusals-- > 0 ? status::BadResourceUnavailable : status::Good;
                     }),
        status::Good);
    EXPECT_EQ(fsm.onMethod("NoSuchMethod", {}), status::BadNotFound);
    srv.start();
    client::Client c;
    c.connect(srv.endpointUrl());

    auto stateNode = [&](const char* name) {
        return as.resolvePath(gripper, std::vector<QualifiedName>{{1, name}}).value_or(NodeId());
    };
    const NodeId currentState =
        *as.resolvePath(gripper, std::vector<QualifiedName>{n0("CurrentState")});
    const NodeId currentId = *as.resolvePath(currentState, std::vector<QualifiedName>{n0("Id")});
    auto current = [&] {
        Variant v = c.readValue(currentState);
        return v.scalar<LocalizedText>() ? v.scalar<LocalizedText>()->text : "<not text>";
    };
    EXPECT_EQ(current(), "Opened");
    EXPECT_EQ(c.readValue(currentId).scalar<NodeId>() ? *c.readValue(currentId).scalar<NodeId>()
                                                      : NodeId(),
              stateNode("Opened"));
    // The description's nodes: StateType objects with StateNumber, HasCause to the method.
    EXPECT_FALSE(stateNode("Fault").isNull());
    EXPECT_FALSE(fsm.method("Close").isNull());

    EXPECT_EQ(c.call(gripper, fsm.method("Close"), {}).status, status::BadResourceUnavailable);
    EXPECT_EQ(current(), "Opened");
    EXPECT_EQ(c.call(gripper, fsm.method("Close"), {}).status, status::Good);
    EXPECT_EQ(current(), "Closed");
    EXPECT_EQ(fsm.transitionTo("Fault"), status::Good);  // no method: the application's call
    EXPECT_EQ(current(), "Fault");
    EXPECT_EQ(fsm.transitionTo("Opened"), status::BadInvalidState);  // Fault is terminal
    EXPECT_EQ(c.call(gripper, fsm.method("Open"), {}).status, status::BadNotExecutable);
    ASSERT_TRUE(observed.waitForCount(2));
    EXPECT_EQ(observed.items(), (std::vector<std::string>{"Opened>OpenedToClosed>Closed",
                                                          "Closed>ClosedToFault>Fault"}));
    Variant last =
        c.readValue(*as.resolvePath(gripper, std::vector<QualifiedName>{n0("LastTransition")}));
    ASSERT_NE(last.scalar<LocalizedText>(), nullptr);
    EXPECT_EQ(last.scalar<LocalizedText>()->text, "ClosedToFault");
}

TEST(StateMachine, BadSetupsThrowClearErrors) {
    server::Server srv(loopbackConfig());
    auto& as = srv.addressSpace();
    // Not a state machine.
    const NodeId plain =
        as.addObject(NodeId(0, ns0::ObjectsFolder), NodeId(1, "Plain"), QualifiedName{1, "Plain"});
    EXPECT_THROW(FiniteStateMachine(srv, plain), server::StateMachineError);
    EXPECT_THROW(FiniteStateMachine(srv, NodeId(1, "Missing")), server::StateMachineError);
    try {
        FiniteStateMachine fsm(srv, plain);
    } catch (const server::StateMachineError& e) {
        EXPECT_NE(std::string(e.what()).find("not a FiniteStateMachineType"), std::string::npos)
            << e.what();
    }
    // A program with an unknown initial state.
    const NodeId program =
        as.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(0, ns0::ProgramStateMachineType),
                       NodeId(1, "P"), QualifiedName{1, "P"});
    EXPECT_THROW(
        FiniteStateMachine(srv, program, FiniteStateMachine::Options{.initialState = "Nope"}),
        server::StateMachineError);
    // An event type that is not a TransitionEventType.
    EXPECT_THROW(
        FiniteStateMachine(
            srv, program, FiniteStateMachine::Options{.eventType = NodeId(0, ns0::BaseObjectType)}),
        server::StateMachineError);
    // A type without states and no description.
    const NodeId empty =
        as.addObjectType(NodeId(0, ns0::FiniteStateMachineType), NodeId(1, "EmptyMachineType"),
                         QualifiedName{1, "EmptyMachineType"});
    const NodeId e =
        as.instantiate(NodeId(0, ns0::ObjectsFolder), empty, NodeId(1, "E"), QualifiedName{1, "E"});
    EXPECT_THROW(FiniteStateMachine(srv, e), server::StateMachineError);
    // Descriptions with unknown states, duplicates, no initial state.
    server::StateMachineDescription d;
    d.states = {{.name = "A", .number = 1, .initial = true}};
    d.transitions = {{.name = "AToB", .number = 1, .from = "A", .to = "B"}};
    EXPECT_THROW(FiniteStateMachine(srv, e, d), server::StateMachineError);
    const NodeId e2 = as.instantiate(NodeId(0, ns0::ObjectsFolder), empty, NodeId(1, "E2"),
                                     QualifiedName{1, "E2"});
    d.states = {{.name = "A", .number = 1}, {.name = "A", .number = 2}};
    d.transitions = {};
    EXPECT_THROW(FiniteStateMachine(srv, e2, d), server::StateMachineError);
    const NodeId e3 = as.instantiate(NodeId(0, ns0::ObjectsFolder), empty, NodeId(1, "E3"),
                                     QualifiedName{1, "E3"});
    d.states = {{.name = "A", .number = 1}};
    EXPECT_THROW(FiniteStateMachine(srv, e3, d), server::StateMachineError);
}

TEST(StateMachine, HandlersOutliveTheMachineSafely) {
    ProgramFixture f;
    const NodeId start = f.fsm->method("Start");
    f.fsm.reset();
    EXPECT_EQ(f.c.call(f.program, start, {}).status, status::BadInvalidState);
}

TEST(StateMachine, ConcurrentTransitionsFromApplicationThreadsAndClients) {
    ProgramFixture f;
    Inbox<std::vector<Variant>> events;
    client::Subscription sub(f.c, {.publishingInterval = 10});
    auto item =
        sub.monitorEvents(NodeId(0, ns0::Server),
                          {.select = {"FromState", "ToState"},
                           .where = client::whereOfType(NodeId(0, ns0::TransitionEventType)),
                           .queueSize = 10000},
                          [&](client::EventFields& e) { events.put(e.take()); });

    // Two application threads and the client race through Start / Halt / Reset; every
    // accepted request is one transition and one event, in an order consistent with the
    // states.
    std::atomic<int> accepted{0};
    Inbox<std::string> observed;  // the server's order (observer, after each transition)
    f.fsm->onTransition([&](const FiniteStateMachine::State& from,
                            const FiniteStateMachine::Transition&,
                            const FiniteStateMachine::State& to) {
        observed.put(from.browseName.name + ">" + to.browseName.name);
    });
    auto worker = [&](int seed) {
        const char* methods[] = {"Start", "Halt", "Reset"};
        for (int i = 0; i < 300; ++i)
            if (f.fsm->fire(methods[(i + seed) % 3]).isGood()) ++accepted;
    };
    std::thread a(worker, 0), b(worker, 1);
    for (int i = 0; i < 30; ++i) {
        for (const char* m : {"Start", "Halt", "Reset"}) {
            StatusCode st = f.call(m);
            if (st.isGood()) ++accepted;
        }
    }
    a.join();
    b.join();
    const auto n = static_cast<std::size_t>(accepted.load());
    ASSERT_GT(n, 0u);
    ASSERT_TRUE(events.waitForCount(n, 10s)) << events.items().size() << " of " << n;
    // Every transition arrives as an event, once, in transition order (each starts where the
    // previous one ended): the server writes a connection's NotificationMessages in sequence
    // order, and the client delivers a message that arrives late or by Republish only once.
    std::this_thread::sleep_for(300ms);  // no further (duplicate) events
    EXPECT_EQ(observed.items().size(), n);
    auto got = events.items();
    EXPECT_EQ(got.size(), n);
    std::map<std::string, std::size_t> sent, received;
    for (const auto& o : observed.items()) ++sent[o];
    std::string previousTo;
    for (const auto& e : got) {
        ASSERT_EQ(e.size(), 2u);
        const auto* from = e[0].scalar<LocalizedText>();
        const auto* to = e[1].scalar<LocalizedText>();
        ASSERT_TRUE(from && to);
        ++received[from->text + ">" + to->text];
        if (!previousTo.empty()) {
            EXPECT_EQ(from->text, previousTo) << "events out of order";
        }
        previousTo = to->text;
    }
    for (const auto& [transition, count] : sent)
        EXPECT_EQ(received[transition], count) << transition;
    EXPECT_EQ(received.size(), sent.size()) << "an event for a transition that did not happen";
    const std::string state = f.fsm->currentState().browseName.name;
    EXPECT_EQ(f.text({"CurrentState"}), state);
    EXPECT_EQ(f.id({"CurrentState", "Id"}), f.fsm->currentState().node);
}

// A machine type built by the application (as a NodeSet2 file would define one): states and
// transitions as components of the type, the initial state an InitialStateType, the cause
// method a Mandatory component that instantiate copies.
TEST(StateMachine, StatesFromAnApplicationDefinedType) {
    server::Server srv(loopbackConfig());
    auto& as = srv.addressSpace();
    const NodeId type =
        as.addObjectType(NodeId(0, ns0::FiniteStateMachineType), NodeId(1, "ValveStateMachineType"),
                         QualifiedName{1, "ValveStateMachineType"});
    auto state = [&](const char* name, UInt32 stateType, UInt32 number) {
        NodeId s =
            as.addObject(type, NodeId(1, std::string("Valve.") + name), QualifiedName{1, name}, {},
                         NodeId(0, stateType), NodeId(0, ns0::HasComponent));
        as.setValue(*as.resolvePath(s, std::vector<QualifiedName>{n0("StateNumber")}),
                    DataValue(Variant(number)));
        return s;
    };
    const NodeId closed = state("Closed", ns0::InitialStateType, 1);
    const NodeId opened = state("Opened", ns0::StateType, 2);
    const NodeId method =
        as.addMethod(type, NodeId(1, "Valve.OpenValve"), QualifiedName{1, "OpenValve"}, {}, {}, {});
    as.addReference(method, NodeId(0, ns0::HasModellingRule),
                    NodeId(0, ns0::ModellingRule_Mandatory));
    const NodeId transition =
        as.addObject(type, NodeId(1, "Valve.ClosedToOpened"), QualifiedName{1, "ClosedToOpened"},
                     {}, NodeId(0, ns0::TransitionType), NodeId(0, ns0::HasComponent));
    as.setValue(*as.resolvePath(transition, std::vector<QualifiedName>{n0("TransitionNumber")}),
                DataValue(Variant(UInt32{7})));
    as.addReference(transition, NodeId(0, ns0::FromState), closed);
    as.addReference(transition, NodeId(0, ns0::ToState), opened);
    as.addReference(transition, NodeId(0, ns0::HasCause), method);

    const NodeId valve = as.instantiate(NodeId(0, ns0::ObjectsFolder), type, NodeId(1, "V1"),
                                        QualifiedName{1, "V1"});
    FiniteStateMachine fsm(srv, valve);
    ASSERT_EQ(fsm.states().size(), 2u);
    ASSERT_EQ(fsm.transitions().size(), 1u);
    EXPECT_EQ(fsm.currentState().node, closed) << "the InitialStateType state";
    const NodeId copy = fsm.method("OpenValve");
    ASSERT_FALSE(copy.isNull());
    EXPECT_NE(copy, method) << "the instance's copy of the method";
    srv.start();
    client::Client c;
    c.connect(srv.endpointUrl());
    EXPECT_EQ(c.call(valve, copy, {}).status, status::Good);
    EXPECT_EQ(fsm.currentState().node, opened);
    const NodeId current = *as.resolvePath(valve, std::vector<QualifiedName>{n0("CurrentState")});
    Variant v = c.readValue(current);
    ASSERT_NE(v.scalar<LocalizedText>(), nullptr);
    EXPECT_EQ(v.scalar<LocalizedText>()->text, "Opened");
    ASSERT_TRUE(fsm.lastTransition().has_value());
    EXPECT_EQ(fsm.lastTransition()->number, 7u);
    EXPECT_EQ(c.call(valve, copy, {}).status, status::BadNotExecutable);
}
