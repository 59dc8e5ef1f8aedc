// GripperDevice over an in-process gripper (FakeGripper), driven by our OPC UA client over
// 127.0.0.1: every skill, a grasp on empty air fails saying so, Halt mid-grasp stops the jaws,
// bad parameters fail before anything moves, and the IGripperType / identity / status nodes.
#include "device/gripper/gripper_device.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>
#include <vector>

#include "gripper_rig.hpp"
#include "skill/client/skill_client.hpp"
#include "skill/client/typed_clients.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_types_model.hpp"

using namespace pnp;
using namespace std::chrono_literals;
using device::gripper::GripKind;
using pnp::testing::GripperRig;
using pnp::testing::waitUntil;
using skill::ProgramState;
using skill::SkillResult;
using skill::client::SkillClient;
namespace names = device::gripper::skill_names;

namespace {

// A node's value as T (a copy), nullopt when it is not a T.
template <class T>
std::optional<T> readAs(GripperRig& rig, const ua::NodeId& node) {
    const ua::Variant v = rig.ua->readValue(node, 5s);
    const T* p = v.scalar<T>();
    return p ? std::optional<T>(*p) : std::nullopt;
}

// ---- the skills -----------------------------------------------------------------------------

TEST(GripperDevice, GraspHoldsAnObject) {
    GripperRig rig;
    rig.hardware.timeScale = 20.0;
    skill::client::GraspGripperSkillClient grasp(rig.ua, rig.skill(names::Grasp), 5s);
    auto r = grasp.run(35.0, 10s);
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_EQ(rig.hardware.grasps.load(), 1);
    EXPECT_DOUBLE_EQ(rig.hardware.lastForce.load(), 35.0);
    EXPECT_TRUE(rig.hardware.holding.load());
    EXPECT_NEAR(rig.hardware.width.load(), 0.03, 1e-9);
    // Activated once, before the first motion (the fake started unactivated).
    EXPECT_EQ(rig.hardware.activations.load(), 1);
    // The status variables follow what the hardware reported.
    EXPECT_TRUE(waitUntil(
        [&] { return readAs<bool>(rig, rig.device->statusNode("Holding")).value_or(false); },
        2000ms));
    const auto w = readAs<double>(rig, rig.device->statusNode("Width"));
    ASSERT_TRUE(w.has_value());
    EXPECT_NEAR(*w, 0.03, 1e-9);
}

TEST(GripperDevice, GraspOnEmptyAirFailsSayingSo) {
    GripperRig rig;
    rig.hardware.timeScale = 50.0;
    rig.hardware.objectPresent = false;
    skill::client::GraspGripperSkillClient grasp(rig.ua, rig.skill(names::Grasp), 5s);
    auto r = grasp.run(std::nullopt, 10s);
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_EQ(r.message, "Grasp failed: no object between the fingers");
    EXPECT_EQ(grasp.state(5s), ProgramState::Halted);
    EXPECT_FALSE(rig.hardware.holding.load());
    EXPECT_DOUBLE_EQ(rig.hardware.lastForce.load(), 20.0);  // the type's default Force
}

TEST(GripperDevice, GraspFailsWhenTheHardwareReportsNothingHeld) {
    // A driver whose grasp "succeeds" with nothing held is not believed.
    GripperRig rig;
    rig.hardware.claimGraspWithoutHolding = true;
    skill::client::GraspGripperSkillClient grasp(rig.ua, rig.skill(names::Grasp), 5s);
    auto r = grasp.run(20.0, 10s);
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_EQ(r.message, "Grasp failed: the gripper reports no object held");
}

TEST(GripperDevice, AVacuumGraspFailsWithoutAPart) {
    GripperRig rig(GripKind::kVacuum);
    skill::client::GraspGripperSkillClient grasp(rig.ua, rig.skill(names::Grasp), 5s);
    auto ok = grasp.run(20.0, 10s);
    ASSERT_EQ(ok.result, SkillResult::Completed) << ok.message;
    rig.hardware.objectPresent = false;
    auto r = grasp.run(20.0, 10s);
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_EQ(r.message, "Grasp failed: no part present");
}

TEST(GripperDevice, AFailingHardwareCallFailsTheSkillWithItsReason) {
    GripperRig rig;
    {
        std::lock_guard l(rig.hardware.failMutex);
        rig.hardware.failNextGrasp =
            device::gripper::Error{device::gripper::ErrorKind::kFault, "overcurrent triggered"};
    }
    skill::client::GraspGripperSkillClient grasp(rig.ua, rig.skill(names::Grasp), 5s);
    auto r = grasp.run(20.0, 10s);
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_EQ(r.message, "Grasp failed: overcurrent triggered");
}

TEST(GripperDevice, AnUnpoweredGripperFailsTheSkillAtOnce) {
    GripperRig rig;
    rig.hardware.powered = false;
    skill::client::ReleaseGripperSkillClient release(rig.ua, rig.skill(names::Release), 5s);
    const auto t0 = std::chrono::steady_clock::now();
    auto r = release.run(std::nullopt, 10s);
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_NE(r.message.find("Release failed: "), std::string::npos) << r.message;
    EXPECT_NE(r.message.find("no answer"), std::string::npos) << r.message;
    EXPECT_LT(std::chrono::steady_clock::now() - t0, 3s);
}

TEST(GripperDevice, ReleaseAndMoveGripperReachTheirWidths) {
    GripperRig rig;
    rig.hardware.timeScale = 20.0;
    skill::client::MoveGripperSkillClient move(rig.ua, rig.skill(names::MoveGripper), 5s);
    auto m = move.run(0.04, 50.0, 10s);
    ASSERT_EQ(m.result, SkillResult::Completed) << m.message;
    EXPECT_NEAR(rig.hardware.width.load(), 0.04, 1e-9);
    EXPECT_DOUBLE_EQ(rig.hardware.lastForce.load(), 50.0);
    skill::client::ReleaseGripperSkillClient release(rig.ua, rig.skill(names::Release), 5s);
    auto r = release.run(std::nullopt, 10s);
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_NEAR(rig.hardware.width.load(), 0.085, 1e-9);
    EXPECT_EQ(rig.hardware.releases.load(), 1);
}

TEST(GripperDevice, HaltMidGraspStopsTheJaws) {
    GripperRig rig;
    rig.hardware.timeScale = 0.05;  // 2.5 mm/s: the grasp would take 20 s
    SkillClient grasp(rig.ua, rig.skill(names::Grasp), 5s);
    grasp.start(5s);
    ASSERT_TRUE(waitUntil([&] { return rig.hardware.moving.load(); }, 3000ms));
    const double before = rig.hardware.width.load();
    ASSERT_TRUE(waitUntil([&] { return rig.hardware.width.load() < before; }, 3000ms));
    grasp.halt(5s);
    EXPECT_TRUE(waitUntil([&] { return !rig.hardware.moving.load(); }, 1000ms));
    EXPECT_EQ(rig.hardware.cancelled.load(), 1);
    EXPECT_GE(rig.hardware.stops.load(), 1);
    EXPECT_EQ(grasp.state(5s), ProgramState::Halted);
    EXPECT_EQ(grasp.finalResult(5s).result, SkillResult::Aborted);
    // Stopped: the jaws stay where they were.
    const double stopped = rig.hardware.width.load();
    std::this_thread::sleep_for(50ms);
    EXPECT_DOUBLE_EQ(rig.hardware.width.load(), stopped);
    EXPECT_GT(stopped, 0.03);
    // Reset, and the next grasp runs.
    rig.hardware.timeScale = 50.0;
    grasp.reset(5s);
    auto r = grasp.run({}, 10s);
    EXPECT_EQ(r.result, SkillResult::Completed) << r.message;
}

TEST(GripperDevice, StartReachesTheHardwareWithinMilliseconds) {
    // The target: gripper skill Start -> first command frame <= 3 ms (median). Here:
    // the Start request sent -> the hardware's grasp() called (the Robotiq writes its request
    // frame first thing in it).
    GripperRig rig;
    rig.hardware.timeScale = 1000.0;
    SkillClient grasp(rig.ua, rig.skill(names::Grasp), 5s);
    ASSERT_EQ(grasp.run({}, 10s).result, SkillResult::Completed);  // activated, warmed up
    // The median of 20 Starts, measured in up to 3 rounds: a machine loaded by other work
    // (CI runs the tests in parallel) may slow one round down; the target holds for a round.
    constexpr double kTargetMs = 3.0;
    double best = 0.0;
    for (int round = 0; round < 3; ++round) {
        std::vector<double> ms;
        for (int i = 0; i < 20; ++i) {
            const auto before = rig.hardware.grasps.load();
            const auto t0 = device::gripper::Clock::now();
            grasp.start(5s);
            ASSERT_TRUE(waitUntil([&] { return rig.hardware.grasps.load() > before; }, 5000ms));
            const device::gripper::Clock::time_point called(
                device::gripper::Clock::duration(rig.hardware.graspCalledAt.load()));
            ms.push_back(std::chrono::duration<double, std::milli>(called - t0).count());
            ASSERT_TRUE(waitUntil([&] { return grasp.state(5s) == ProgramState::Ready; }, 5000ms));
        }
        std::sort(ms.begin(), ms.end());
        std::printf("Start sent -> hardware grasp(), round %d: median %.3f ms, max %.3f ms\n",
                    round + 1, ms[ms.size() / 2], ms.back());
        best = round == 0 ? ms[ms.size() / 2] : std::min(best, ms[ms.size() / 2]);
        if (best <= kTargetMs) break;
    }
#ifndef PNP_SANITIZED_BUILD  // a performance target: asserted in optimised builds only
    EXPECT_LE(best, kTargetMs);
#endif
}

TEST(GripperDevice, BadParametersFailAndNothingMoves) {
    GripperRig rig;
    SkillClient grasp(rig.ua, rig.skill(names::Grasp), 5s);
    auto g = grasp.run({{"Force", ua::Variant(-5.0)}}, 10s);
    EXPECT_EQ(g.result, SkillResult::Failed);
    EXPECT_EQ(g.message, "Grasp failed: Force must be a finite number >= 0 N, got -5");

    SkillClient move(rig.ua, rig.skill(names::MoveGripper), 5s);
    auto wide = move.run({{"Width", ua::Variant(0.2)}, {"Force", ua::Variant(20.0)}}, 10s);
    EXPECT_EQ(wide.result, SkillResult::Failed);
    EXPECT_EQ(wide.message,
              "MoveGripper failed: Width 0.2 m is outside the gripper's span 0 .. 0.085 m");
    move.reset(5s);
    auto negative = move.run({{"Width", ua::Variant(-0.01)}, {"Force", ua::Variant(20.0)}}, 10s);
    EXPECT_EQ(negative.result, SkillResult::Failed);
    EXPECT_NE(negative.message.find("outside the gripper's span"), std::string::npos);
    move.reset(5s);
    auto nan = move.run({{"Width", ua::Variant(0.04)}, {"Force", ua::Variant(std::nan(""))}}, 10s);
    EXPECT_EQ(nan.result, SkillResult::Failed);
    EXPECT_NE(nan.message.find("Force must be"), std::string::npos) << nan.message;

    SkillClient release(rig.ua, rig.skill(names::Release), 5s);
    auto rel = release.run({{"Force", ua::Variant(-1.0)}}, 10s);
    EXPECT_EQ(rel.result, SkillResult::Failed);

    EXPECT_EQ(rig.hardware.grasps.load(), 0);
    EXPECT_EQ(rig.hardware.moves.load(), 0);
    EXPECT_EQ(rig.hardware.releases.load(), 0);
    EXPECT_EQ(rig.hardware.activations.load(), 0);
    EXPECT_DOUBLE_EQ(rig.hardware.width.load(), 0.085);
}

// ---- the nodes ------------------------------------------------------------------------------

TEST(GripperDevice, IGripperTypeGripPointIsReadable) {
    GripperRig rig;
    const ua::UInt16 sk = rig.skills();
    const std::string gp =
        "/" + std::to_string(sk) + ":GripPoints/" + std::to_string(sk) + ":GripPoint_1/";
    const ua::NodeId device = rig.device->node();
    const ua::NodeId type = rig.ua->resolve(device, gp + std::to_string(sk) + ":Type", 5s);
    const ua::NodeId offset = rig.ua->resolve(device, gp + std::to_string(sk) + ":Offset", 5s);
    const ua::NodeId span = rig.ua->resolve(device, gp + std::to_string(sk) + ":Span", 5s);

    const auto kind = readAs<ua::Int32>(rig, type);
    ASSERT_TRUE(kind.has_value());
    EXPECT_EQ(*kind, 0);  // Parallel
    const auto ox = readAs<ua::ExtensionObject>(rig, offset);
    ASSERT_TRUE(ox.has_value());
    auto frame = ua::fromExtensionObject<ua::ThreeDFrame>(*ox);
    ASSERT_TRUE(frame.has_value());
    EXPECT_DOUBLE_EQ(frame->cartesianCoordinates.z, 0.2028);
    EXPECT_DOUBLE_EQ(frame->cartesianCoordinates.x, 0.0);
    const auto sx = readAs<ua::ExtensionObject>(rig, span);
    ASSERT_TRUE(sx.has_value());
    auto range = ua::fromExtensionObject<ua::Range>(*sx);
    ASSERT_TRUE(range.has_value());
    EXPECT_DOUBLE_EQ(range->low, 0.0);
    EXPECT_DOUBLE_EQ(range->high, 0.085);
    // DisplayName: the grip point's name.
    auto dn = rig.ua->readAttribute(rig.device->gripPoint(), ua::AttributeId::DisplayName, 5s);
    const auto* text = dn.value ? dn.value->scalar<ua::LocalizedText>() : nullptr;
    ASSERT_NE(text, nullptr);
    EXPECT_EQ(text->text, "Tip");

    // HasInterface IGripperType and ISkillControllerType.
    ua::client::BrowseOptions b;
    b.referenceTypeId = ua::NodeId(0, ua::ns0::HasInterface);
    bool gripper = false, controller = false;
    for (const auto& r : rig.ua->browse(device, b, 5s)) {
        if (r.nodeId.nodeId == ua::NodeId(sk, ua::UInt32{1020})) gripper = true;
        if (r.nodeId.nodeId == ua::NodeId(sk, ua::UInt32{1002})) controller = true;
    }
    EXPECT_TRUE(gripper);
    EXPECT_TRUE(controller);

    // Identification from the hardware.
    const std::string di = "/" + std::to_string(rig.di()) + ":";
    const auto m = readAs<ua::LocalizedText>(rig, rig.ua->resolve(device, di + "Manufacturer", 5s));
    ASSERT_TRUE(m.has_value());
    EXPECT_EQ(m->text, "Fake Grippers Inc.");
    const auto model = readAs<ua::LocalizedText>(rig, rig.ua->resolve(device, di + "Model", 5s));
    ASSERT_TRUE(model.has_value());
    EXPECT_EQ(model->text, "FG-85");
    const auto sn = readAs<ua::String>(rig, rig.ua->resolve(device, di + "SerialNumber", 5s));
    ASSERT_TRUE(sn.has_value());
    EXPECT_EQ(*sn, "SN-0042");
}

TEST(GripperDevice, AVacuumGripperHasNoMoveGripperAndNoSpan) {
    GripperRig rig(GripKind::kVacuum);
    EXPECT_FALSE(rig.skill(names::Grasp).isNull());
    EXPECT_FALSE(rig.skill(names::Release).isNull());
    EXPECT_TRUE(rig.skill(names::MoveGripper).isNull());
    const ua::UInt16 sk = rig.skills();
    const std::string gp =
        "/" + std::to_string(sk) + ":GripPoints/" + std::to_string(sk) + ":GripPoint_1/";
    const auto kind = readAs<ua::Int32>(
        rig, rig.ua->resolve(rig.device->node(), gp + std::to_string(sk) + ":Type", 5s));
    ASSERT_TRUE(kind.has_value());
    EXPECT_EQ(*kind, 1);  // Vacuum
    EXPECT_THROW(rig.ua->resolve(rig.device->node(), gp + std::to_string(sk) + ":Span", 5s),
                 ua::client::Error);
    EXPECT_FALSE(rig.device->statusNode("Vacuum").isNull());
    EXPECT_TRUE(rig.device->statusNode("Width").isNull());
}

}  // namespace
