// The simulated Robotiq 2F-85 (pnp_sim_robotiq) behind modbus::RtuSlave on a pseudo-terminal:
// the manual's example frames byte for byte, libmodbus as the adapter would use it, the
// faults, the timings, and grasping an object of the world. Every wait is bounded.
#include <gtest/gtest.h>
#include <modbus.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <memory>
#include <thread>

#include "../modbus/modbus_helpers.hpp"
#include "kinematics/kinematics.hpp"
#include "sim/robotiq/robotiq_2f85.hpp"
#include "world/cell_file.hpp"
#include "world/world.hpp"

namespace pnp::sim::robotiq::test {
namespace {

using modbus::test::Bytes;
using modbus::test::fromHex;
using modbus::test::rtuFrame;
using modbus::test::SerialPeer;
using modbus::test::toHex;
using namespace std::chrono_literals;

constexpr double kDt = 0.002;  // s, the cell's step

world::CellDescription thesisCell() {
    auto cell =
        world::loadCellFile(std::filesystem::path(PNP_MODELS_DIR) / "cells" / "thesis.yaml");
    if (!cell.ok()) {
        ADD_FAILURE() << cell.error().message;
        return {};
    }
    return *cell;
}

// The thesis cell with the 2F-85 locked on the UR5's flange from the start.
world::CellDescription gripperOnFlange() {
    world::CellDescription cell = thesisCell();
    for (auto& dock : cell.docks) {
        if (dock.tool == "parallel-gripper") dock.tool.reset();
    }
    if (!cell.robots.empty()) cell.robots[0].tool = "parallel-gripper";
    return cell;
}

std::size_t toolIndex(const world::World& world, const std::string& name) {
    const auto& tools = world.description().tools;
    for (std::size_t i = 0; i < tools.size(); ++i) {
        if (tools[i].name == name) return i;
    }
    ADD_FAILURE() << "no tool " << name;
    return 0;
}

struct ModbusDeleter {
    void operator()(modbus_t* ctx) const {
        modbus_close(ctx);
        modbus_free(ctx);
    }
};
using Context = std::unique_ptr<modbus_t, ModbusDeleter>;

// The adapter's view: libmodbus RTU on the pty, slave 9, 115200 8N1.
Context adapter(const std::string& path, int slave = Robotiq2f85::kSlave) {
    Context ctx(modbus_new_rtu(path.c_str(), 115200, 'N', 8, 1));
    if (!ctx) return ctx;
    modbus_set_slave(ctx.get(), slave);
    modbus_set_response_timeout(ctx.get(), 0, 500000);
    if (modbus_connect(ctx.get()) != 0) {
        ADD_FAILURE() << "modbus_connect: " << modbus_strerror(errno);
        return nullptr;
    }
    return ctx;
}

struct Fixture : ::testing::Test {
    explicit Fixture(world::CellDescription cell = gripperOnFlange()) : world(std::move(cell)) {}

    world::World world;
    std::size_t tool = toolIndex(world, "parallel-gripper");
    Robotiq2f85 gripper{world, tool};
    modbus::PseudoTerminal pty;
    modbus::RtuSlave slave{pty.masterFd(), Robotiq2f85::rtuConfig(), gripper};

    void SetUp() override { slave.start(); }
    void TearDown() override {
        stopStepping();
        slave.stop();
    }

    // Simulated time, stepped here (deterministic): world then gripper, as the cell does.
    void run(double seconds) {
        const int steps = static_cast<int>(std::lround(seconds / kDt));
        for (int i = 0; i < steps; ++i) {
            world.step(kDt);
            gripper.step(kDt);
        }
    }

    // Real time: a stepping thread at 500 Hz (bounded to 20 s) for tests through libmodbus.
    void startStepping() {
        stepping_ = true;
        stepper_ = std::thread([this] {
            auto next = std::chrono::steady_clock::now();
            for (int i = 0; i < 10000 && stepping_; ++i) {
                world.step(kDt);
                gripper.step(kDt);
                next += 2ms;
                std::this_thread::sleep_until(next);
            }
        });
    }
    void stopStepping() {
        stepping_ = false;
        if (stepper_.joinable()) stepper_.join();
    }

    // Request -> response through the pty, raw bytes.
    std::string exchange(SerialPeer& peer, const std::string& request, std::size_t count) {
        return toHex(peer.exchange(fromHex(request), count, 1000ms));
    }
    // The response the gripper should give: our address, the PDU, its CRC.
    static std::string frame(const std::string& pdu) {
        return toHex(rtuFrame(Robotiq2f85::kSlave, fromHex(pdu)));
    }

    std::atomic<bool> stepping_{false};
    std::thread stepper_;
};

TEST_F(Fixture, ToolOnTheFlangeIsPoweredAndAnswers) {
    ASSERT_TRUE(world.toolPowered(tool));
    gripper.step(kDt);
    EXPECT_TRUE(gripper.answering());
    EXPECT_NEAR(gripper.opening(), 0.085, 1e-9);
}

// The manual's example (Control > Modbus RTU > Example), frame by frame, with the fingers
// closing on nothing; the frames that depend on an object are in GraspAnObject below.
TEST_F(Fixture, ManualExampleFramesByteForByte) {
    SerialPeer peer(pty.path());
    ASSERT_TRUE(peer.ok());
    // Step 1: activation request (clear rACT, then set it).
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 00 00 00 00 00 00 73 30", 8),
              "09 10 03 E8 00 03 01 30");
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 01 00 00 00 00 00 72 E1", 8),
              "09 10 03 E8 00 03 01 30");
    // Step 2: read the status until the activation is completed (FC03 and FC04 alike).
    EXPECT_EQ(exchange(peer, "09 03 07 D0 00 01 85 CF", 7), "09 03 02 11 00 55 D5");
    EXPECT_EQ(exchange(peer, "09 04 07 D0 00 01 30 0F", 7), "09 04 02 11 00 54 A1");
    run(0.5);
    EXPECT_EQ(exchange(peer, "09 04 07 D0 00 01 30 0F", 7), "09 04 02 11 00 54 A1");
    run(0.502);
    EXPECT_EQ(exchange(peer, "09 03 07 D0 00 01 85 CF", 7), "09 03 02 31 00 4C 15");
    EXPECT_EQ(exchange(peer, "09 04 07 D0 00 01 30 0F", 7), "09 04 02 31 00 4D 61");
    // Step 4: close at full speed and full force.
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 09 00 00 FF FF FF 42 29", 8),
              "09 10 03 E8 00 03 01 30");
    // Step 5: the grip is not completed yet (one step later: position 14, 100 mA).
    run(kDt);
    EXPECT_EQ(exchange(peer, "09 03 07 D0 00 03 04 0E", 11), "09 03 06 39 00 00 FF 0E 0A F7 8B");
    // Nothing between the fingers: they close to their end, at the requested position.
    run(1.0);
    EXPECT_EQ(exchange(peer, "09 04 07 D0 00 03 B1 CE", 11), frame("04 06 F9 00 00 FF E6 00"));
    EXPECT_NEAR(gripper.opening(), 0.0, 1e-9);
    // Step 7: open at full speed and full force.
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 09 00 00 00 FF FF 72 19", 8),
              "09 10 03 E8 00 03 01 30");
    run(0.01);
    EXPECT_EQ(exchange(peer, "09 04 07 D0 00 03 B1 CE", 11).substr(0, 18), "09 04 06 39 00 00 ");
    // Step 8: the opening is completed: the fingers at their software limit, 13/255.
    run(1.0);
    EXPECT_EQ(exchange(peer, "09 04 07 D0 00 03 B1 CE", 11), "09 04 06 F9 00 00 00 0D 00 17 AA");
    EXPECT_NEAR(gripper.opening(), 0.085, 1e-9);
    // The manual's FC16 example on 0x03E9 (position, speed, force only) is taken as well.
    EXPECT_EQ(exchange(peer, "09 10 03 E9 00 02 04 60 E6 3C C8 EC 7C", 8),
              "09 10 03 E9 00 02 91 30");
    EXPECT_EQ(slave.stats().frames, 14u);
}

TEST_F(Fixture, MotionTakesTheStrokeOverTheRequestedSpeed) {
    const std::uint16_t activate[3] = {0x0100, 0x0000, 0x0000};
    ASSERT_EQ(gripper.writeHolding(0x03E8, activate), modbus::Exception::kNone);
    run(1.002);
    ASSERT_EQ(gripper.statusBytes()[0], 0x31);
    // rSP 0: 20 mm/s, 85 mm in 4.25 s; rSP 255: 150 mm/s, 0.567 s.
    for (const auto& [speed, seconds] : {std::pair{0x00, 4.25}, std::pair{0xFF, 0.085 / 0.150}}) {
        const std::uint16_t close[3] = {0x0900, 0x00FF, static_cast<std::uint16_t>(speed << 8)};
        ASSERT_EQ(gripper.writeHolding(0x03E8, close), modbus::Exception::kNone);
        int steps = 0;
        while (gripper.statusBytes()[0] >> 6 != 3 && steps < 5000) {
            run(kDt);
            ++steps;
        }
        EXPECT_NEAR(steps * kDt, seconds, 2 * kDt) << "rSP " << speed;
        EXPECT_EQ(gripper.statusBytes()[4], 0xE6);
        const std::uint16_t open[3] = {0x0900, 0x0000, 0xFF00};
        ASSERT_EQ(gripper.writeHolding(0x03E8, open), modbus::Exception::kNone);
        run(1.0);
        EXPECT_EQ(gripper.statusBytes()[4], 0x0D);
    }
}

TEST_F(Fixture, HalfwayRequestStopsThereWithMidStrokeWidth) {
    const std::uint16_t activate[3] = {0x0100, 0, 0};
    gripper.writeHolding(0x03E8, activate);
    run(1.002);
    const std::uint16_t half[3] = {0x0900, 0x0080, 0x8000};  // rPR 128
    gripper.writeHolding(0x03E8, half);
    run(2.0);
    const auto s = gripper.statusBytes();
    EXPECT_EQ(s[0], 0xF9);
    EXPECT_EQ(s[3], 0x80);
    EXPECT_EQ(s[4], 0x80);
    EXPECT_NEAR(gripper.opening(), 0.085 * (230 - 128) / 217.0, 1e-9);
    // rGTO 0 stops the motion where it is; gGTO and gOBJ read 0.
    const std::uint16_t close[3] = {0x0900, 0x00FF, 0x8000};
    gripper.writeHolding(0x03E8, close);
    run(0.1);
    const std::uint16_t stop[1] = {0x0100};
    gripper.writeHolding(0x03E8, stop);
    const double stoppedAt = gripper.opening();
    run(0.5);
    EXPECT_EQ(gripper.opening(), stoppedAt);
    EXPECT_EQ(gripper.statusBytes()[0], 0x31);
}

TEST_F(Fixture, FaultsOfTheManual) {
    // rGTO without rACT: 0x07, nothing moves.
    const std::uint16_t goWithoutActivation[3] = {0x0800, 0x00FF, 0xFFFF};
    gripper.writeHolding(0x03E8, goWithoutActivation);
    run(0.5);
    auto s = gripper.statusBytes();
    EXPECT_EQ(s[0], 0x00);
    EXPECT_EQ(s[2], Robotiq2f85::kFaultActivationBitClear);
    // rGTO during the activation: 0x05, the action follows once activated.
    const std::uint16_t activateAndGo[3] = {0x0900, 0x00FF, 0xFFFF};
    gripper.writeHolding(0x03E8, activateAndGo);
    s = gripper.statusBytes();
    EXPECT_EQ(s[0], 0x11);
    EXPECT_EQ(s[2], Robotiq2f85::kFaultActionDelayed);
    run(1.002);
    s = gripper.statusBytes();
    EXPECT_EQ(s[2], Robotiq2f85::kFaultNone);
    EXPECT_EQ(s[0] & 0x3F, 0x39);  // activated, going
    run(1.0);
    EXPECT_EQ(gripper.statusBytes()[0], 0xF9);
    // Automatic release (rATR, rARD opening): slowly open, then 0x0F until reactivated.
    const std::uint16_t release[1] = {0x3100};
    gripper.writeHolding(0x03E8, release);
    s = gripper.statusBytes();
    EXPECT_EQ(s[0], 0x01);  // gACT, gSTA 0 (automatic release)
    EXPECT_EQ(s[2], Robotiq2f85::kFaultAutoReleaseRunning);
    run(5.0);
    s = gripper.statusBytes();
    EXPECT_EQ(s[2], Robotiq2f85::kFaultAutoReleaseDone);
    EXPECT_EQ(s[4], 0x0D);
    const std::uint16_t go[1] = {0x0900};
    gripper.writeHolding(0x03E8, go);
    EXPECT_EQ(gripper.statusBytes()[2], Robotiq2f85::kFaultAutoReleaseDone);
    const std::uint16_t reset[1] = {0x0000};
    gripper.writeHolding(0x03E8, reset);
    EXPECT_EQ(gripper.statusBytes()[2], Robotiq2f85::kFaultNone);
    EXPECT_EQ(gripper.statusBytes()[0], 0x00);
}

TEST_F(Fixture, LibmodbusActivatesClosesOnNothingAndOpens) {
    startStepping();
    Context ctx = adapter(pty.path());
    ASSERT_TRUE(ctx);
    auto status = [&](std::uint16_t* regs) {
        return modbus_read_input_registers(ctx.get(), 0x07D0, 3, regs) == 3;
    };
    auto waitFor = [&](auto done, std::chrono::milliseconds timeout) {
        std::uint16_t regs[3] = {};
        const auto end = std::chrono::steady_clock::now() + timeout;
        while (std::chrono::steady_clock::now() < end) {
            if (status(regs) && done(regs)) return true;
            std::this_thread::sleep_for(5ms);
        }
        return false;
    };
    const std::uint16_t clear[3] = {0, 0, 0};
    ASSERT_EQ(modbus_write_registers(ctx.get(), 0x03E8, 3, clear), 3) << modbus_strerror(errno);
    const std::uint16_t activate[3] = {0x0100, 0, 0};
    ASSERT_EQ(modbus_write_registers(ctx.get(), 0x03E8, 3, activate), 3);
    EXPECT_TRUE(waitFor([](const std::uint16_t* r) { return r[0] == 0x3100; }, 3000ms));
    // Close and read back in one FC23 transaction, as the manual shows it.
    const std::uint16_t close[3] = {0x0900, 0x00FF, 0xFFFF};
    std::uint16_t regs[3] = {};
    ASSERT_EQ(modbus_write_and_read_registers(ctx.get(), 0x03E8, 3, close, 0x07D0, 3, regs), 3)
        << modbus_strerror(errno);
    EXPECT_EQ(regs[0], 0x3900);  // go-to, fingers in motion
    EXPECT_EQ(regs[1], 0x00FF);  // no fault, rPR echoed
    EXPECT_TRUE(waitFor([](const std::uint16_t* r) { return r[0] >> 14 == 3; }, 3000ms));
    ASSERT_TRUE(status(regs));
    EXPECT_EQ(regs[0], 0xF900);
    EXPECT_EQ(regs[2], 0xE600);  // closed to the end: nothing was there
    const std::uint16_t open[3] = {0x0900, 0x0000, 0xFFFF};
    ASSERT_EQ(modbus_write_registers(ctx.get(), 0x03E8, 3, open), 3);
    EXPECT_TRUE(
        waitFor([](const std::uint16_t* r) { return r[0] == 0xF900 && r[2] == 0x0D00; }, 3000ms));
    // The adapter may read its own request back (FC03 on the output registers).
    ASSERT_EQ(modbus_read_registers(ctx.get(), 0x03E8, 3, regs), 3);
    EXPECT_EQ(regs[0], 0x0900);
    EXPECT_EQ(regs[2], 0xFFFF);
}

TEST_F(Fixture, IllegalRegistersGetException02) {
    Context ctx = adapter(pty.path());
    ASSERT_TRUE(ctx);
    std::uint16_t regs[9] = {};
    EXPECT_EQ(modbus_read_input_registers(ctx.get(), 0x0000, 1, regs), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_read_input_registers(ctx.get(), 0x07D0, 9, regs), -1);  // one too many
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0x07CF, 2, regs), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_write_register(ctx.get(), 0x07D0, 0x0100), -1);  // status is read-only
    EXPECT_EQ(errno, EMBXILADD);
    const std::uint16_t values[2] = {0, 0};
    EXPECT_EQ(modbus_write_registers(ctx.get(), 0x03EF, 2, values), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_read_input_registers(ctx.get(), 0x07D0, 8, regs), 8);
    EXPECT_EQ(modbus_write_register(ctx.get(), 0x03EF, 0), 1);
}

TEST_F(Fixture, BadCrcAndOtherSlaveGetNoAnswer) {
    SerialPeer peer(pty.path());
    ASSERT_TRUE(peer.ok());
    EXPECT_EQ(exchange(peer, "09 03 07 D0 00 01 85 CE", 7), "");  // CRC off by one bit
    EXPECT_EQ(exchange(peer, "0A 03 07 D0 00 01 85 CF", 7), "");  // slave 10, old CRC
    EXPECT_EQ(toHex(peer.exchange(rtuFrame(10, fromHex("03 07 D0 00 01")), 7, 200ms)), "");
    EXPECT_EQ(exchange(peer, "09 03 07 D0 00 01 85 CF", 7), frame("03 02 00 00"));
    const modbus::RtuStats s = slave.stats();
    EXPECT_EQ(s.badCrc, 2u);
    EXPECT_EQ(s.otherSlave, 1u);
    EXPECT_EQ(s.frames, 1u);
}

// The thesis cell as it starts: the 2F-85 parked in its dock, without power.
struct Unpowered : Fixture {
    Unpowered() : Fixture(thesisCell()) {}
};

TEST_F(Unpowered, ToolInItsDockDoesNotAnswer) {
    ASSERT_FALSE(world.toolPowered(tool));
    run(0.01);
    EXPECT_FALSE(gripper.answering());
    Context ctx = adapter(pty.path());
    ASSERT_TRUE(ctx);
    modbus_set_response_timeout(ctx.get(), 0, 200000);
    std::uint16_t regs[3] = {};
    EXPECT_EQ(modbus_read_input_registers(ctx.get(), 0x07D0, 3, regs), -1);
    EXPECT_EQ(errno, ETIMEDOUT);
    EXPECT_EQ(slave.stats().notAnswering, 1u);
}

// The manual's grasp: an object 16 mm across between the fingers stops them at 189/255.
world::CellDescription narrowObjectUnderTheGripper() {
    world::CellDescription cell = gripperOnFlange();
    if (cell.objects.empty() || cell.robots.empty()) return cell;
    world::ObjectDescription& cube = cell.objects[0];
    cube.size = Eigen::Vector3d(0.016, 0.016, 0.04);
    // The grip point (the finger tips) at the object's centre, the flange pointing down.
    const world::RobotDescription& r = cell.robots[0];
    const world::ToolDescription* t = cell.findTool("parallel-gripper");
    Eigen::Isometry3d flange = r.base * kinematics::forward(r.model, r.home);
    flange.translation() = cube.pose.translation() - flange.linear() * t->tcp.translation();
    // The object turned as the grip frame: 16 mm across the fingers whatever their heading.
    cube.pose.linear() = flange.linear() * t->tcp.linear();
    auto q = kinematics::solveNearest(r.model, r.base.inverse() * flange, r.home);
    if (!q.ok()) {
        ADD_FAILURE() << q.error().message;
        return cell;
    }
    cell.robots[0].home = *q;
    return cell;
}

struct WithObject : Fixture {
    WithObject() : Fixture(narrowObjectUnderTheGripper()) {}
};

TEST_F(WithObject, GraspAnObjectAsInTheManual) {
    SerialPeer peer(pty.path());
    ASSERT_TRUE(peer.ok());
    const auto grip = world.gripPoint(tool);
    ASSERT_TRUE(grip);
    ASSERT_LT((grip->translation() - world.objects()[0].pose.translation()).norm(), 1e-6);
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 01 00 00 00 00 00 72 E1", 8),
              "09 10 03 E8 00 03 01 30");
    run(1.002);
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 09 00 00 FF FF FF 42 29", 8),
              "09 10 03 E8 00 03 01 30");
    run(1.0);
    // Step 5: the grasp is completed: stopped on contact while closing, at 189/255.
    EXPECT_EQ(exchange(peer, "09 04 07 D0 00 03 B1 CE", 11), "09 04 06 B9 00 00 FF BD 00 5C 9A");
    EXPECT_EQ(world.held(tool), std::optional<std::size_t>(0));
    EXPECT_NEAR(gripper.opening(), 0.016, 1e-9);
    // Step 7-8: opening; three steps later the fingers have left the object (187/255, 160 mA).
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 09 00 00 00 FF FF 72 19", 8),
              "09 10 03 E8 00 03 01 30");
    run(3 * kDt);
    EXPECT_EQ(exchange(peer, "09 04 07 D0 00 03 B1 CE", 11), "09 04 06 39 00 00 00 BB 10 71 06");
    EXPECT_FALSE(world.held(tool));
    run(1.0);
    EXPECT_EQ(exchange(peer, "09 04 07 D0 00 03 B1 CE", 11), "09 04 06 F9 00 00 00 0D 00 17 AA");
}

// The 4 cm green cube on the table, its centre `offset` (m) beside the grip point along the
// fingers' axis (the robot's tracking error, a cube put down off its nominal place), turned as
// the fingers; the grip point at the height of its centre.
world::CellDescription cubeOffCentreBetweenTheFingers(double offset) {
    world::CellDescription cell = gripperOnFlange();
    if (cell.objects.empty() || cell.robots.empty()) return cell;
    world::ObjectDescription& cube = cell.objects[0];
    const world::RobotDescription& r = cell.robots[0];
    const world::ToolDescription* t = cell.findTool("parallel-gripper");
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

struct OffCentre : Fixture, ::testing::WithParamInterface<double> {
    OffCentre() : Fixture(cubeOffCentreBetweenTheFingers(GetParam())) {}

    // The UR's protective stop limit (sim::ur::UrControllerConfig::protectiveStopForce).
    static constexpr double kProtectiveStopForce = 250.0;  // N
    double maxForce = 0.0;

    // As run(), the world refreshed after the gripper's step too (as the robot controller's
    // next setJoints does), recording the largest TCP force.
    void stepAndWatch(double seconds) {
        const int steps = static_cast<int>(std::lround(seconds / kDt));
        for (int i = 0; i < steps; ++i) {
            world.step(kDt);
            maxForce = std::max(maxForce, world.robot(0).tcpForce.norm());
            gripper.step(kDt);
            world.step(0.0);
            maxForce = std::max(maxForce, world.robot(0).tcpForce.norm());
        }
    }
};

TEST_P(OffCentre, FingersClosingCentreTheCubeWithoutATcpForce) {
    SerialPeer peer(pty.path());
    ASSERT_TRUE(peer.ok());
    const std::size_t cube = 0;
    // Activate (the fingers open fully), then close at full speed and force (rPR 255).
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 01 00 00 00 00 00 72 E1", 8),
              "09 10 03 E8 00 03 01 30");
    stepAndWatch(1.002);
    EXPECT_EQ(maxForce, 0.0) << "the open fingers are clear of the cube";
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 09 00 00 FF FF FF 42 29", 8),
              "09 10 03 E8 00 03 01 30");
    stepAndWatch(1.0);
    // The first finger to touch pushed the cube along the table to the centre; held there.
    EXPECT_EQ(world.held(tool), std::optional<std::size_t>(cube));
    EXPECT_NEAR(gripper.opening(), 0.04, 1e-9);
    const auto grip = world.gripPoint(tool);
    ASSERT_TRUE(grip);
    const Eigen::Vector3d inGrip = grip->inverse() * world.objects()[cube].pose.translation();
    EXPECT_NEAR(inGrip.x(), 0.0, 1e-9) << "held centred between the jaws";
    EXPECT_NEAR(inGrip.y(), 0.0, 1e-9);
    EXPECT_LT(maxForce, 1.0) << "closing: side contact is no push into a top face (the UR "
                             << "stops at " << kProtectiveStopForce << " N)";
    maxForce = 0.0;
    // Open (rPR 0): it rests on the table where it is, centred; the fingers leave its sides.
    EXPECT_EQ(exchange(peer, "09 10 03 E8 00 03 06 09 00 00 00 FF FF 72 19", 8),
              "09 10 03 E8 00 03 01 30");
    stepAndWatch(1.0);
    EXPECT_FALSE(world.held(tool));
    EXPECT_EQ(world.objects()[cube].holder, "table");
    EXPECT_NEAR(world.objects()[cube].pose.translation().z(), 0.02, 1e-9);
    EXPECT_LT(maxForce, 1.0) << "releasing: side contact is no push into a top face";
}

INSTANTIATE_TEST_SUITE_P(CubeOffTheGripPoint, OffCentre,
                         ::testing::Values(0.0, 0.0005, -0.0005, 0.001, -0.001));

}  // namespace
}  // namespace pnp::sim::robotiq::test
