// WsgHardware (the adapter) against the simulated WSG 50 over TCP on loopback: identification,
// homing, moves, a grasp on nothing failing with its reason, a real grasp, release, Halt
// mid-motion, an unpowered gripper.
#include <gtest/gtest.h>

#include "device/wsg/wsg_hardware.hpp"
#include "wsg_helpers.hpp"

namespace pnp::wsg::test {
namespace {

namespace gripper = pnp::device::gripper;
using device::wsg::WsgHardware;
using device::wsg::WsgHardwareConfig;

gripper::Deadline in(std::chrono::milliseconds ms) { return gripper::Clock::now() + ms; }

struct HardwareRig {
    explicit HardwareRig(bool onFlange = true, bool part = false)
        : world(cellWithWsg(onFlange, part)),
          tool(toolIndex(world.description())),
          wsg(world, tool, anyPort()),
          stepper(world, wsg),
          hardware(config()) {}
    WsgHardwareConfig config() {
        WsgHardwareConfig c;
        c.port = wsg.port();
        return c;
    }
    bool powered() {
        return waitFor([&] { return wsg.state().listening; }, 2000ms);
    }
    world::World world;
    std::size_t tool;
    sim::wsg::Wsg50 wsg;
    Stepper stepper;
    WsgHardware hardware;
    std::atomic<bool> cancel{false};
};

TEST(WsgHardware, ParsesAddresses) {
    auto a = device::wsg::parseAddress("192.168.1.20");
    ASSERT_TRUE(a);
    EXPECT_EQ(a->first, "192.168.1.20");
    EXPECT_EQ(a->second, 1000);
    a = device::wsg::parseAddress("wsg.local:1002");
    ASSERT_TRUE(a);
    EXPECT_EQ(a->first, "wsg.local");
    EXPECT_EQ(a->second, 1002);
    EXPECT_FALSE(device::wsg::parseAddress(""));
    EXPECT_FALSE(device::wsg::parseAddress(":1000"));
    EXPECT_FALSE(device::wsg::parseAddress("host:"));
    EXPECT_FALSE(device::wsg::parseAddress("host:70000"));
    EXPECT_FALSE(device::wsg::parseAddress("host:12ab"));
}

TEST(WsgHardware, GripPointAndIdentification) {
    HardwareRig rig;
    const gripper::GripPoint p = rig.hardware.gripPoint();
    EXPECT_EQ(p.kind, gripper::GripKind::kParallel);
    EXPECT_DOUBLE_EQ(p.spanMin, 0.0);
    EXPECT_DOUBLE_EQ(p.spanMax, 0.110);
    EXPECT_NEAR(p.offset.translation().z(), 0.19, 1e-12);
    EXPECT_EQ(rig.hardware.endpoint(), "tcp://127.0.0.1:" + std::to_string(rig.wsg.port()));
    EXPECT_EQ(rig.hardware.serialNumber(), "");
    ASSERT_TRUE(rig.powered());
    auto c = rig.hardware.connect(in(2000ms));
    ASSERT_TRUE(c.ok()) << c.error().message;
    EXPECT_EQ(rig.hardware.manufacturer(), "SCHUNK");
    EXPECT_EQ(rig.hardware.modelName(), "WSG 50");
    EXPECT_EQ(rig.hardware.serialNumber(), "50001");
    EXPECT_EQ(rig.hardware.firmwareVersion(), "4.2.0.0");
}

TEST(WsgHardware, HomesMovesAndReleases) {
    HardwareRig rig;
    ASSERT_TRUE(rig.powered());
    auto s = rig.hardware.status(in(2000ms));
    ASSERT_TRUE(s.ok()) << s.error().message;
    EXPECT_FALSE(s->ready) << "not homed at power-on";
    // A move before homing is refused by the gripper, with its reason.
    auto m = rig.hardware.move({0.05, 0.1, 20.0}, in(2000ms), rig.cancel);
    ASSERT_FALSE(m.ok());
    EXPECT_EQ(m.error().kind, gripper::ErrorKind::kRefused);
    EXPECT_NE(m.error().message.find("E_NOT_INITIALIZED"), std::string::npos);

    auto a = rig.hardware.activate(in(5000ms), rig.cancel);
    ASSERT_TRUE(a.ok()) << a.error().message;
    EXPECT_TRUE(rig.wsg.state().referenced);
    // Idempotent: homed already, nothing moves.
    a = rig.hardware.activate(in(2000ms), rig.cancel);
    ASSERT_TRUE(a.ok()) << a.error().message;

    m = rig.hardware.move({0.05, 0.2, 20.0}, in(3000ms), rig.cancel);
    ASSERT_TRUE(m.ok()) << m.error().message;
    EXPECT_NEAR(m->width, 0.05, 1e-6);
    EXPECT_TRUE(m->ready);
    EXPECT_FALSE(m->moving);
    EXPECT_NEAR(rig.wsg.state().width, 50.0, 1e-6);

    // Outside the span: refused before anything is sent.
    m = rig.hardware.move({0.2, 0.1, 20.0}, in(1000ms), rig.cancel);
    ASSERT_FALSE(m.ok());
    EXPECT_EQ(m.error().kind, gripper::ErrorKind::kRefused);

    auto r = rig.hardware.release(in(3000ms), rig.cancel);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_NEAR(r->width, 0.110, 1e-6);
    EXPECT_FALSE(r->holding);
}

TEST(WsgHardware, GraspOnNothingFailsWithTheReason) {
    HardwareRig rig;
    ASSERT_TRUE(rig.powered());
    ASSERT_TRUE(rig.hardware.activate(in(5000ms), rig.cancel).ok());
    auto g = rig.hardware.grasp({0.03, 0.2, 20.0}, in(3000ms), rig.cancel);
    ASSERT_FALSE(g.ok());
    EXPECT_EQ(g.error().kind, gripper::ErrorKind::kRefused);
    EXPECT_EQ(g.error().message, "no object between the fingers");
    EXPECT_EQ(rig.wsg.state().grasping, GraspingState::kNoPartFound);
}

TEST(WsgHardware, GraspsAPartAndReleasesIt) {
    HardwareRig rig(true, true);
    ASSERT_TRUE(rig.powered());
    ASSERT_TRUE(rig.hardware.activate(in(5000ms), rig.cancel).ok());
    auto g = rig.hardware.grasp({0.0, 0.1, 30.0}, in(3000ms), rig.cancel);
    ASSERT_TRUE(g.ok()) << g.error().message;
    EXPECT_TRUE(g->holding);
    EXPECT_NEAR(g->width, 0.04, 1e-6);
    EXPECT_TRUE(rig.stepper.read([&](const world::World& w) { return w.held(rig.tool); }));
    auto r = rig.hardware.release(in(3000ms), rig.cancel);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_FALSE(r->holding);
    EXPECT_FALSE(rig.stepper.read([&](const world::World& w) { return w.held(rig.tool); }));
}

TEST(WsgHardware, CancelStopsTheGripperMidMotion) {
    HardwareRig rig;
    ASSERT_TRUE(rig.powered());
    ASSERT_TRUE(rig.hardware.activate(in(5000ms), rig.cancel).ok());
    // 100 mm at 10 mm/s would take 10 s; Halt after 200 ms.
    std::thread halt([&] {
        std::this_thread::sleep_for(200ms);
        rig.cancel = true;
    });
    const auto start = gripper::Clock::now();
    auto m = rig.hardware.move({0.01, 0.01, 20.0}, in(15000ms), rig.cancel);
    halt.join();
    ASSERT_FALSE(m.ok());
    EXPECT_EQ(m.error().kind, gripper::ErrorKind::kCancelled);
    EXPECT_LT(gripper::Clock::now() - start, 1500ms) << "cancel must be prompt";
    const auto state = rig.wsg.state();
    EXPECT_FALSE(state.moving);
    EXPECT_GT(state.width, 90.0);
    EXPECT_LT(state.width, 110.0);
    // The next call is not confused by the stopped motion's late answer.
    rig.cancel = false;
    auto again = rig.hardware.move({0.08, 0.2, 20.0}, in(3000ms), rig.cancel);
    ASSERT_TRUE(again.ok()) << again.error().message;
    EXPECT_NEAR(again->width, 0.08, 1e-6);
}

TEST(WsgHardware, TimeoutStopsTheGripper) {
    HardwareRig rig;
    ASSERT_TRUE(rig.powered());
    ASSERT_TRUE(rig.hardware.activate(in(5000ms), rig.cancel).ok());
    auto m = rig.hardware.move({0.01, 0.01, 20.0}, in(300ms), rig.cancel);
    ASSERT_FALSE(m.ok());
    EXPECT_EQ(m.error().kind, gripper::ErrorKind::kTimeout);
    EXPECT_TRUE(waitFor([&] { return !rig.wsg.state().moving; }, 1000ms));
}

TEST(WsgHardware, UnpoweredGripperIsNoDeviceWithinTheDeadline) {
    HardwareRig rig(false);  // in its dock: no power, nothing listens
    const auto start = gripper::Clock::now();
    auto c = rig.hardware.connect(in(500ms));
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.error().kind, gripper::ErrorKind::kNoDevice);
    EXPECT_LT(gripper::Clock::now() - start, 700ms);
    auto s = rig.hardware.status(in(500ms));
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.error().kind, gripper::ErrorKind::kNoDevice);
    // A peer that accepts the connection but never answers (a wrong device on the port):
    // kNoDevice at the deadline.
    const int silent = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ASSERT_EQ(::bind(silent, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    ASSERT_EQ(::listen(silent, 4), 0);
    socklen_t len = sizeof a;
    ::getsockname(silent, reinterpret_cast<sockaddr*>(&a), &len);
    WsgHardwareConfig config;
    config.port = ntohs(a.sin_port);
    WsgHardware mute(config);
    const auto t0 = gripper::Clock::now();
    c = mute.connect(in(300ms));
    ::close(silent);
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.error().kind, gripper::ErrorKind::kNoDevice);
    EXPECT_GE(gripper::Clock::now() - t0, 290ms);
    EXPECT_LT(gripper::Clock::now() - t0, 600ms);
}

}  // namespace
}  // namespace pnp::wsg::test
