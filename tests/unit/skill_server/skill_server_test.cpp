// The server side of skills over real sockets: the program state machine and its events as
// a client sees them, execution off the network thread, FinalResultData, Halt / Suspend /
// Reset, DI locking (two clients), parameters checked against the model at start-up.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <map>
#include <mutex>
#include <thread>

#include "skill/demo/demo_skills.hpp"
#include "skill/server/controller.hpp"
#include "support/inbox.hpp"
#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::skill {
namespace {

using namespace std::chrono_literals;
using pnp::testing::Inbox;
using pnp::testing::loopbackConfig;
using ua::NodeId;
using ua::QualifiedName;
using ua::Variant;
namespace client = ua::client;
namespace status = ua::status;
namespace ns0 = ua::ns0;

// A transition event as the test selects it.
struct Seen {
    ua::UInt32 transition = 0;
    ua::UInt32 from = 0;
    ua::UInt32 to = 0;
    std::string message;
    Variant intermediate;
    NodeId source;
};

struct SkillServer {
    ua::server::Server server{loopbackConfig()};
    std::unique_ptr<server::SkillController> controller;

    explicit SkillServer(std::function<void(SkillServer&)> build = {}) {
        demo::loadDemoModels(server);
        if (build)
            build(*this);
        else
            controller = demo::addDemoSkills(server);
        server.start();
    }
    ~SkillServer() {
        controller.reset();
        server.stop();
    }
    NodeId skill(const std::string& name) const { return NodeId(1, "DemoGripper." + name); }
    NodeId member(const NodeId& skill,
                  std::initializer_list<std::pair<std::string_view, const char*>> path) const {
        std::vector<QualifiedName> names;
        auto& space = const_cast<ua::server::Server&>(server).addressSpace();
        for (auto [uri, name] : path)
            names.emplace_back(uri.empty() ? ua::UInt16{0} : *space.namespaceIndex(uri), name);
        auto id = space.resolvePath(skill, names);
        EXPECT_TRUE(id.has_value()) << path.begin()->second;
        return id.value_or(NodeId());
    }
    NodeId parameter(const NodeId& skill, const char* name, std::string_view uri = kDemoUri) const {
        return member(skill, {{kDiUri, "ParameterSet"}, {uri, name}});
    }
    NodeId method(const NodeId& skill, const char* name) const {
        return member(skill, {{"", name}});
    }
    NodeId lockMethod(const NodeId& skill, const char* name) const {
        return member(skill, {{kDiUri, "Lock"}, {kDiUri, name}});
    }
};

struct Session {
    client::Client c;
    explicit Session(const ua::server::Server& s) {
        c.connect(pnp::testing::url(s));
        c.startBackgroundThread();
    }
    ua::StatusCode call(const NodeId& object, const NodeId& method) {
        return c.call(object, method, {}).status;
    }
    ua::Int32 lockCall(const SkillServer& s, const NodeId& skill, const char* name) {
        std::vector<Variant> in;
        if (std::string_view(name) == "InitLock") in.emplace_back(ua::String("test"));
        auto r = c.call(s.member(skill, {{kDiUri, "Lock"}}), s.lockMethod(skill, name), in);
        EXPECT_TRUE(r.ok()) << name << " " << r.status.toString();
        return r.outputs.empty() || !r.outputs[0].scalar<ua::Int32>()
                   ? -99
                   : *r.outputs[0].scalar<ua::Int32>();
    }
    ua::UInt32 stateNumber(const SkillServer& s, const NodeId& skill) {
        Variant v = c.readValue(s.member(skill, {{"", "CurrentState"}, {"", "Number"}}));
        return v.scalar<ua::UInt32>() ? *v.scalar<ua::UInt32>() : 0;
    }
};

constexpr ua::UInt32 kHalted = 11, kReady = 12, kRunning = 13, kSuspended = 14;

struct Transitions {
    Inbox<Seen> inbox;
    client::Subscription sub;
    client::MonitoredItem item;
    Transitions(Session& session, const SkillServer& s, const NodeId& skill) {
        sub = client::Subscription(session.c, {.publishingInterval = 10});
        const NodeId type(
            *const_cast<ua::server::Server&>(s.server).addressSpace().namespaceIndex(kBaseUri),
            types::SkillTransitionEventType.id);
        item =
            sub.monitorEvents(skill,
                              {.select = {"Transition/Number", "FromState/Number", "ToState/Number",
                                          "Message", "IntermediateResult", "SourceNode"},
                               .eventType = NodeId(0, ns0::ProgramTransitionEventType),
                               .where = client::whereOfType(type)},
                              [this](client::EventFields& e) {
                                  Seen s;
                                  auto u = [&](std::size_t i) {
                                      const auto* v = e[i].scalar<ua::UInt32>();
                                      return v ? *v : 0u;
                                  };
                                  s.transition = u(0);
                                  s.from = u(1);
                                  s.to = u(2);
                                  if (const auto* m = e[3].scalar<ua::LocalizedText>())
                                      s.message = m->text;
                                  s.intermediate = e[4];
                                  if (const auto* n = e[5].scalar<NodeId>()) s.source = *n;
                                  inbox.put(std::move(s));
                              });
    }
    std::vector<Seen> take(std::size_t n) {
        EXPECT_TRUE(inbox.waitForCount(n, 5000ms)) << "expected " << n << " transitions";
        return inbox.items();
    }
};

TEST(SkillServer, InstantCompletionStillGoesReadyRunningReadyWithBothEvents) {
    SkillServer s;
    Session a(s.server);
    const NodeId delay = s.skill("Delay");
    Transitions t(a, s, delay);
    ASSERT_EQ(a.c.writeValue(s.parameter(delay, "DurationMs"), 0.0), status::Good);
    ASSERT_EQ(a.call(delay, s.method(delay, "Start")), status::Good);
    auto seen = t.take(2);
    ASSERT_GE(seen.size(), 2u);
    EXPECT_EQ(seen[0].transition, 2u);  // ReadyToRunning
    EXPECT_EQ(seen[0].from, kReady);
    EXPECT_EQ(seen[0].to, kRunning);
    EXPECT_EQ(seen[1].transition, 4u);  // RunningToReady
    EXPECT_EQ(seen[1].to, kReady);
    EXPECT_EQ(seen[0].source, delay);
    EXPECT_EQ(a.stateNumber(s, delay), kReady);
    Variant result =
        a.c.readValue(s.member(delay, {{"", "FinalResultData"}, {kBaseUri, "Result"}}));
    ASSERT_TRUE(result.scalar<ua::Int32>());
    EXPECT_EQ(*result.scalar<ua::Int32>(), static_cast<ua::Int32>(SkillResult::Completed));
}

TEST(SkillServer, FailureEndsHaltedWithTheReasonAndResetGoesBackToReady) {
    SkillServer s;
    Session a(s.server);
    const NodeId delay = s.skill("Delay");
    Transitions t(a, s, delay);
    ASSERT_EQ(a.c.writeValue(s.parameter(delay, "FailWith"), ua::String("gripper blocked")),
              status::Good);
    ASSERT_EQ(a.call(delay, s.method(delay, "Start")), status::Good);
    auto seen = t.take(2);
    ASSERT_GE(seen.size(), 2u);
    EXPECT_EQ(seen[1].transition, 3u);  // RunningToHalted
    EXPECT_EQ(seen[1].to, kHalted);
    EXPECT_EQ(seen[1].message, "gripper blocked");
    EXPECT_EQ(a.stateNumber(s, delay), kHalted);
    Variant msg = a.c.readValue(s.member(delay, {{"", "FinalResultData"}, {kBaseUri, "Message"}}));
    ASSERT_TRUE(msg.scalar<ua::String>());
    EXPECT_EQ(*msg.scalar<ua::String>(), "gripper blocked");
    Variant result =
        a.c.readValue(s.member(delay, {{"", "FinalResultData"}, {kBaseUri, "Result"}}));
    EXPECT_EQ(*result.scalar<ua::Int32>(), static_cast<ua::Int32>(SkillResult::Failed));
    // Start is not executable while Halted.
    EXPECT_TRUE(a.call(delay, s.method(delay, "Start")).isBad());
    ASSERT_EQ(a.call(delay, s.method(delay, "Reset")), status::Good);
    seen = t.take(3);
    EXPECT_EQ(seen[2].transition, 1u);  // HaltedToReady
    EXPECT_EQ(a.stateNumber(s, delay), kReady);
}

TEST(SkillServer, HaltStopsARunAtOnceAndSuspendPausesIt) {
    SkillServer s;
    Session a(s.server);
    const NodeId delay = s.skill("Delay");
    Transitions t(a, s, delay);
    ASSERT_EQ(a.c.writeValue(s.parameter(delay, "DurationMs"), 60000.0), status::Good);
    ASSERT_EQ(a.call(delay, s.method(delay, "Start")), status::Good);
    ASSERT_EQ(a.call(delay, s.method(delay, "Suspend")), status::Good);
    EXPECT_EQ(a.stateNumber(s, delay), kSuspended);
    ASSERT_EQ(a.call(delay, s.method(delay, "Resume")), status::Good);
    EXPECT_EQ(a.stateNumber(s, delay), kRunning);
    const auto before = std::chrono::steady_clock::now();
    ASSERT_EQ(a.call(delay, s.method(delay, "Halt")), status::Good);
    EXPECT_EQ(a.stateNumber(s, delay), kHalted);
    Variant result =
        a.c.readValue(s.member(delay, {{"", "FinalResultData"}, {kBaseUri, "Result"}}));
    EXPECT_EQ(*result.scalar<ua::Int32>(), static_cast<ua::Int32>(SkillResult::Aborted));
    ASSERT_EQ(a.call(delay, s.method(delay, "Reset")), status::Good);
    EXPECT_LT(std::chrono::steady_clock::now() - before, 5s);
    auto seen = t.take(5);
    ASSERT_GE(seen.size(), 5u);
    const ua::UInt32 expected[] = {2, 5, 6, 3, 1};  // Start Suspend Resume Halt Reset
    for (std::size_t i = 0; i < 5; ++i) EXPECT_EQ(seen[i].transition, expected[i]) << i;
    // The halted run's late outcome is dropped: no sixth transition.
    EXPECT_FALSE(t.inbox.waitForCount(6, 300ms));
    // And the skill runs again.
    ASSERT_EQ(a.c.writeValue(s.parameter(delay, "DurationMs"), 0.0), status::Good);
    ASSERT_EQ(a.call(delay, s.method(delay, "Start")), status::Good);
    EXPECT_TRUE(t.inbox.waitForCount(7));
}

TEST(SkillServer, ProgressIsTheIntermediateResultOfTheEvents) {
    SkillServer s;
    Session a(s.server);
    const NodeId move = s.skill("MoveGripper");
    Transitions t(a, s, move);
    ASSERT_EQ(a.c.writeValue(s.parameter(move, "Width", kBaseUri), 0.0), status::Good);
    ASSERT_EQ(a.call(move, s.method(move, "Start")), status::Good);
    auto seen = t.take(2);
    ASSERT_GE(seen.size(), 2u);
    EXPECT_EQ(seen[1].transition, 4u);
    ASSERT_TRUE(seen[1].intermediate.scalar<double>());
    EXPECT_DOUBLE_EQ(*seen[1].intermediate.scalar<double>(), 0.0);
    // A width outside the gripper's range fails with a reason.
    ASSERT_EQ(a.c.writeValue(s.parameter(move, "Width", kBaseUri), 0.5), status::Good);
    ASSERT_EQ(a.call(move, s.method(move, "Start")), status::Good);
    seen = t.take(4);
    EXPECT_EQ(seen[3].to, kHalted);
    EXPECT_NE(seen[3].message.find("Width"), std::string::npos);
}

TEST(SkillServer, OnlyTheLockHolderWritesParametersAndCallsMethods) {
    SkillServer s;
    Session a(s.server), b(s.server);
    const NodeId delay = s.skill("Delay");
    const NodeId duration = s.parameter(delay, "DurationMs");
    EXPECT_EQ(a.lockCall(s, delay, "InitLock"), 0);
    EXPECT_EQ(b.lockCall(s, delay, "InitLock"), -1);  // E_AlreadyLocked
    EXPECT_EQ(b.c.writeValue(duration, 5.0), status::BadLocked);
    EXPECT_EQ(b.call(delay, s.method(delay, "Start")), status::BadLocked);
    EXPECT_EQ(b.lockCall(s, delay, "ExitLock"), -2);  // not b's lock
    EXPECT_EQ(b.lockCall(s, delay, "RenewLock"), -2);
    EXPECT_EQ(a.c.writeValue(duration, 1.0), status::Good);
    EXPECT_EQ(a.lockCall(s, delay, "RenewLock"), 0);
    EXPECT_EQ(
        *a.c.readValue(s.member(delay, {{kDiUri, "Lock"}, {kDiUri, "Locked"}})).scalar<bool>(),
        true);
    EXPECT_EQ(a.lockCall(s, delay, "ExitLock"), 0);
    EXPECT_EQ(b.c.writeValue(duration, 2.0), status::Good);
    // BreakLock ends anyone's lock; a closed session gives its lock up.
    EXPECT_EQ(a.lockCall(s, delay, "InitLock"), 0);
    EXPECT_EQ(b.lockCall(s, delay, "BreakLock"), 0);
    EXPECT_EQ(b.lockCall(s, delay, "InitLock"), 0);
    b.c.disconnect();
    EXPECT_EQ(a.lockCall(s, delay, "InitLock"), 0);
}

TEST(SkillServer, ALockExpiresAfterItsInactiveTime) {
    SkillServer s([](SkillServer& self) {
        self.controller = std::make_unique<server::SkillController>(
            self.server,
            server::SkillControllerOptions{.name = "DemoGripper", .maxInactiveLockTime = 200ms});
        self.controller->add(
            "Delay", server::makeSkill(types::DelaySkillType,
                                       {server::declareParameter<double>("DurationMs")}, {}));
    });
    Session a(s.server), b(s.server);
    const NodeId delay = s.skill("Delay");
    EXPECT_EQ(a.lockCall(s, delay, "InitLock"), 0);
    EXPECT_EQ(b.c.writeValue(s.parameter(delay, "DurationMs"), 5.0), status::BadLocked);
    std::this_thread::sleep_for(300ms);
    EXPECT_EQ(b.c.writeValue(s.parameter(delay, "DurationMs"), 5.0), status::Good);
    EXPECT_EQ(a.lockCall(s, delay, "RenewLock"), -1);  // E_NotLocked: it expired
}

// Two clients race lock -> write -> start -> wait -> unlock on one skill: every execution
// runs with exactly the value its own client wrote.
TEST(SkillServer, AtomicParametrizationUnderARaceOfTwoClients) {
    std::mutex logMutex;
    std::vector<double> executed;
    SkillServer s([&](SkillServer& self) {
        self.controller = std::make_unique<server::SkillController>(
            self.server, server::SkillControllerOptions{.name = "DemoGripper"});
        auto duration = server::declareParameter<double>("DurationMs");
        self.controller->add("Delay", server::makeSkill(types::DelaySkillType, {duration},
                                                        {.execute = [&](server::Execution& run) {
                                                            const double* v =
                                                                run.value(0).scalar<double>();
                                                            std::lock_guard l(logMutex);
                                                            executed.push_back(v ? *v : -1);
                                                            return server::Outcome::completed();
                                                        }}));
    });
#ifdef PNP_SANITIZED_BUILD
    constexpr int kRuns = 200;
#else
    constexpr int kRuns = 1000;
#endif
    const NodeId delay = s.skill("Delay");
    const NodeId duration = s.parameter(delay, "DurationMs");
    const NodeId start = s.method(delay, "Start");
    std::vector<double> started[2];
    std::atomic<int> failures{0};
    auto racer = [&](int who) {
        Session me(s.server);
        const auto deadline = std::chrono::steady_clock::now() + 60s;
        for (int i = 0; i < kRuns && std::chrono::steady_clock::now() < deadline; ++i) {
            while (me.lockCall(s, delay, "InitLock") != 0) {
                if (std::chrono::steady_clock::now() > deadline) return;
                std::this_thread::sleep_for(50us);
            }
            const double value = who * 1e6 + i;
            if (me.c.writeValue(duration, value) != status::Good ||
                me.call(delay, start) != status::Good) {
                ++failures;
            } else {
                started[who].push_back(value);
                // Start returned after Ready -> Running; Ready again means this run ended.
                for (int k = 0; k < 100000 && me.stateNumber(s, delay) != kReady; ++k) {
                }
            }
            EXPECT_EQ(me.lockCall(s, delay, "ExitLock"), 0);
        }
    };
    std::thread t0(racer, 0), t1(racer, 1);
    t0.join();
    t1.join();
    EXPECT_EQ(failures.load(), 0);
    EXPECT_EQ(started[0].size(), static_cast<std::size_t>(kRuns));
    EXPECT_EQ(started[1].size(), static_cast<std::size_t>(kRuns));
    std::lock_guard l(logMutex);
    ASSERT_EQ(executed.size(), started[0].size() + started[1].size());
    // In execution order, each client's values appear exactly in the order it started them.
    std::vector<double> per[2];
    for (double v : executed) per[v >= 1e6 ? 1 : 0].push_back(v);
    EXPECT_EQ(per[0], started[0]);
    EXPECT_EQ(per[1], started[1]);
}

TEST(SkillServer, DeclaredParametersAreCheckedAgainstTheModelAtStartUp) {
    ua::server::Server server(loopbackConfig());
    demo::loadDemoModels(server);
    server::SkillController c(server, {.name = "Checked"});
    try {
        c.add("Missing", server::makeSkill(types::DelaySkillType,
                                           {server::declareParameter<double>("Width")}, {}));
        FAIL() << "a parameter that the type lacks must be refused";
    } catch (const server::SkillError& e) {
        EXPECT_NE(std::string(e.what()).find("Width"), std::string::npos) << e.what();
    }
    try {
        c.add("Mistyped",
              server::makeSkill(types::DelaySkillType,
                                {server::declareParameter<ua::Int32>("DurationMs")}, {}));
        FAIL() << "a mistyped parameter must be refused";
    } catch (const server::SkillError& e) {
        EXPECT_NE(std::string(e.what()).find("DurationMs"), std::string::npos) << e.what();
    }
    try {
        c.add("Abstract", server::makeSkill(types::GripperSkillType, {}, {}));
        FAIL() << "an abstract type cannot be instantiated";
    } catch (const server::SkillError& e) {
        EXPECT_NE(std::string(e.what()).find("GripperSkillType"), std::string::npos) << e.what();
    }
    // A refused skill leaves nothing behind; a good one is added.
    EXPECT_FALSE(server.addressSpace().contains(NodeId(1, "Checked.Missing")));
    EXPECT_NO_THROW(
        c.add("Delay", server::makeSkill(types::DelaySkillType,
                                         {server::declareParameter<double>("DurationMs")}, {})));
}

TEST(SkillServer, TheControllerImplementsISkillControllerTypeBelowDeviceSet) {
    SkillServer s;
    auto& space = s.server.addressSpace();
    const NodeId device(1, "DemoGripper");
    ASSERT_TRUE(space.contains(device));
    const NodeId iface = server::resolve(space, types::ISkillControllerType);
    ua::server::ContinuationPointStore points(1);
    ua::BrowseDescription d;
    d.nodeId = device;
    d.browseDirection = ua::BrowseDirection::Inverse;
    d.referenceTypeId = NodeId(0, ns0::HierarchicalReferences);
    d.includeSubtypes = true;
    d.resultMask = 0x3F;
    auto parents = space.browse(d, 0, points).references;
    ASSERT_FALSE(parents.empty());
    EXPECT_EQ(parents[0].browseName.name, "DeviceSet");
    d.browseDirection = ua::BrowseDirection::Forward;
    d.referenceTypeId = NodeId(0, ns0::HasInterface);
    auto ifaces = space.browse(d, 0, points).references;
    ASSERT_EQ(ifaces.size(), 1u);
    EXPECT_EQ(ifaces[0].nodeId.nodeId, iface);
    EXPECT_EQ(s.controller->skills().size(), 4u);
}

}  // namespace
}  // namespace pnp::skill

namespace pnp::skill {
namespace {

// Bad input gets a clear status and the skill keeps serving.
TEST(SkillServer, BadRequestsGetAStatusAndTheSkillKeepsWorking) {
    SkillServer s;
    Session a(s.server);
    const NodeId delay = s.skill("Delay");
    // Arguments to a method without any.
    auto r = a.c.call(delay, s.method(delay, "Start"), {Variant(1.0)});
    EXPECT_EQ(r.status, status::BadTooManyArguments);
    // A method of another skill called on this one.
    r = a.c.call(delay, s.method(s.skill("Grasp"), "Start"), {});
    EXPECT_TRUE(r.status.isBad());
    // InitLock with a context that is not a String.
    r = a.c.call(s.member(delay, {{kDiUri, "Lock"}}), s.lockMethod(delay, "InitLock"),
                 {Variant(ua::Int32{7})});
    EXPECT_TRUE(r.status.isBad() ||
                (!r.inputArgumentResults.empty() && r.inputArgumentResults[0].isBad()));
    // A parameter of the wrong type, a result variable, a state variable.
    EXPECT_EQ(a.c.writeValue(s.parameter(delay, "DurationMs"), ua::String("soon")),
              status::BadTypeMismatch);
    EXPECT_TRUE(a.c.writeValue(s.member(delay, {{"", "FinalResultData"}, {kBaseUri, "Result"}}),
                               ua::Int32{1})
                    .isBad());
    EXPECT_TRUE(
        a.c.writeValue(s.member(delay, {{"", "CurrentState"}}), ua::LocalizedText("", "Running"))
            .isBad());
    // A DurationMs the skill refuses ends the run Failed with the reason.
    ASSERT_EQ(a.c.writeValue(s.parameter(delay, "DurationMs"), -5.0), status::Good);
    ASSERT_EQ(a.call(delay, s.method(delay, "Start")), status::Good);
    for (int i = 0; i < 500 && a.stateNumber(s, delay) != kHalted; ++i)
        std::this_thread::sleep_for(1ms);
    EXPECT_EQ(a.stateNumber(s, delay), kHalted);
    // Resume / Suspend in the wrong state.
    EXPECT_TRUE(a.call(delay, s.method(delay, "Resume")).isBad());
    EXPECT_TRUE(a.call(delay, s.method(delay, "Suspend")).isBad());
    ASSERT_EQ(a.call(delay, s.method(delay, "Reset")), status::Good);
    ASSERT_EQ(a.c.writeValue(s.parameter(delay, "DurationMs"), 0.0), status::Good);
    ASSERT_EQ(a.call(delay, s.method(delay, "Start")), status::Good);
    for (int i = 0; i < 500 && a.stateNumber(s, delay) != kReady; ++i)
        std::this_thread::sleep_for(1ms);
    EXPECT_EQ(a.stateNumber(s, delay), kReady);
}

// A skill whose execute() throws ends Failed with the exception's message; a skill that
// ignores Halt does not keep the state machine from Halted, and Reset waits for it.
TEST(SkillServer, ThrowingAndStubbornSkillsStayWithinTheStateMachine) {
    std::atomic<bool> release{false};
    SkillServer s([&](SkillServer& self) {
        self.controller = std::make_unique<server::SkillController>(
            self.server, server::SkillControllerOptions{.name = "DemoGripper"});
        self.controller->add(
            "Thrower", server::makeSkill(types::DelaySkillType, {},
                                         {.execute = [](server::Execution&) -> server::Outcome {
                                             throw std::runtime_error("axis 3 overheated");
                                         }}));
        self.controller->add(
            "Stubborn",
            server::makeSkill(types::DelaySkillType, {}, {.execute = [&](server::Execution&) {
                                  for (int i = 0; i < 5000 && !release; ++i)
                                      std::this_thread::sleep_for(1ms);
                                  return server::Outcome::completed();
                              }}));
    });
    Session a(s.server);
    const NodeId thrower = s.skill("Thrower");
    ASSERT_EQ(a.call(thrower, s.method(thrower, "Start")), status::Good);
    for (int i = 0; i < 500 && a.stateNumber(s, thrower) != kHalted; ++i)
        std::this_thread::sleep_for(1ms);
    EXPECT_EQ(a.stateNumber(s, thrower), kHalted);
    Variant msg =
        a.c.readValue(s.member(thrower, {{"", "FinalResultData"}, {kBaseUri, "Message"}}));
    EXPECT_EQ(*msg.scalar<ua::String>(), "axis 3 overheated");

    const NodeId stubborn = s.skill("Stubborn");
    ASSERT_EQ(a.call(stubborn, s.method(stubborn, "Start")), status::Good);
    ASSERT_EQ(a.call(stubborn, s.method(stubborn, "Halt")), status::Good);
    EXPECT_EQ(a.stateNumber(s, stubborn), kHalted);
    // Reset completes once the run has returned, not before.
    std::atomic<bool> resetDone{false};
    a.c.callAsync(stubborn, s.method(stubborn, "Reset"), {},
                  [&](ua::client::Result<ua::client::CallResult> r) {
                      EXPECT_TRUE(r.ok() && r.value().ok());
                      resetDone = true;
                  });
    std::this_thread::sleep_for(100ms);
    EXPECT_FALSE(resetDone.load());
    EXPECT_EQ(a.stateNumber(s, stubborn), kHalted);
    release = true;
    for (int i = 0; i < 2000 && !resetDone; ++i) std::this_thread::sleep_for(1ms);
    EXPECT_TRUE(resetDone.load());
    EXPECT_EQ(a.stateNumber(s, stubborn), kReady);
}

}  // namespace
}  // namespace pnp::skill
