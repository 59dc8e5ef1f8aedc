// RobotDevice over an in-process arm (FakeArm, paced at 2 ms) with the real robot::Controller
// and robot::Planner, driven by our OPC UA client over 127.0.0.1: each move skill reaches its
// target, refused requests never move the arm, Halt brakes, Suspend / Resume stay on the path,
// a force limit ends the move Halted with ForcesExceeded, and the Robotics nodes follow the arm.
#include "device/robot/robot_device.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <thread>
#include <vector>

#include "kinematics/kinematics.hpp"
#include "robot_rig.hpp"
#include "skill/client/skill_client.hpp"
#include "skill/client/typed_clients.hpp"
#include "support/loopback_server.hpp"
#include "support/wait.hpp"
#include "ua/client/client.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp;
using namespace std::chrono_literals;
using device::robot::RobotDevice;
using pnp::testing::FakeArm;
using pnp::testing::waitUntil;
using skill::ProgramState;
using skill::SkillResult;
using skill::client::CartesianMove;
using skill::client::JointMove;
using skill::client::SkillClient;
namespace names = device::robot::skill_names;
namespace status = ua::status;

namespace {

using pnp::testing::distance;
using pnp::testing::kHome;
using pnp::testing::kPi;
using pnp::testing::Rig;

// A run ends when the last point is commanded; the arm gets there within a few cycles.
void settle(const Rig& rig) {
    EXPECT_TRUE(waitUntil([&] { return rig.arm.atRest(); }, 1000ms));
}

ua::ThreeDFrame frameOf(const Eigen::Isometry3d& pose) { return ua::spatial::toFrame(pose); }

// Position and rotation error between two poses (m, rad).
std::pair<double, double> poseError(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
    const double p = (a.translation() - b.translation()).norm();
    const double r = Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
    return {p, r};
}

// The target `shift` m away from where the flange is (same orientation).
Eigen::Isometry3d shifted(const Rig& rig, const Eigen::Vector3d& shift) {
    Eigen::Isometry3d t = rig.flangeAt(rig.arm.q());
    t.translation() += shift;
    return t;
}

// Starts a skill with these parameters (no lock) and waits until it runs.
void startSkill(SkillClient& s, const skill::client::NamedValues& params) {
    s.setParameters(params, 5s);
    s.start(5s);
}

ProgramState waitForEnd(SkillClient& s, std::chrono::milliseconds timeout = 20000ms) {
    ProgramState st = ProgramState::Unknown;
    waitUntil(
        [&] {
            st = s.state(5s);
            return st == ProgramState::Ready || st == ProgramState::Halted;
        },
        timeout);
    return st;
}

// ---- every skill reaches its target ------------------------------------------------------

TEST(RobotDevice, JointPtpMoveReachesTheTarget) {
    Rig rig;
    skill::client::JointPtpMoveSkillClient s(rig.ua, rig.skill(names::JointPtpMove), 5s);
    robot::Joints goal = kHome;
    goal[0] += 0.3;
    goal[2] -= 0.2;
    goal[5] += 0.5;
    auto r = s.run(JointMove{{goal.begin(), goal.end()}, {}, {}, ""}, 20s);
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    settle(rig);
    EXPECT_TRUE(waitUntil([&] { return rig.arm.atRest(); }, 1000ms));
    EXPECT_LT(distance(rig.arm.q(), goal), 1e-6);
    // Progress was reported and ended at 1.
    ASSERT_FALSE(r.transitions.empty());
    const auto* last = r.transitions.back().intermediateResult.scalar<double>();
    ASSERT_NE(last, nullptr);
    EXPECT_DOUBLE_EQ(*last, 1.0);
}

TEST(RobotDevice, JointLinearMoveReachesTheTarget) {
    Rig rig;
    skill::client::JointLinearMoveSkillClient s(rig.ua, rig.skill(names::JointLinearMove), 5s);
    // A nearby configuration of the same branch: the line ends in exactly these joints.
    const Eigen::Isometry3d goalPose = shifted(rig, {0.05, -0.04, 0.03});
    auto goal = kinematics::solveNearest(rig.arm.model(), goalPose, rig.arm.q());
    ASSERT_TRUE(goal.ok());
    auto r = s.run(JointMove{{goal->begin(), goal->end()}, {}, {}, ""}, 20s);
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    settle(rig);
    EXPECT_LT(distance(rig.arm.q(), *goal), 1e-6);
}

TEST(RobotDevice, CartesianPtpMoveReachesThePose) {
    Rig rig;
    skill::client::CartesianPtpMoveSkillClient s(rig.ua, rig.skill(names::CartesianPtpMove), 5s);
    Eigen::Isometry3d target = shifted(rig, {0.08, 0.05, -0.06});
    target.linear() = target.linear() * Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()).matrix();
    auto r = s.run(CartesianMove{frameOf(target), {}, {}, {}, ""}, 20s);
    ASSERT_EQ(r.run.result, SkillResult::Completed) << r.run.message;
    settle(rig);
    auto [p, a] = poseError(rig.flangeAt(rig.arm.q()), target);
    EXPECT_LE(p, 1e-5) << "end pose error " << p * 1e3 << " mm";
    EXPECT_LE(a, 1e-5);
    EXPECT_FALSE(r.forcesExceeded);
    ASSERT_TRUE(r.forcesMax.has_value());
}

TEST(RobotDevice, CartesianLinearForceMoveCompletesBelowTheLimit) {
    Rig rig;
    SkillClient s(rig.ua, rig.skill(names::CartesianLinearForceMove), 5s);
    const Eigen::Isometry3d target = shifted(rig, {0.0, 0.05, -0.05});
    rig.arm.setForce([](double, const robot::Joints&) {
        return std::array<double, 6>{1.0, -2.0, 3.0, 0, 0, 0};
    });
    auto r = skill::client::cartesianResultOf(
        s.run({{"TargetPosition", ua::Variant(ua::toExtensionObject(frameOf(target)))},
               {"MaxForce", ua::Variant(ua::toExtensionObject(ua::ThreeDVector{50, 50, 50}))}},
              20s));
    ASSERT_EQ(r.run.result, SkillResult::Completed) << r.run.message;
    settle(rig);
    auto [p, a] = poseError(rig.flangeAt(rig.arm.q()), target);
    EXPECT_LE(p, 1e-5);
    EXPECT_LE(a, 1e-5);
    EXPECT_FALSE(r.forcesExceeded);
    ASSERT_TRUE(r.forcesMax.has_value());
    EXPECT_NEAR(r.forcesMax->x, 1.0, 1e-9);
    EXPECT_NEAR(r.forcesMax->y, 2.0, 1e-9);
    EXPECT_NEAR(r.forcesMax->z, 3.0, 1e-9);
}

TEST(RobotDevice, ForceAboveMaxForceEndsHaltedWithForcesExceeded) {
    Rig rig;
    SkillClient s(rig.ua, rig.skill(names::CartesianLinearForceMove), 5s);
    const Eigen::Isometry3d target = shifted(rig, {0.0, 0.0, -0.15});
    // A surface 3 cm below the flange, as a 1000 N/m spring: 20 N 2 cm into it; 120 N at
    // the target.
    const double surface = rig.flangeAt(rig.arm.q()).translation().z() - 0.03;
    const kinematics::RobotModel model = rig.arm.model();
    rig.arm.setForce([surface, model](double, const robot::Joints& q) {
        const double depth = surface - kinematics::forward(model, q).translation().z();
        return std::array<double, 6>{0.0, 0.0, -1000.0 * std::max(0.0, depth), 0, 0, 0};
    });
    rig.arm.mark();
    auto r = skill::client::cartesianResultOf(
        s.run({{"TargetPosition", ua::Variant(ua::toExtensionObject(frameOf(target)))},
               {"MaxForce", ua::Variant(ua::toExtensionObject(ua::ThreeDVector{100, 100, 20}))}},
              20s));
    EXPECT_EQ(r.run.result, SkillResult::Failed) << r.run.message;
    EXPECT_EQ(s.state(5s), ProgramState::Halted);
    EXPECT_NE(r.run.message.find("force"), std::string::npos) << r.run.message;
    EXPECT_TRUE(r.forcesExceeded);
    ASSERT_TRUE(r.forcesMax.has_value());
    EXPECT_GT(r.forcesMax->z, 20.0);
    EXPECT_LT(r.forcesMax->z, 100.0);  // braked when it was exceeded, not at the target
    EXPECT_NEAR(r.forcesMax->x, 0.0, 1e-9);
    // Stopped short of the target, at rest, braking within the limits.
    EXPECT_TRUE(waitUntil([&] { return rig.arm.atRest(); }, 2000ms));
    EXPECT_GT(poseError(rig.flangeAt(rig.arm.q()), target).first, 0.02);
    EXPECT_LE(rig.arm.maxSpeedRatio(), 1.001);
    EXPECT_LE(rig.arm.maxAccelerationRatio(), 1.05);
}

TEST(RobotDevice, PositionStreamFollowsWrittenTargetsUntilHalt) {
    Rig rig;
    SkillClient s(rig.ua, rig.skill(names::PositionStream), 5s);
    const auto* p = s.findParameter("TargetJointPosition");
    ASSERT_NE(p, nullptr);
    robot::Joints a = kHome;
    a[0] += 0.1;
    startSkill(s, {{"TargetJointPosition", ua::Variant(std::vector<double>(a.begin(), a.end()))}});
    ASSERT_TRUE(waitUntil([&] { return distance(rig.arm.q(), a) < 1e-9; }, 5000ms));
    EXPECT_EQ(s.state(5s), ProgramState::Running);
    // Targets written while Running are followed; a refused one changes nothing.
    robot::Joints b = a;
    b[1] -= 0.2;
    b[4] += 0.1;
    EXPECT_EQ(rig.ua->writeValue(p->node, ua::Variant(std::vector<double>(b.begin(), b.end())), 5s),
              ua::StatusCode{});
    ASSERT_TRUE(waitUntil([&] { return distance(rig.arm.q(), b) < 1e-9; }, 5000ms));
    EXPECT_TRUE(rig.ua->writeValue(p->node, ua::Variant(std::vector<double>{0, 0, 0}), 5s).isBad());
    EXPECT_TRUE(rig.ua->writeValue(p->node, ua::Variant(std::vector<double>{9, 0, 0, 0, 0, 0}), 5s)
                    .isBad());
    std::this_thread::sleep_for(100ms);
    EXPECT_LT(distance(rig.arm.q(), b), 1e-9);
    // Halt while moving: brakes, Aborted.
    robot::Joints c = b;
    c[0] -= 0.6;
    rig.arm.mark();
    EXPECT_EQ(rig.ua->writeValue(p->node, ua::Variant(std::vector<double>(c.begin(), c.end())), 5s),
              ua::StatusCode{});
    std::this_thread::sleep_for(150ms);
    s.halt(5s);
    EXPECT_EQ(waitForEnd(s), ProgramState::Halted);
    EXPECT_EQ(s.finalResult(5s).result, SkillResult::Aborted);
    EXPECT_TRUE(waitUntil([&] { return rig.arm.atRest(); }, 3000ms));
    EXPECT_GT(distance(rig.arm.q(), c), 0.05);
    EXPECT_LE(rig.arm.maxSpeedRatio(), 1.001);
    EXPECT_LE(rig.arm.maxAccelerationRatio(), 1.05);
}

// ---- refused requests never move the arm ----------------------------------------------------

struct Refusal {
    const char* skill;
    skill::client::NamedValues parameters;
    const char* says;  // a word of the reason
};

TEST(RobotDevice, BadTargetsFailWithAReasonAndNothingMoves) {
    Rig rig;
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const Eigen::Isometry3d near = shifted(rig, {0.05, 0.0, 0.0});
    ua::ThreeDFrame nanFrame = frameOf(near);
    nanFrame.cartesianCoordinates.y = nan;
    ua::ThreeDFrame far = frameOf(near);
    far.cartesianCoordinates.x = 5.0;
    auto frame = [](const ua::ThreeDFrame& f) { return ua::Variant(ua::toExtensionObject(f)); };
    auto joints = [](std::vector<double> q) { return ua::Variant(std::move(q)); };
    std::vector<double> home(kHome.begin(), kHome.end());
    std::vector<double> outside = home;
    outside[2] = 7.0;  // beyond ±2π
    std::vector<double> withNan = home;
    withNan[3] = nan;
    // Bounds that exclude every solution of axis 1 near home.
    std::vector<ua::Range> bounds(6, ua::Range{-2 * kPi, 2 * kPi});
    bounds[0] = ua::Range{1.0, 2.0};
    std::vector<ua::ExtensionObject> boundsX;
    for (const auto& b : bounds) boundsX.push_back(ua::toExtensionObject(b));
    std::vector<ua::ExtensionObject> fiveBounds(boundsX.begin(), boundsX.begin() + 5);

    const std::vector<Refusal> cases{
        {names::CartesianPtpMove, {{"TargetPosition", frame(nanFrame)}}, "finite"},
        {names::CartesianLinearMove, {{"TargetPosition", frame(nanFrame)}}, "finite"},
        {names::CartesianPtpMove, {{"TargetPosition", frame(far)}}, "reach"},
        {names::CartesianLinearMove, {{"TargetPosition", frame(far)}}, ""},
        {names::CartesianPtpMove,
         {{"TargetPosition", frame(frameOf(near))}, {"AxisBounds", ua::Variant(boundsX)}},
         "bound"},
        {names::CartesianPtpMove,
         {{"TargetPosition", frame(frameOf(near))}, {"AxisBounds", ua::Variant(fiveBounds)}},
         "AxisBounds"},
        {names::CartesianPtpMove,
         {{"TargetPosition", frame(frameOf(near))}, {"ToolFrame", ua::Variant(ua::String("nope"))}},
         "nope"},
        {names::CartesianPtpMove,
         {{"TargetPosition", frame(frameOf(near))},
          {"MaxVelocity", ua::Variant(std::vector<double>{1, 1})}},
         ""},
        {names::CartesianLinearForceMove,
         {{"TargetPosition", frame(frameOf(near))},
          {"MaxForce", ua::Variant(ua::toExtensionObject(ua::ThreeDVector{nan, 1, 1}))}},
         "MaxForce"},
        {names::JointPtpMove, {{"TargetJointPosition", joints({0, 0, 0, 0, 0})}}, "6"},
        {names::JointPtpMove, {{"TargetJointPosition", joints(outside)}}, "limit"},
        {names::JointPtpMove, {{"TargetJointPosition", joints(withNan)}}, ""},
        {names::JointPtpMove,
         {{"TargetJointPosition", joints(home)}, {"MaxVelocity", joints({-1.0})}},
         ""},
        {names::JointLinearMove, {{"TargetJointPosition", joints(outside)}}, "limit"},
        {names::JointLinearMove, {{"TargetJointPosition", joints({1, 2, 3, 4, 5, 6, 7})}}, "6"},
        {names::PositionStream, {{"TargetJointPosition", joints(outside)}}, "limit"},
        {names::PositionStream, {{"TargetJointPosition", joints({0.1})}}, "6"},
    };
    rig.arm.mark();
    for (const auto& c : cases) {
        SCOPED_TRACE(std::string(c.skill) + " " + c.parameters.front().first);
        SkillClient s(rig.ua, rig.skill(c.skill), 5s);
        auto r = s.run(c.parameters, 20s);
        EXPECT_EQ(r.result, SkillResult::Failed) << r.message;
        EXPECT_FALSE(r.message.empty());
        EXPECT_NE(r.message.find(c.says), std::string::npos) << r.message;
        EXPECT_EQ(s.state(5s), ProgramState::Halted);
        s.reset(5s);
    }
    EXPECT_EQ(rig.arm.maxDistanceFromMark(), 0.0) << "a refused request moved the arm";
}

// ---- Halt, Suspend, Resume -----------------------------------------------------------------

TEST(RobotDevice, HaltMidMotionBrakesAndAborts) {
    Rig rig;
    SkillClient s(rig.ua, rig.skill(names::JointPtpMove), 5s);
    robot::Joints goal = kHome;
    goal[0] += 2.0;
    rig.arm.mark();
    startSkill(
        s, {{"TargetJointPosition", ua::Variant(std::vector<double>(goal.begin(), goal.end()))}});
    ASSERT_TRUE(waitUntil([&] { return std::abs(rig.arm.qd()[0]) > 1.0; }, 5000ms));
    s.halt(5s);
    EXPECT_EQ(s.state(5s), ProgramState::Halted);
    EXPECT_EQ(s.finalResult(5s).result, SkillResult::Aborted);
    ASSERT_TRUE(waitUntil([&] { return rig.arm.atRest(); }, 3000ms));
    EXPECT_GT(distance(rig.arm.q(), goal), 0.1) << "the arm went on to the goal";
    // Braked along the path within the limits: no jump.
    EXPECT_LE(rig.arm.maxSpeedRatio(), 1.001);
    EXPECT_LE(rig.arm.maxAccelerationRatio(), 1.05);
    robot::Joints q = rig.arm.q();
    for (std::size_t i = 1; i < q.size(); ++i) EXPECT_EQ(q[i], kHome[i]) << "axis " << i + 1;
    // Reset waits for the run to end; the skill is usable again.
    s.reset(5s);
    EXPECT_EQ(s.state(5s), ProgramState::Ready);
}

TEST(RobotDevice, SuspendStopsOnThePathAndResumeReachesTheGoal) {
    Rig rig;
    SkillClient s(rig.ua, rig.skill(names::JointPtpMove), 5s);
    robot::Joints goal = kHome;
    goal[0] += 1.5;
    goal[1] -= 0.75;
    rig.arm.mark();
    startSkill(
        s, {{"TargetJointPosition", ua::Variant(std::vector<double>(goal.begin(), goal.end()))}});
    ASSERT_TRUE(waitUntil([&] { return std::abs(rig.arm.qd()[0]) > 0.5; }, 5000ms));
    s.suspend(5s);
    EXPECT_EQ(s.state(5s), ProgramState::Suspended);
    ASSERT_TRUE(waitUntil([&] { return rig.arm.atRest(); }, 3000ms));
    const robot::Joints held = rig.arm.q();
    std::this_thread::sleep_for(200ms);
    EXPECT_EQ(distance(rig.arm.q(), held), 0.0) << "the arm moved while suspended";
    // On the PTP path: both moving axes at the same fraction of their way.
    const double f0 = (held[0] - kHome[0]) / (goal[0] - kHome[0]);
    const double f1 = (held[1] - kHome[1]) / (goal[1] - kHome[1]);
    EXPECT_GT(f0, 0.0);
    EXPECT_LT(f0, 1.0);
    EXPECT_NEAR(f0, f1, 1e-6);
    s.resume(5s);
    EXPECT_EQ(waitForEnd(s), ProgramState::Ready);
    EXPECT_EQ(s.finalResult(5s).result, SkillResult::Completed);
    settle(rig);
    EXPECT_LT(distance(rig.arm.q(), goal), 1e-6);
    EXPECT_LE(rig.arm.maxSpeedRatio(), 1.001);
    EXPECT_LE(rig.arm.maxAccelerationRatio(), 1.05);
}

// ---- the Robotics information model ------------------------------------------------------

TEST(RobotDevice, AxesActualPositionFollowTheArm) {
    Rig rig;
    auto readAxes = [&] {
        std::vector<ua::ReadValueId> ids;
        for (int i = 0; i < 6; ++i) {
            ua::ReadValueId id;
            id.nodeId = rig.device->actualPositionNode(i);
            id.attributeId = static_cast<ua::UInt32>(ua::AttributeId::Value);
            ids.push_back(id);
        }
        robot::Joints q{};
        auto values = rig.ua->read(ids, 5s);
        for (std::size_t i = 0; i < 6; ++i) {
            const double* v = values[i].value ? values[i].value->scalar<double>() : nullptr;
            q[i] = v ? *v : std::numeric_limits<double>::quiet_NaN();
        }
        return q;
    };
    EXPECT_TRUE(waitUntil([&] { return distance(readAxes(), kHome) < 1e-12; }, 2000ms));
    skill::client::JointPtpMoveSkillClient s(rig.ua, rig.skill(names::JointPtpMove), 5s);
    robot::Joints goal = kHome;
    goal[3] += 0.4;
    goal[4] -= 0.3;
    // While moving, the values change (bounded rate, but more than once).
    int changes = 0;
    std::jthread watcher([&](std::stop_token stop) {
        robot::Joints last = readAxes();
        for (int i = 0; i < 500 && !stop.stop_requested(); ++i) {
            robot::Joints now = readAxes();
            if (distance(now, last) > 0) ++changes;
            last = now;
            std::this_thread::sleep_for(10ms);
        }
    });
    auto r = s.run(JointMove{{goal.begin(), goal.end()}, {}, {}, ""}, 20s);
    watcher.request_stop();
    watcher.join();
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    settle(rig);
    EXPECT_GE(changes, 5);
    EXPECT_TRUE(waitUntil([&] { return distance(readAxes(), rig.arm.q()) < 1e-12; }, 2000ms));
    // Identity from the hardware, units as the spec asks.
    const ua::NodeId dev = rig.device->motionDeviceNode();
    EXPECT_EQ(rig.ua->readValue(rig.at(dev, {{rig.di(), "Model"}}), 5s),
              ua::Variant(ua::LocalizedText("", "FakeArm")));
    EXPECT_EQ(rig.ua->readValue(rig.at(dev, {{rig.di(), "SerialNumber"}}), 5s),
              ua::Variant(ua::String("FA-0001")));
    const auto eu =
        rig.ua->readValue(rig.at(rig.device->actualPositionNode(0), {{0, "EngineeringUnits"}}), 5s);
    const auto* x = eu.scalar<ua::ExtensionObject>();
    ASSERT_NE(x, nullptr);
    auto info = ua::fromExtensionObject<ua::EUInformation>(*x);
    ASSERT_TRUE(info.has_value());
    EXPECT_EQ(info->displayName.text, "rad");
    EXPECT_EQ(info->unitId, 4405297);  // UNECE C81
}

TEST(RobotDevice, WorldToRobotBaseAndToolsAreCheckedAndUsed) {
    Rig rig;
    const ua::NodeId dev = rig.device->motionDeviceNode();
    const ua::NodeId wtb = rig.at(dev, {{rig.skr(), "WorldToRobotBase"}});
    const ua::NodeId setTool = rig.at(dev, {{rig.skr(), "SetTool"}});
    const ua::NodeId clearTool = rig.at(dev, {{rig.skr(), "ClearTool"}});
    auto frame = [](const Eigen::Isometry3d& t) {
        return ua::Variant(ua::toExtensionObject(ua::spatial::toFrame(t)));
    };

    // A base 1 m along x and turned 90° about z in the world.
    Eigen::Isometry3d base = Eigen::Isometry3d::Identity();
    base.translation() = Eigen::Vector3d(1.0, 0.0, 0.2);
    base.linear() = Eigen::AngleAxisd(kPi / 2, Eigen::Vector3d::UnitZ()).matrix();
    ua::ThreeDFrame bad = ua::spatial::toFrame(base);
    bad.orientation.c = std::numeric_limits<double>::infinity();
    EXPECT_TRUE(rig.ua->writeValue(wtb, ua::Variant(ua::toExtensionObject(bad)), 5s).isBad());
    EXPECT_TRUE(rig.device->worldToBase().isApprox(Eigen::Isometry3d::Identity()));
    ASSERT_EQ(rig.ua->writeValue(wtb, frame(base), 5s), ua::StatusCode{});
    EXPECT_TRUE(rig.device->worldToBase().isApprox(base, 1e-12));

    // Tools: bad arguments change nothing.
    Eigen::Isometry3d tcp = Eigen::Isometry3d::Identity();
    tcp.translation() = Eigen::Vector3d(0.0, 0.0, 0.15);
    ua::ThreeDFrame nanTool = ua::spatial::toFrame(tcp);
    nanTool.cartesianCoordinates.z = std::numeric_limits<double>::quiet_NaN();
    EXPECT_EQ(rig.ua->call(dev, setTool, {ua::Variant(ua::String("")), frame(tcp)}, 5s).status,
              status::BadInvalidArgument);
    EXPECT_EQ(rig.ua
                  ->call(dev, setTool,
                         {ua::Variant(ua::String("gripper")),
                          ua::Variant(ua::toExtensionObject(nanTool))},
                         5s)
                  .status,
              status::BadInvalidArgument);
    EXPECT_EQ(rig.ua->call(dev, clearTool, {ua::Variant(ua::String("gripper"))}, 5s).status,
              status::BadInvalidArgument);
    EXPECT_EQ(rig.device->activeTool(), "");
    ASSERT_EQ(
        rig.ua->call(dev, setTool, {ua::Variant(ua::String("gripper")), frame(tcp)}, 5s).status,
        ua::StatusCode{});
    EXPECT_EQ(rig.device->activeTool(), "gripper");

    // A linear move of the active tool to a world pose.
    const Eigen::Isometry3d toolNow =
        base * kinematics::forward(rig.arm.model(), rig.arm.q()) * tcp;
    Eigen::Isometry3d target = toolNow;
    target.translation() += Eigen::Vector3d(0.05, 0.05, 0.0);
    skill::client::CartesianLinearMoveSkillClient s(rig.ua, rig.skill(names::CartesianLinearMove),
                                                    5s);
    auto r = s.run(CartesianMove{ua::spatial::toFrame(target), {}, {0.2}, {}, ""}, 20s);
    ASSERT_EQ(r.run.result, SkillResult::Completed) << r.run.message;
    settle(rig);
    auto [p, a] = poseError(base * kinematics::forward(rig.arm.model(), rig.arm.q()) * tcp, target);
    EXPECT_LE(p, 1e-5);
    EXPECT_LE(a, 1e-5);

    // ClearTool: the flange again; a named, removed tool is unknown to a move.
    ASSERT_EQ(rig.ua->call(dev, clearTool, {ua::Variant(ua::String("gripper"))}, 5s).status,
              ua::StatusCode{});
    EXPECT_EQ(rig.device->activeTool(), "");
    rig.arm.mark();
    auto refused = s.run(CartesianMove{ua::spatial::toFrame(target), {}, {}, {}, "gripper"}, 20s);
    EXPECT_EQ(refused.run.result, SkillResult::Failed);
    EXPECT_NE(refused.run.message.find("gripper"), std::string::npos) << refused.run.message;
    EXPECT_EQ(rig.arm.maxDistanceFromMark(), 0.0);
}

TEST(RobotDevice, MotionDeviceSystemStructure) {
    Rig rig;
    const ua::UInt16 rob = rig.rob(), di = rig.di();
    // Browse paths as OPC 40010-1 lays them out.
    const ua::NodeId system = rig.at(ua::NodeId(0, 85), {{di, "DeviceSet"}, {1, "ArmSystem"}});
    EXPECT_EQ(system, rig.device->systemNode());
    EXPECT_EQ(rig.at(system, {{rob, "MotionDevices"}, {1, "Arm"}}), rig.device->motionDeviceNode());
    EXPECT_EQ(rig.at(system, {{rob, "MotionDevices"},
                              {1, "Arm"},
                              {rob, "Axes"},
                              {1, "Axis3"},
                              {di, "ParameterSet"},
                              {rob, "ActualPosition"}}),
              rig.device->actualPositionNode(2));
    EXPECT_EQ(rig.at(system, {{rob, "Controllers"}, {1, "ArmController"}}),
              rig.device->controllerNode());
    const ua::NodeId estop = rig.at(system, {{rob, "SafetyStates"},
                                             {1, "ArmSafetyState"},
                                             {di, "ParameterSet"},
                                             {rob, "EmergencyStop"}});
    EXPECT_EQ(rig.ua->readValue(estop, 5s), ua::Variant(false));
    EXPECT_EQ(rig.ua->readValue(rig.at(rig.device->controllerNode(), {{di, "Manufacturer"}}), 5s),
              ua::Variant(ua::LocalizedText("", "pnp tests")));
    // The six skills.
    for (const char* n :
         {names::CartesianPtpMove, names::CartesianLinearMove, names::JointPtpMove,
          names::JointLinearMove, names::CartesianLinearForceMove, names::PositionStream})
        EXPECT_FALSE(rig.skill(n).isNull()) << n;
}

}  // namespace
