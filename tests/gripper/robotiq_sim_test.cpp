// RobotiqHardware (libmodbus RTU) against the simulated 2F-85 (pnp_sim_robotiq behind
// modbus::RtuSlave on a pseudo-terminal) in the thesis cell's world, stepped at 500 Hz in
// real time: activation, a grasp on empty air refused, a grasp on an object held by the world,
// Halt (cancel) stopping the fingers mid-stroke, a dead line as kNoDevice; and the whole
// stack — ToolAdapter + GripperDevice over the simulator — running Grasp from an OPC UA client.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <thread>

#include "device/gripper/tool_adapter.hpp"
#include "device/robotiq/robotiq_hardware.hpp"
#include "kinematics/kinematics.hpp"
#include "modbus/modbus.hpp"
#include "sim/robotiq/robotiq_2f85.hpp"
#include "skill/client/typed_clients.hpp"
#include "support/loopback_server.hpp"
#include "support/wait.hpp"
#include "ua/client/client.hpp"
#include "world/cell_file.hpp"
#include "world/world.hpp"

using namespace pnp;
using namespace std::chrono_literals;
namespace gr = device::gripper;
using device::robotiq::RobotiqConfig;
using device::robotiq::RobotiqHardware;
using pnp::testing::waitUntil;
using sim::robotiq::Robotiq2f85;

namespace {

constexpr double kStep = 0.002;  // s, the cell's step

world::CellDescription thesisCellFile() {
    auto cell =
        world::loadCellFile(std::filesystem::path(PNP_MODELS_DIR) / "cells" / "thesis.yaml");
    if (!cell.ok()) {
        ADD_FAILURE() << cell.error().message;
        return {};
    }
    return *cell;
}

// The thesis cell with the 2F-85 locked on the UR5's flange (powered) from the start; with
// `object`, the first object (made `across` wide) between the finger tips.
world::CellDescription robotiqOnTheFlange(bool object, double across = 0.016) {
    world::CellDescription cell = thesisCellFile();
    for (auto& dock : cell.docks)
        if (dock.tool == "parallel-gripper") dock.tool.reset();
    if (cell.robots.empty() || cell.objects.empty()) return cell;
    cell.robots[0].tool = "parallel-gripper";
    if (!object) return cell;
    world::ObjectDescription& cube = cell.objects[0];
    cube.size = Eigen::Vector3d(across, across, 0.04);
    const world::RobotDescription& r = cell.robots[0];
    const world::ToolDescription* t = cell.findTool("parallel-gripper");
    Eigen::Isometry3d flange = r.base * kinematics::forward(r.model, r.home);
    flange.translation() = cube.pose.translation() - flange.linear() * t->tcp.translation();
    cube.pose.linear() = flange.linear() * t->tcp.linear();
    auto q = kinematics::solveNearest(r.model, r.base.inverse() * flange, r.home);
    if (!q.ok()) {
        ADD_FAILURE() << q.error().message;
        return cell;
    }
    cell.robots[0].home = *q;
    return cell;
}

std::size_t toolNamed(const world::World& world, const std::string& name) {
    const auto& tools = world.description().tools;
    for (std::size_t i = 0; i < tools.size(); ++i)
        if (tools[i].name == name) return i;
    ADD_FAILURE() << "no tool " << name;
    return 0;
}

// The simulated gripper on a pty, its world stepped at 500 Hz in real time (bounded).
struct SimulatedRobotiq {
    world::World world;
    std::size_t tool = toolNamed(world, "parallel-gripper");
    Robotiq2f85 gripper{world, tool, {.activationTime = 0.1}};
    modbus::PseudoTerminal pty;
    modbus::RtuSlave slave{pty.masterFd(), Robotiq2f85::rtuConfig(), gripper};
    std::atomic<bool> stepping{true};
    std::thread stepper;

    explicit SimulatedRobotiq(bool object, double across = 0.016)
        : world(robotiqOnTheFlange(object, across)) {
        slave.start();
        stepper = std::thread([this] {
            auto next = std::chrono::steady_clock::now();
            for (int i = 0; i < 60000 && stepping; ++i) {  // 2 min at most
                world.step(kStep);
                gripper.step(kStep);
                next += 2ms;
                std::this_thread::sleep_until(next);
            }
        });
    }
    ~SimulatedRobotiq() {
        pause();
        slave.stop();
    }
    // Stops the stepping: the world (not thread-safe) may be read afterwards.
    void pause() {
        stepping = false;
        if (stepper.joinable()) stepper.join();
    }
    // The line's far end is a thread of this process, which a loaded machine (CI runs the
    // tests in parallel, the sanitizers slow every thread) may not run for a while: a generous
    // answer time, as what is under test here is never how fast the device answers.
    RobotiqConfig config() const { return {.serialPath = pty.path(), .transactionTimeout = 1s}; }
};

gr::Deadline in(std::chrono::milliseconds d) { return gr::Clock::now() + d; }

TEST(RobotiqOnTheSimulator, ActivatesAndRefusesAGraspOnEmptyAir) {
    SimulatedRobotiq sim(false);
    RobotiqHardware h(sim.config());
    ASSERT_TRUE(h.connect(in(5000ms)).ok());
    std::atomic<bool> cancel{false};
    auto a = h.activate(in(5000ms), cancel);
    ASSERT_TRUE(a.ok()) << a.error().message;
    auto s = h.status(in(5000ms));
    ASSERT_TRUE(s.ok());
    EXPECT_TRUE(s->ready);

    auto g = h.grasp({.width = 0.0, .speed = 0.15, .force = 100.0}, in(5000ms), cancel);
    ASSERT_FALSE(g.ok());
    EXPECT_EQ(g.error().kind, gr::ErrorKind::kRefused);
    EXPECT_NE(g.error().message.find("no object between the fingers"), std::string::npos)
        << g.error().message;
    auto r = h.release(in(5000ms), cancel);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_FALSE(r->holding);
    EXPECT_GT(sim.gripper.opening(), 0.08);
    sim.pause();
    EXPECT_FALSE(sim.world.held(sim.tool));
}

TEST(RobotiqOnTheSimulator, GraspsAnObjectTheWorldThenHolds) {
    SimulatedRobotiq sim(true);
    RobotiqHardware h(sim.config());
    ASSERT_TRUE(h.connect(in(5000ms)).ok());
    std::atomic<bool> cancel{false};
    ASSERT_TRUE(h.activate(in(5000ms), cancel).ok());
    auto g = h.grasp({.width = 0.0, .speed = 0.15, .force = 50.0}, in(5000ms), cancel);
    ASSERT_TRUE(g.ok()) << g.error().message;
    EXPECT_TRUE(g->holding);
    EXPECT_NEAR(g->width, 0.016, 0.0005);  // stopped on the 16 mm object (a count: 0.39 mm)
    auto r = h.release(in(5000ms), cancel);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_FALSE(r->holding);
    sim.pause();
    EXPECT_FALSE(sim.world.held(sim.tool));
}

// The adapter's widths are the world's: a grasp on the 40 mm cube reports 40 mm, a move
// goes to the opening asked for.
TEST(RobotiqOnTheSimulator, WidthsAreTheWorlds) {
    SimulatedRobotiq sim(true, 0.04);
    RobotiqHardware h(sim.config());
    ASSERT_TRUE(h.connect(in(5000ms)).ok());
    std::atomic<bool> cancel{false};
    ASSERT_TRUE(h.activate(in(5000ms), cancel).ok());
    auto s = h.status(in(5000ms));
    ASSERT_TRUE(s.ok());
    EXPECT_DOUBLE_EQ(s->width, 0.085);  // activated: fully open
    auto g = h.grasp({.width = 0.0, .speed = 0.15, .force = 50.0}, in(5000ms), cancel);
    ASSERT_TRUE(g.ok()) << g.error().message;
    EXPECT_TRUE(g->holding);
    EXPECT_NEAR(g->width, 0.04, 0.0005);
    EXPECT_NEAR(sim.gripper.opening(), 0.04, 0.0005);
    ASSERT_TRUE(h.release(in(5000ms), cancel).ok());
    for (const double width : {0.06, 0.075}) {
        auto m = h.move({.width = width, .speed = 0.15, .force = 50.0}, in(5000ms), cancel);
        ASSERT_TRUE(m.ok()) << m.error().message;
        EXPECT_NEAR(m->width, width, 0.0005);
        EXPECT_NEAR(sim.gripper.opening(), width, 0.0005);
    }
}

TEST(RobotiqOnTheSimulator, AGraspedObjectIsHeldByTheWorld) {
    SimulatedRobotiq sim(true);
    RobotiqHardware h(sim.config());
    ASSERT_TRUE(h.connect(in(5000ms)).ok());
    std::atomic<bool> cancel{false};
    ASSERT_TRUE(h.activate(in(5000ms), cancel).ok());
    auto g = h.grasp({.width = 0.0, .speed = 0.15, .force = 50.0}, in(5000ms), cancel);
    ASSERT_TRUE(g.ok()) << g.error().message;
    sim.pause();
    EXPECT_EQ(sim.world.held(sim.tool), std::optional<std::size_t>(0));
}

TEST(RobotiqOnTheSimulator, CancelStopsTheFingersMidStroke) {
    SimulatedRobotiq sim(false);
    RobotiqHardware h(sim.config());
    ASSERT_TRUE(h.connect(in(5000ms)).ok());
    std::atomic<bool> cancel{false};
    ASSERT_TRUE(h.activate(in(5000ms), cancel).ok());
    const double open = sim.gripper.opening();
    // The slowest speed: 20 mm/s, the stroke takes > 4 s.
    std::thread halt([&] {
        std::this_thread::sleep_for(300ms);
        cancel = true;
    });
    auto g = h.grasp({.width = 0.0, .speed = 0.02, .force = 50.0}, in(10000ms), cancel);
    halt.join();
    ASSERT_FALSE(g.ok());
    EXPECT_EQ(g.error().kind, gr::ErrorKind::kCancelled);
    std::this_thread::sleep_for(100ms);
    const double stopped = sim.gripper.opening();
    EXPECT_LT(stopped, open);
    EXPECT_GT(stopped, 0.03);
    std::this_thread::sleep_for(200ms);
    EXPECT_NEAR(sim.gripper.opening(), stopped, 1e-9);  // it stays
}

TEST(RobotiqOnTheSimulator, AnUnpoweredGripperIsNoDevice) {
    world::CellDescription cell = thesisCellFile();  // the 2F-85 in its dock: no power
    world::World world(cell);
    const std::size_t tool = toolNamed(world, "parallel-gripper");
    Robotiq2f85 gripper(world, tool);
    gripper.step(kStep);
    modbus::PseudoTerminal pty;
    modbus::RtuSlave slave(pty.masterFd(), Robotiq2f85::rtuConfig(), gripper);
    slave.start();
    RobotiqHardware h({.serialPath = pty.path()});
    const auto t0 = gr::Clock::now();
    auto c = h.connect(in(50ms));
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.error().kind, gr::ErrorKind::kNoDevice);
    EXPECT_NE(c.error().message.find("no answer from slave 9"), std::string::npos)
        << c.error().message;
    EXPECT_LT(gr::Clock::now() - t0, 500ms);  // bounded by the deadline
    slave.stop();
}

TEST(RobotiqOnTheSimulator, TheToolAdapterServesAGraspOverOpcUa) {
    SimulatedRobotiq sim(true);
    RobotiqHardware h(sim.config());
    gr::ToolAdapterOptions o;
    o.server = pnp::testing::loopbackConfig();
    o.device.name = "Robotiq";
    o.device.speed = 0.15;
    // Polls and a grace time a loaded machine cannot miss (the lifecycle's timing is
    // tool_adapter_test's): a withdrawn server would halt the grasp under test.
    o.pollTimeout = 500ms;
    o.graceTime = 5s;
    gr::ToolAdapter adapter(h, o);
    adapter.start();
    ASSERT_TRUE(waitUntil([&] { return adapter.serving(); }, 30000ms));
    auto ua = std::make_shared<ua::client::Client>();
    ua->connect(adapter.endpointUrl());
    const auto sk = ua->namespaceIndex("urn:pnp:ua:skills", 5s);
    const auto di = ua->namespaceIndex("http://opcfoundation.org/UA/DI/", 5s);
    const ua::NodeId grasp =
        ua->resolve(ua::NodeId(di, ua::UInt32{5001}),
                    "/1:Robotiq/" + std::to_string(sk) + ":Skills/1:Grasp", 5s);
    skill::client::GraspGripperSkillClient client(ua, grasp, 5s);
    auto r = client.run(60.0, 10s);
    EXPECT_EQ(r.result, skill::SkillResult::Completed) << r.message;
    ua->disconnect();
    adapter.stop();
    sim.pause();
    EXPECT_EQ(sim.world.held(sim.tool), std::optional<std::size_t>(0));
}

}  // namespace
