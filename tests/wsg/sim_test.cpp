// The simulated WSG 50 over real TCP (loopback), driven with raw frames: two-phase answers of
// motions, errors as the device reports them, fast stop + acknowledge, grasping against the
// world, power.
#include <gtest/gtest.h>

#include <cmath>

#include "kinematics/kinematics.hpp"
#include "wsg_helpers.hpp"

namespace pnp::wsg::test {
namespace {

struct Rig {
    explicit Rig(bool onFlange = true, bool part = false, sim::wsg::Wsg50Config config = anyPort())
        : world(cellWithWsg(onFlange, part)),
          tool(toolIndex(world.description())),
          wsg(world, tool, config),
          stepper(world, wsg) {}
    world::World world;
    std::size_t tool;
    sim::wsg::Wsg50 wsg;
    Stepper stepper;

    bool connect(RawClient& c) {
        if (!waitFor([&] { return wsg.state().listening; }, 2000ms)) return false;
        return c.connect(wsg.port());
    }
    // Homing: E_CMD_PENDING, then E_SUCCESS.
    void home(RawClient& c) {
        auto r = c.call(Command::kHoming, homingPayload());
        ASSERT_TRUE(r);
        ASSERT_EQ(r->status, st(Status::kCmdPending));
        r = c.response(3000ms);
        ASSERT_TRUE(r);
        ASSERT_EQ(r->id, 0x20);
        ASSERT_EQ(r->status, st(Status::kSuccess));
    }
};

TEST(WsgSim, ListensOnlyWhilePowered) {
    Rig docked(false);  // in its dock: no power
    for (int i = 0; i < 20; ++i) std::this_thread::sleep_for(5ms);
    EXPECT_FALSE(docked.wsg.state().powered);
    EXPECT_FALSE(docked.wsg.state().listening);
    RawClient c;
    EXPECT_FALSE(c.connect(docked.wsg.port())) << "an unpowered gripper accepts nothing";
    EXPECT_NE(docked.wsg.port(), 0);
}

TEST(WsgSim, AnswersSystemInformationAndState) {
    Rig rig;
    RawClient c;
    ASSERT_TRUE(rig.connect(c));
    auto r = c.call(Command::kGetSystemInformation);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->id, 0x50);
    ASSERT_TRUE(r->ok());
    const auto info = parseSystemInformation(r->values);
    ASSERT_TRUE(info);
    EXPECT_EQ(info->type, 1);
    EXPECT_EQ(info->serialNumber, 50001u);

    r = c.call(Command::kGetSystemState, queryPayload());
    ASSERT_TRUE(r && r->ok());
    EXPECT_EQ(*getU32(r->values, 0) & system_flag::kReferenced, 0u) << "not homed at power-on";
    r = c.call(Command::kGetOpeningWidth, queryPayload());
    ASSERT_TRUE(r && r->ok());
    EXPECT_FLOAT_EQ(*getFloat(r->values, 0), 110.0f);
    r = c.call(Command::kGetGraspingState, queryPayload());
    ASSERT_TRUE(r && r->ok());
    EXPECT_EQ(r->values, (std::vector<std::uint8_t>{0}));
    r = c.call(Command::kLoop, {1, 2, 3});
    ASSERT_TRUE(r && r->ok());
    EXPECT_EQ(r->values, (std::vector<std::uint8_t>{1, 2, 3}));
}

TEST(WsgSim, MotionIsAnsweredPendingThenWithItsResult) {
    Rig rig;
    RawClient c;
    ASSERT_TRUE(rig.connect(c));
    // Not homed: refused.
    auto r = c.call(Command::kPrePosition, prePositionPayload(0, 50.0f, 100.0f));
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kNotInitialized));
    rig.home(c);
    EXPECT_TRUE(rig.wsg.state().referenced);

    const auto start = std::chrono::steady_clock::now();
    r = c.call(Command::kPrePosition, prePositionPayload(0, 50.0f, 200.0f));
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kCmdPending));
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kPositioning);
    r = c.response(3000ms);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->id, 0x21);
    EXPECT_EQ(r->status, st(Status::kSuccess));
    // 60 mm at 200 mm/s with 1000 mm/s² ramps: about 0.5 s.
    EXPECT_GT(std::chrono::steady_clock::now() - start, 250ms);
    r = c.call(Command::kGetOpeningWidth, queryPayload());
    ASSERT_TRUE(r && r->ok());
    EXPECT_NEAR(*getFloat(r->values, 0), 50.0f, 1e-3);
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kIdle);
}

TEST(WsgSim, ReportsErrorsAsTheDeviceDoes) {
    Rig rig;
    RawClient c;
    ASSERT_TRUE(rig.connect(c));
    // A bad checksum: E_CHECKSUM_ERROR with the frame's id.
    auto bad = encodeCommand(Command::kGetOpeningWidth, queryPayload());
    bad.back() ^= 0xFF;
    ASSERT_TRUE(c.sendBytes(bad));
    auto r = c.response();
    ASSERT_TRUE(r);
    EXPECT_EQ(r->id, 0x43);
    EXPECT_EQ(r->status, st(Status::kChecksumError));
    EXPECT_EQ(rig.wsg.state().checksumErrors, 1u);
    // Unknown command: E_CMD_UNKNOWN, as in the manual's example (id 0x90).
    ASSERT_TRUE(c.sendBytes(encodeFrame(0x90, {})));
    r = c.response();
    ASSERT_TRUE(r);
    EXPECT_EQ(r->id, 0x90);
    EXPECT_EQ(r->status, st(Status::kCmdUnknown));
    // The manual's frame for that answer, byte for byte.
    ASSERT_TRUE(c.sendBytes(encodeFrame(0x90, {})));
    auto f = c.next();
    ASSERT_TRUE(f);
    EXPECT_EQ(
        encodeFrame(f->id, f->payload),
        (std::vector<std::uint8_t>{0xAA, 0xAA, 0xAA, 0x90, 0x02, 0x00, 0x0E, 0x00, 0xFD, 0x02}));
    // Wrong payload length: E_CMD_FORMAT_ERROR.
    r = c.call(Command::kGrasp, {1, 2, 3});
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kCmdFormatError));
    // Out of range: E_RANGE_ERROR (force 100 N, speed 1000 mm/s, width 200 mm).
    r = c.call(Command::kSetForceLimit, floatPayload(100.0f));
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kRangeError));
    rig.home(c);
    r = c.call(Command::kPrePosition, prePositionPayload(0, 50.0f, 1000.0f));
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kRangeError));
    r = c.call(Command::kPrePosition, prePositionPayload(0, 200.0f, 100.0f));
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kRangeError));
    // A valid setting is kept.
    r = c.call(Command::kSetForceLimit, floatPayload(20.0f));
    ASSERT_TRUE(r && r->ok());
    r = c.call(Command::kGetForceLimit);
    ASSERT_TRUE(r && r->ok());
    EXPECT_FLOAT_EQ(*getFloat(r->values, 0), 20.0f);
    // An oversized frame: E_INSUFFICIENT_RESOURCES, and the connection still serves.
    ASSERT_TRUE(c.sendBytes({0xAA, 0xAA, 0xAA, 0x43, 0xFF, 0xFF}));
    r = c.response();
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kInsufficientResources));
    r = c.call(Command::kGetOpeningWidth, queryPayload());
    ASSERT_TRUE(r && r->ok());
}

TEST(WsgSim, FastStopNeedsAcknowledge) {
    Rig rig;
    RawClient c;
    ASSERT_TRUE(rig.connect(c));
    rig.home(c);
    auto r = c.call(Command::kPrePosition, prePositionPayload(0, 10.0f, 20.0f));
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, st(Status::kCmdPending));
    std::this_thread::sleep_for(100ms);
    ASSERT_TRUE(c.send(Command::kFastStop));
    // Both answers: the fast stop's, and the aborted motion's result (in either order).
    bool aborted = false, stopped = false;
    for (int i = 0; i < 2; ++i) {
        r = c.response();
        ASSERT_TRUE(r);
        if (r->id == 0x21) aborted = r->status == st(Status::kCmdAborted);
        if (r->id == 0x23) stopped = r->ok();
    }
    EXPECT_TRUE(aborted);
    EXPECT_TRUE(stopped);
    const double stoppedAt = rig.wsg.state().width;
    EXPECT_GT(stoppedAt, 10.0);
    EXPECT_LT(stoppedAt, 110.0);
    EXPECT_TRUE(rig.wsg.state().fastStop);
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kError);
    r = c.call(Command::kGetSystemState, queryPayload());
    ASSERT_TRUE(r && r->ok());
    EXPECT_NE(*getU32(r->values, 0) & system_flag::kFastStop, 0u);
    // Motions are refused until acknowledged.
    r = c.call(Command::kPrePosition, prePositionPayload(0, 50.0f, 100.0f));
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kAccessDenied));
    r = c.call(Command::kAcknowledgeFastStop, {'n', 'o', 'k'});
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kInvalidParameter));
    r = c.call(Command::kAcknowledgeFastStop, acknowledgeFastStopPayload());
    ASSERT_TRUE(r && r->ok());
    EXPECT_FALSE(rig.wsg.state().fastStop);
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kIdle);
    EXPECT_NEAR(rig.wsg.state().width, stoppedAt, 1e-9) << "the jaws stayed where they stopped";
    r = c.call(Command::kPrePosition, prePositionPayload(0, 50.0f, 100.0f));
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kCmdPending));
    r = c.response(3000ms);
    ASSERT_TRUE(r && r->ok());
}

TEST(WsgSim, StopAbortsTheMotion) {
    Rig rig;
    RawClient c;
    ASSERT_TRUE(rig.connect(c));
    rig.home(c);
    auto r = c.call(Command::kPrePosition, prePositionPayload(0, 10.0f, 20.0f));
    ASSERT_TRUE(r && r->pending());
    r = c.call(Command::kGrasp, graspPayload(10.0f, 20.0f));
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kAlreadyRunning));
    ASSERT_TRUE(c.send(Command::kStop));
    bool aborted = false, stopped = false;
    for (int i = 0; i < 2; ++i) {
        r = c.response();
        ASSERT_TRUE(r);
        if (r->id == 0x21) aborted = r->status == st(Status::kCmdAborted);
        if (r->id == 0x22) stopped = r->ok();
    }
    EXPECT_TRUE(aborted && stopped);
    EXPECT_FALSE(rig.wsg.state().moving);
    EXPECT_FALSE(rig.wsg.state().fastStop);
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kIdle);
}

TEST(WsgSim, GraspOnNothingFindsNoPart) {
    Rig rig;
    RawClient c;
    ASSERT_TRUE(rig.connect(c));
    rig.home(c);
    auto r = c.call(Command::kGrasp, graspPayload(30.0f, 200.0f));
    ASSERT_TRUE(r && r->pending());
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kGrasping);
    r = c.response(3000ms);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->id, 0x25);
    EXPECT_EQ(r->status, st(Status::kCmdFailed));
    r = c.call(Command::kGetGraspingState, queryPayload());
    ASSERT_TRUE(r && r->ok());
    EXPECT_EQ(r->values.at(0), static_cast<std::uint8_t>(GraspingState::kNoPartFound));
    // Closed to the nominal width less the clamping travel (5 mm).
    EXPECT_NEAR(rig.wsg.state().width, 25.0, 1e-6);
    r = c.call(Command::kGetGraspingStatistics, {0});
    ASSERT_TRUE(r && r->ok());
    const auto stats = parseGraspingStatistics(r->values);
    ASSERT_TRUE(stats);
    EXPECT_EQ(stats->total, 1u);
    EXPECT_EQ(stats->noPart, 1);
}

TEST(WsgSim, GraspsThePartBetweenItsFingersAndReleasesIt) {
    Rig rig(true, true);
    const std::size_t part = rig.world.description().objects.size() - 1;
    RawClient c;
    ASSERT_TRUE(rig.connect(c));
    rig.home(c);
    auto r = c.call(Command::kGrasp, graspPayload(38.0f, 100.0f));
    ASSERT_TRUE(r && r->pending());
    r = c.response(3000ms);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kSuccess));
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kHolding);
    EXPECT_NEAR(rig.wsg.state().width, 40.0, 1e-6) << "the jaws stop on the 40 mm part";
    EXPECT_EQ(rig.stepper.read([&](const world::World& w) { return w.held(rig.tool); }), part);
    r = c.call(Command::kGetForce, queryPayload());
    ASSERT_TRUE(r && r->ok());
    EXPECT_GT(*getFloat(r->values, 0), 0.0f);
    // While holding, a pre-position is refused; release opens and lets go.
    r = c.call(Command::kPrePosition, prePositionPayload(0, 80.0f, 100.0f));
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kAccessDenied));
    r = c.call(Command::kRelease, graspPayload(80.0f, 100.0f));
    ASSERT_TRUE(r && r->pending());
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kReleasing);
    r = c.response(3000ms);
    ASSERT_TRUE(r && r->ok());
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kIdle);
    EXPECT_NEAR(rig.wsg.state().width, 80.0, 1e-6);
    EXPECT_FALSE(rig.stepper.read([&](const world::World& w) { return w.held(rig.tool); }));
}

TEST(WsgSim, PrePositionIsBlockedByAPart) {
    Rig rig(true, true);
    RawClient c;
    ASSERT_TRUE(rig.connect(c));
    rig.home(c);
    auto r =
        c.call(Command::kPrePosition, prePositionPayload(move_flag::kStopOnBlock, 20.0f, 100.0f));
    ASSERT_TRUE(r && r->pending());
    r = c.response(3000ms);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, st(Status::kAxisBlocked));
    EXPECT_NEAR(rig.wsg.state().width, 40.0, 1e-6);
    EXPECT_FALSE(rig.stepper.read([&](const world::World& w) { return w.held(rig.tool); }));
}

TEST(WsgSim, BoundsItsConnections) {
    auto config = anyPort();
    config.maxConnections = 2;
    Rig rig(true, false, config);
    RawClient a, b, extra;
    ASSERT_TRUE(rig.connect(a));
    ASSERT_TRUE(rig.connect(b));
    ASSERT_TRUE(waitFor([&] { return rig.wsg.state().connections == 2; }, 1000ms));
    ASSERT_TRUE(rig.connect(extra));  // accepted by the kernel, then closed by the device
    EXPECT_TRUE(extra.waitClosed(2000ms));
    auto r = a.call(Command::kGetOpeningWidth, queryPayload());
    ASSERT_TRUE(r && r->ok());
}

TEST(WsgSim, DisconnectWithoutAnnouncementRaisesFastStopWhenConfigured) {
    auto config = anyPort();
    config.fastStopOnDisconnect = true;
    Rig rig(true, false, config);
    {
        RawClient polite;
        ASSERT_TRUE(rig.connect(polite));
        auto r = polite.call(Command::kDisconnect);
        ASSERT_TRUE(r && r->ok());
    }
    ASSERT_TRUE(waitFor([&] { return rig.wsg.state().connections == 0; }, 2000ms));
    EXPECT_FALSE(rig.wsg.state().fastStop);
    {
        RawClient rude;
        ASSERT_TRUE(rig.connect(rude));
        ASSERT_TRUE(waitFor([&] { return rig.wsg.state().connections == 1; }, 1000ms));
    }
    EXPECT_TRUE(waitFor([&] { return rig.wsg.state().fastStop; }, 2000ms));
}

}  // namespace
}  // namespace pnp::wsg::test

namespace pnp::wsg::test {
namespace {

// The thesis cell with the WSG on the UR5's flange, its grip point (the finger tips) at the
// height of the green cube's centre but `offset` (m) beside it along the fingers' axis, as the
// robot's tracking error or a cube put down off its nominal place leaves it. The cube rests
// on the table, turned as the fingers.
world::CellDescription cubeOffCentreBetweenTheFingers(double offset) {
    world::CellDescription cell = cellWithWsg(true);
    if (cell.objects.empty() || cell.robots.empty()) {
        ADD_FAILURE() << "no cube or robot in the thesis cell";
        return cell;
    }
    world::ObjectDescription& cube = cell.objects[0];
    const world::RobotDescription& r = cell.robots[0];
    const world::ToolDescription* t = cell.findTool(kTool);
    Eigen::Isometry3d flange = r.base * kinematics::forward(r.model, r.home);
    const Eigen::Vector3d across = flange.linear() * t->tcp.linear().col(0);  // horizontal
    const Eigen::Vector3d grip = cube.pose.translation() - offset * across;
    flange.translation() = grip - flange.linear() * t->tcp.translation();
    cube.pose.linear() =
        Eigen::AngleAxisd(std::atan2(across.y(), across.x()), Eigen::Vector3d::UnitZ())
            .toRotationMatrix();
    auto q = kinematics::solveNearest(r.model, r.base.inverse() * flange, r.home);
    if (!q.ok()) {
        ADD_FAILURE() << q.error().message;
        return cell;
    }
    cell.robots[0].home = *q;
    return cell;
}

// The UR's protective stop limit (sim::ur::UrControllerConfig::protectiveStopForce).
constexpr double kProtectiveStopForce = 250.0;  // N

// Steps the world and the gripper by hand (deterministic: the network thread only takes the
// commands, each answered "pending" before the stepping goes on), the world refreshed after the
// gripper's step as the robot controller's next setJoints does; records the largest TCP force.
struct HandStepped {
    explicit HandStepped(double offset)
        : world(cubeOffCentreBetweenTheFingers(offset)),
          tool(toolIndex(world.description())),
          wsg(world, tool, anyPort()) {}
    world::World world;
    std::size_t tool;
    sim::wsg::Wsg50 wsg;
    double maxForce = 0.0;

    void step() {
        world.step(0.002);
        maxForce = std::max(maxForce, world.robot(0).tcpForce.norm());
        wsg.step(0.002);
        world.step(0.0);
        maxForce = std::max(maxForce, world.robot(0).tcpForce.norm());
    }
    // A motion command: pending at once, then stepped (at most `maxSteps`) to its end.
    std::optional<Response> motion(RawClient& c, Command command,
                                   const std::vector<std::uint8_t>& payload, int maxSteps = 2000) {
        auto r = c.call(command, payload);
        if (!r || !r->pending()) return r;
        for (int i = 0; i < maxSteps && wsg.state().moving; ++i) step();
        return c.response(2000ms);
    }
};

TEST(WsgSim, FingersClosingOnAnOffCentreCubeCentreItWithoutATcpForce) {
    for (const double offset : {0.0, 0.0005, -0.0005, 0.001, -0.001}) {
        SCOPED_TRACE("cube centre " + std::to_string(offset * 1000.0) + " mm off the grip point");
        HandStepped rig(offset);
        const std::size_t cube = 0;
        ASSERT_FALSE(rig.world.held(rig.tool));
        ASSERT_TRUE(waitFor(
            [&] {
                rig.step();
                return rig.wsg.state().listening;
            },
            2000ms));
        RawClient c;
        ASSERT_TRUE(c.connect(rig.wsg.port()));
        auto r = rig.motion(c, Command::kHoming, homingPayload());
        ASSERT_TRUE(r && r->ok());
        EXPECT_EQ(rig.maxForce, 0.0) << "the open fingers are clear of the cube";
        // Closing: the first finger to touch pushes the cube along the table to the centre.
        r = rig.motion(c, Command::kGrasp, graspPayload(40.0f, 100.0f));
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, st(Status::kSuccess));
        EXPECT_EQ(rig.world.held(rig.tool), cube);
        EXPECT_NEAR(rig.wsg.state().width, 40.0, 1e-6);
        const auto grip = rig.world.gripPoint(rig.tool);
        ASSERT_TRUE(grip);
        const Eigen::Vector3d inGrip =
            grip->inverse() * rig.world.objects()[cube].pose.translation();
        EXPECT_NEAR(inGrip.x(), 0.0, 1e-9) << "held centred between the jaws";
        EXPECT_NEAR(inGrip.y(), 0.0, 1e-9);
        EXPECT_LT(rig.maxForce, 1.0) << "closing: side contact is no push into a top face";
        rig.maxForce = 0.0;
        // Letting go: it rests on the table where it is, centred; the fingers leave its sides.
        r = rig.motion(c, Command::kRelease, graspPayload(60.0f, 100.0f));
        ASSERT_TRUE(r && r->ok());
        EXPECT_FALSE(rig.world.held(rig.tool));
        EXPECT_EQ(rig.world.objects()[cube].holder, "table");
        EXPECT_NEAR(rig.world.objects()[cube].pose.translation().z(), 0.02, 1e-9);
        EXPECT_LT(rig.maxForce, 1.0)
            << "releasing: side contact (the UR stops at " << kProtectiveStopForce << " N)";
    }
}

}  // namespace
}  // namespace pnp::wsg::test
