// SkillClient, GenericSkillClient and the typed clients against a real skill server in the
// test process (127.0.0.1, ephemeral port): a DelaySkillType skill whose DurationMs and
// FailWith parameters make it a no-op, a failing or a slow run (sleepFor honours Halt).
#include "skill/client/skill_client.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include "skill/client/generic_client.hpp"
#include "skill/client/typed_clients.hpp"
#include "skill/server/controller.hpp"
#include "skill/server/skill.hpp"
#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp;
using namespace pnp::skill;
using namespace pnp::skill::client;
using namespace std::chrono_literals;
using pnp::testing::errorOf;
namespace status = pnp::ua::status;

namespace {

// DurationMs of Running time (Halt interrupts it), then FailWith ? Failed : Completed.
class DelaySkill : public server::Skill {
  public:
    DelaySkill() : Skill(types::DelaySkillType) {}
    server::Param<double> duration = parameter<double>("DurationMs", 0.0);
    server::Param<ua::String> failWith = optionalParameter<ua::String>("FailWith", "");
    server::Outcome execute(server::Execution& run) override {
        const auto ms = std::chrono::duration<double, std::milli>(run.get(duration));
        if (!run.sleepFor(std::chrono::duration_cast<std::chrono::nanoseconds>(ms)))
            return server::Outcome::aborted("halted");
        std::string fail = run.get(failWith);
        if (!fail.empty()) return server::Outcome::failed(fail);
        return server::Outcome::completed("done");
    }
};

struct Cell {
    ua::server::Server server{pnp::testing::loopbackConfig()};
    std::unique_ptr<server::SkillController> controller;
    ua::NodeId delay;
    std::shared_ptr<ua::client::Client> a = std::make_shared<ua::client::Client>();
    std::shared_ptr<ua::client::Client> b = std::make_shared<ua::client::Client>();

    Cell() {
        server::loadSkillModels(server.addressSpace(), {kDemoUri, kBaseUri});
        controller = std::make_unique<server::SkillController>(
            server, server::SkillControllerOptions{.name = "Cell"});
        delay = controller->add("Delay", std::make_shared<DelaySkill>()).node();
        server.start();
        a->connect(pnp::testing::url(server));
        b->connect(pnp::testing::url(server));
    }
    ~Cell() {
        a->disconnect();
        b->disconnect();
        controller.reset();
        server.stop();
    }
};

std::vector<ua::UInt32> numbersOf(const std::vector<Transition>& ts) {
    std::vector<ua::UInt32> out;
    for (const auto& t : ts) out.push_back(t.number);
    return out;
}

TEST(SkillClient, DiscoversTypeParametersAndState) {
    Cell cell;
    SkillClient skill(cell.a, cell.delay, 5s);
    EXPECT_EQ(skill.browseName(), "Delay");
    ASSERT_GE(skill.typeChain().size(), 2u);
    EXPECT_EQ(skill.type().name, "DelaySkillType");
    EXPECT_TRUE(skill.isA(types::DelaySkillType));
    EXPECT_TRUE(skill.isA(types::SkillType));
    EXPECT_FALSE(skill.isA(types::GraspGripperSkillType));
    const ParameterInfo* d = skill.findParameter("DurationMs");
    ASSERT_NE(d, nullptr);
    EXPECT_EQ(d->dataType, ua::NodeId(0, ua::ns0::Double));
    EXPECT_EQ(d->valueRank, -1);
    EXPECT_TRUE(d->writable);
    EXPECT_NE(skill.findParameter("FailWith"), nullptr);
    EXPECT_EQ(skill.state(), ProgramState::Ready);
    EXPECT_EQ(skill.finalResult().result, SkillResult::None);
}

TEST(SkillClient, ParametersByNameInOneWrite) {
    Cell cell;
    SkillClient skill(cell.a, cell.delay, 5s);
    skill.setParameter("DurationMs", 12.5);
    EXPECT_EQ(skill.parameter("DurationMs"), ua::Variant(12.5));
    skill.setParameters({{"DurationMs", 3.0}, {"FailWith", ua::String("x")}});
    EXPECT_EQ(skill.parameter("DurationMs"), ua::Variant(3.0));
    EXPECT_EQ(skill.parameter("FailWith"), ua::Variant(ua::String("x")));
    EXPECT_EQ(errorOf([&] { skill.parameter("Nope"); }), status::BadNotFound);
    try {
        skill.setParameter("DurationMs", ua::String("fast"));
        FAIL() << "a String was accepted for a Double";
    } catch (const Error& e) {
        EXPECT_TRUE(e.status().isBad());
        EXPECT_NE(std::string(e.what()).find("DurationMs"), std::string::npos) << e.what();
    }
}

TEST(GenericSkillClient, CoercesTextByDataType) {
    Cell cell;
    GenericSkillClient skill(cell.a, cell.delay, 5s);
    auto values = skill.parse({"DurationMs=5", "FailWith=boom, really"});
    ASSERT_EQ(values.size(), 2u);
    EXPECT_EQ(values[0].second, ua::Variant(5.0));
    EXPECT_EQ(values[1].second, ua::Variant(ua::String("boom, really")));
    try {
        skill.parse({"DurationMs=abc"});
        FAIL();
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadTypeMismatch);
        std::string what = e.what();
        EXPECT_NE(what.find("DurationMs"), std::string::npos) << what;
        EXPECT_NE(what.find("Double"), std::string::npos) << what;
    }
    EXPECT_EQ(errorOf([&] { skill.parse({"Nope=1"}); }), status::BadNotFound);
    EXPECT_EQ(errorOf([&] { skill.parse({"DurationMs"}); }), status::BadSyntaxError);
    skill.setParametersFromText({"DurationMs=7.5"});
    EXPECT_EQ(skill.parameter("DurationMs"), ua::Variant(7.5));
    std::string text = skill.describe();
    EXPECT_NE(text.find("DurationMs: Double = 7.5"), std::string::npos) << text;
    EXPECT_NE(text.find("FailWith: String"), std::string::npos) << text;

    // Forms of the other types, on declared parameters.
    auto p = [](ua::UInt32 type, ua::Int32 rank) {
        return ParameterInfo{"P", {}, ua::NodeId(0, type), rank, true};
    };
    EXPECT_EQ(coerce(p(ua::ns0::Double, 1), "[1, 2,3]"), ua::Variant(std::vector<double>{1, 2, 3}));
    EXPECT_EQ(coerce(p(ua::ns0::Double, 1), "1,2"), ua::Variant(std::vector<double>{1, 2}));
    EXPECT_EQ(coerce(p(ua::ns0::Boolean, -1), "true"), ua::Variant(true));
    EXPECT_EQ(coerce(p(ua::ns0::Int32, -1), "-4"), ua::Variant(ua::Int32{-4}));
    EXPECT_EQ(coerce(p(ua::ns0::UInt32, 1), "[1,2]"), ua::Variant(std::vector<ua::UInt32>{1, 2}));
    EXPECT_EQ(coerce(p(ua::ns0::LocalizedText, -1), "hi"),
              ua::Variant(ua::LocalizedText("", "hi")));
    ua::ThreeDFrame f;
    f.cartesianCoordinates = {1, 2, 3};
    f.orientation = {4, 5, 6};
    EXPECT_EQ(coerce(p(ua::ns0::ThreeDFrame, -1), "1,2,3,4,5,6"),
              ua::Variant(ua::toExtensionObject(f)));
    EXPECT_EQ(coerce(p(ua::ns0::ThreeDVector, -1), "1,2,3"),
              ua::Variant(ua::toExtensionObject(ua::ThreeDVector{1, 2, 3})));
    EXPECT_EQ(coerce(p(ua::ns0::Range, 1), "[0,1],[2,3]"),
              ua::Variant(std::vector<ua::ExtensionObject>{
                  ua::toExtensionObject(ua::Range{0, 1}), ua::toExtensionObject(ua::Range{2, 3})}));
    EXPECT_EQ(formatValue(coerce(p(ua::ns0::Range, -1), "0.5,2")), "0.5,2");
    EXPECT_EQ(errorOf([&] { coerce(p(ua::ns0::ThreeDFrame, -1), "1,2,3"); }),
              status::BadTypeMismatch);
    EXPECT_EQ(errorOf([&] { coerce(p(ua::ns0::Byte, -1), "300"); }), status::BadTypeMismatch);
    EXPECT_EQ(errorOf([&] { coerce(p(ua::ns0::Boolean, -1), "yes"); }), status::BadTypeMismatch);
}

TEST(SkillClient, LockSeenFromTwoClients) {
    Cell cell;
    SkillClient a(cell.a, cell.delay, 5s);
    SkillClient b(cell.b, cell.delay, 5s);
    ASSERT_TRUE(a.lock("test a"));
    EXPECT_FALSE(b.lock("test b"));
    EXPECT_EQ(errorOf([&] { b.setParameter("DurationMs", 1.0); }), status::BadLocked);
    EXPECT_EQ(errorOf([&] { b.start(); }), status::BadLocked);
    EXPECT_FALSE(b.renewLock());
    EXPECT_TRUE(a.renewLock());
    a.setParameter("DurationMs", 1.0);  // the holder may write
    EXPECT_TRUE(a.unlock());
    EXPECT_FALSE(a.unlock());
    ASSERT_TRUE(b.lock("test b"));
    b.setParameter("DurationMs", 2.0);
    EXPECT_TRUE(b.unlock());
}

TEST(SkillClient, RunCompletes) {
    Cell cell;
    SkillClient skill(cell.a, cell.delay, 5s);
    RunResult r = skill.run({{"DurationMs", 20.0}, {"FailWith", ua::String("")}}, 5s);
    EXPECT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_FALSE(r.timedOut);
    EXPECT_EQ(numbersOf(r.transitions), (std::vector<ua::UInt32>{2, 4}));
    ASSERT_EQ(r.transitions.size(), 2u);
    EXPECT_EQ(r.transitions[0].from, ProgramState::Ready);
    EXPECT_EQ(r.transitions[0].to, ProgramState::Running);
    EXPECT_EQ(r.transitions[1].to, ProgramState::Ready);
    EXPECT_EQ(r.transitions[1].source, cell.delay);
    EXPECT_EQ(skill.state(), ProgramState::Ready);
    // The lock was released.
    SkillClient other(cell.b, cell.delay, 5s);
    EXPECT_TRUE(other.lock());
    EXPECT_TRUE(other.unlock());

    // Latency of a no-op run (lock, state, write, Start, events, result, unlock).
    std::vector<double> us;
    for (int i = 0; i < 20; ++i) {
        auto t0 = ua::client::Clock::now();
        RunResult n = skill.run({{"DurationMs", 0.0}}, 5s);
        us.push_back(
            std::chrono::duration<double, std::micro>(ua::client::Clock::now() - t0).count());
        ASSERT_EQ(n.result, SkillResult::Completed) << n.message;
    }
    std::sort(us.begin(), us.end());
    std::printf("no-op run(): median %.0f us, max %.0f us (20 runs)\n", us[us.size() / 2],
                us.back());
}

// With a long publishing interval, a no-op run's events are held back and its end is found by
// polling; they arrive during the next run, which must not take them for its own (it would
// end at once, with the result it has cleared: None).
TEST(SkillClient, LateEventsOfAnEarlierRunAreNotTakenForTheNext) {
    Cell cell;
    SkillClient skill(cell.a, cell.delay, 5s, SkillClientOptions{.publishingInterval = 300});
    for (int i = 0; i < 3; ++i) {
        RunResult r = skill.run({{"DurationMs", 0.0}, {"FailWith", ua::String("")}}, 5s);
        ASSERT_EQ(r.result, SkillResult::Completed) << "no-op run " << i << ": " << r.message;
    }
    // Started within the interval after the no-op runs' events: theirs arrive during it.
    const auto t0 = ua::client::Clock::now();
    RunResult r = skill.run({{"DurationMs", 500.0}}, 5s);
    const auto took = ua::client::Clock::now() - t0;
    EXPECT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_GE(took, 500ms) << "ended on an earlier run's events";
    ASSERT_FALSE(r.transitions.empty());
    EXPECT_EQ(r.transitions.back().to, ProgramState::Ready);
    EXPECT_EQ(numbersOf(r.transitions), (std::vector<ua::UInt32>{2, 4}));
}

TEST(SkillClient, RunFailsThenResetsOnTheNextRun) {
    Cell cell;
    SkillClient skill(cell.a, cell.delay, 5s);
    std::mutex m;
    std::vector<Transition> seen;
    skill.onTransition([&](const Transition& t) {
        std::lock_guard l(m);
        seen.push_back(t);
    });
    RunResult r = skill.run({{"DurationMs", 0.0}, {"FailWith", ua::String("gripper jammed")}}, 5s);
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_EQ(r.message, "gripper jammed");
    EXPECT_EQ(numbersOf(r.transitions), (std::vector<ua::UInt32>{2, 3}));
    EXPECT_EQ(skill.state(), ProgramState::Halted);

    RunResult again = skill.run({{"FailWith", ua::String("")}}, 5s);
    EXPECT_EQ(again.result, SkillResult::Completed) << again.message;
    EXPECT_EQ(numbersOf(again.transitions), (std::vector<ua::UInt32>{2, 4}));
    // The callback saw all of it in order, Reset's Halted -> Ready included.
    for (int i = 0; i < 200; ++i) {
        {
            std::lock_guard l(m);
            if (seen.size() >= 5) break;
        }
        std::this_thread::sleep_for(5ms);
    }
    std::lock_guard l(m);
    EXPECT_EQ(numbersOf(seen), (std::vector<ua::UInt32>{2, 3, 1, 2, 4}));
    EXPECT_EQ(skill.takeTransitions().size(), 5u);
}

TEST(SkillClient, RunPastItsDeadlineIsHalted) {
    Cell cell;
    SkillClient skill(cell.a, cell.delay, 5s);
    auto t0 = ua::client::Clock::now();
    RunResult r = skill.run({{"DurationMs", 10000.0}}, 300ms);
    auto took = ua::client::Clock::now() - t0;
    EXPECT_TRUE(r.timedOut);
    EXPECT_EQ(r.result, SkillResult::Aborted);
    EXPECT_LT(took, 3s);
    ASSERT_FALSE(r.transitions.empty());
    EXPECT_EQ(r.transitions.front().number, 2u);
    EXPECT_EQ(r.transitions.back().number, 3u);  // Running -> Halted
    EXPECT_EQ(skill.state(), ProgramState::Halted);
    // Unlocked: another client runs it (Reset first).
    SkillClient other(cell.b, cell.delay, 5s);
    RunResult next = other.run({{"DurationMs", 0.0}}, 5s);
    EXPECT_EQ(next.result, SkillResult::Completed) << next.message;
}

TEST(SkillClient, RunCancelled) {
    Cell cell;
    SkillClient skill(cell.a, cell.delay, 5s);
    std::stop_source stop;
    std::jthread canceller([&] {
        std::this_thread::sleep_for(100ms);
        stop.request_stop();
    });
    auto t0 = ua::client::Clock::now();
    RunResult r = skill.run({{"DurationMs", 10000.0}}, 10s, stop.get_token());
    EXPECT_LT(ua::client::Clock::now() - t0, 3s);
    EXPECT_FALSE(r.timedOut);
    EXPECT_EQ(r.result, SkillResult::Aborted);
    EXPECT_EQ(skill.state(), ProgramState::Halted);
}

TEST(SkillClient, SuspendAndResumeDuringARun) {
    Cell cell;
    SkillClient skill(cell.a, cell.delay, 5s);
    skill.subscribeTransitions();
    std::future<RunResult> run = std::async(std::launch::async, [&] {
        return skill.run({{"DurationMs", 300.0}}, 10s);
    });
    std::optional<Transition> t = skill.nextTransition(5s);
    ASSERT_TRUE(t);
    EXPECT_EQ(t->number, 2u);
    skill.suspend();  // the same session holds the lock
    EXPECT_EQ(skill.state(), ProgramState::Suspended);
    std::this_thread::sleep_for(50ms);
    skill.resume();
    ASSERT_EQ(run.wait_for(10s), std::future_status::ready);
    RunResult r = run.get();
    EXPECT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_EQ(numbersOf(r.transitions), (std::vector<ua::UInt32>{2, 5, 6, 4}));
}

TEST(SkillClient, RunWaitsForAnotherClientsLock) {
    Cell cell;
    SkillClient a(cell.a, cell.delay, 5s);
    SkillClient b(cell.b, cell.delay, 5s);
    ASSERT_TRUE(a.lock());
    // Still locked at the deadline: BadLocked.
    EXPECT_EQ(errorOf([&] { b.run({{"DurationMs", 0.0}}, 200ms); }), status::BadLocked);
    std::jthread release([&] {
        std::this_thread::sleep_for(100ms);
        a.unlock();
    });
    RunResult r = b.run({{"DurationMs", 0.0}}, 5s);
    EXPECT_EQ(r.result, SkillResult::Completed) << r.message;
}

TEST(TypedClients, CheckTheSkillType) {
    Cell cell;
    try {
        GraspGripperSkillClient grasp(cell.a, cell.delay, 5s);
        FAIL() << "a Grasp client accepted a Delay skill";
    } catch (const Error& e) {
        EXPECT_EQ(e.status(), status::BadTypeMismatch);
        EXPECT_NE(std::string(e.what()).find("GraspGripperSkillType"), std::string::npos);
    }
    EXPECT_EQ(errorOf([&] { MoveGripperSkillClient(cell.a, cell.delay, 5s); }),
              status::BadTypeMismatch);
    EXPECT_EQ(errorOf([&] { JointPtpMoveSkillClient(cell.a, cell.delay, 5s); }),
              status::BadTypeMismatch);
    // A node that is no skill at all.
    EXPECT_EQ(errorOf([&] { SkillClient(cell.a, ua::NodeId(0, ua::ns0::Server), 5s); }),
              status::BadTypeMismatch);
}

}  // namespace
