// The simulated cell in process (src/sim/cell): the thesis cell's world stepped at 500 Hz,
// its UR controller reached over RTDE on a real socket, and the ground truth read over
// OPC UA — as an adapter and a test would see them.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <mutex>
#include <numbers>
#include <optional>
#include <set>
#include <thread>

#include "device/ur/ur_hardware.hpp"
#include "robot/controller.hpp"
#include "robot/planner.hpp"
#include "rtde/client.hpp"
#include "sim/cell/ground_truth.hpp"
#include "sim/cell/simulator.hpp"
#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/client/error.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/status_codes.hpp"
#include "world/cell_file.hpp"

namespace {

using namespace std::chrono_literals;
using pnp::sim::cell::Simulator;

pnp::world::CellDescription thesisCell() {
    auto cell = pnp::world::loadCellFile(pnp::sim::cell::defaultCellFile());
    EXPECT_TRUE(cell.ok()) << (cell.ok() ? "" : cell.error().message);
    return cell.value();
}

pnp::sim::cell::SimulatorConfig testConfig() {
    pnp::sim::cell::SimulatorConfig c;
    c.ephemeralPorts = true;
    return c;
}

std::vector<double> readDoubles(pnp::ua::client::Client& c, const pnp::ua::NodeId& node) {
    auto v = c.readValue(node, 5s);
    const auto* a = v.array<double>();
    return a ? *a : std::vector<double>{};
}

TEST(SimCell, ServesTheUrControllerOverRtdeOnTheAddressItReports) {
    const auto cell = thesisCell();
    Simulator sim(cell, testConfig());
    sim.start();
    const auto endpoints = sim.endpoints();
    // The UR controller first, then the tools' devices and the changer's ADC input.
    ASSERT_EQ(endpoints.size(), 5u);
    EXPECT_EQ(endpoints[1].device, "robotiq-2f85");
    EXPECT_EQ(endpoints[1].protocol, "modbus-rtu");
    EXPECT_EQ(endpoints[1].address().rfind("/dev/pts/", 0), 0u) << endpoints[1].address();
    EXPECT_EQ(endpoints[2].device, "schmalz-ecbpi");
    EXPECT_EQ(endpoints[2].ioLinkPort, 1u);
    EXPECT_EQ(endpoints[3].device, "schunk-wsg50");
    EXPECT_EQ(endpoints[4].device, "kelvin-adc-input");
    EXPECT_EQ(endpoints[4].name, "ur5-changer");
    for (const auto& e : endpoints)
        if (e.path.empty()) {
            EXPECT_NE(e.port, 0) << e.name;
        }
    EXPECT_EQ(endpoints[0].name, "ur5");
    EXPECT_EQ(endpoints[0].device, "ur-controller");
    EXPECT_EQ(endpoints[0].protocol, "rtde");
    ASSERT_NE(endpoints[0].port, 0);

    pnp::rtde::Client rtde;
    ASSERT_TRUE(
        rtde.connect(endpoints[0].host, endpoints[0].port, pnp::rtde::deadlineIn(2000ms)).ok());
    ASSERT_TRUE(rtde.negotiateProtocolVersion(pnp::rtde::deadlineIn(2000ms)).ok());
    auto recipe =
        rtde.setupOutputs(500.0, {"timestamp", "actual_q"}, pnp::rtde::deadlineIn(2000ms));
    ASSERT_TRUE(recipe.ok());
    ASSERT_TRUE(recipe->valid());
    ASSERT_TRUE(rtde.start(pnp::rtde::deadlineIn(2000ms)).ok());
    // 100 samples at 500 Hz: the robot stands at its home joints and the clock advances.
    double first = -1.0, last = -1.0;
    int samples = 0;
    for (int i = 0; i < 1000 && samples < 100; ++i) {
        auto r = rtde.receive(pnp::rtde::deadlineIn(1000ms));
        ASSERT_TRUE(r.ok()) << r.status().message;
        const auto* s = std::get_if<pnp::rtde::DataSample>(&r.value());
        if (!s) continue;
        ++samples;
        const double t = std::get<double>(s->values[0]);
        if (first < 0) first = t;
        last = t;
        const auto q = std::get<pnp::rtde::Vector6d>(s->values[1]);
        for (int k = 0; k < 6; ++k) EXPECT_NEAR(q[k], cell.robots[0].home[k], 1e-12);
    }
    EXPECT_EQ(samples, 100);
    EXPECT_GT(last, first);
}

TEST(SimCell, StepsAtItsFixedRate) {
    Simulator sim(thesisCell(), testConfig());
    sim.start();
    const auto t0 = std::chrono::steady_clock::now();
    const auto s0 = sim.stats().steps;
    std::this_thread::sleep_for(1000ms);
    const double elapsed =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const auto steps = sim.stats().steps - s0;
    // 500 Hz on a loaded 2-core CI machine: within 10 % over one second.
    EXPECT_NEAR(static_cast<double>(steps) / elapsed, 500.0, 50.0);
    const auto snap = sim.snapshot();
    ASSERT_TRUE(snap);
    EXPECT_NEAR(snap->time, static_cast<double>(snap->step) / 500.0, 1e-9);
}

// The thesis cell's simulator with its ground truth served on loopback, and a client of it.
struct TruthRig {
    pnp::world::CellDescription cell = thesisCell();
    Simulator sim{cell, testConfig()};
    pnp::ua::server::Server server{pnp::testing::loopbackConfig()};
    pnp::sim::cell::GroundTruth truth{server, sim, {.rate = 100.0}};
    pnp::ua::client::Client c;
    pnp::ua::UInt16 ns = 0;

    TruthRig() {
        sim.start();
        server.start();
        truth.start();
        c.connect(pnp::testing::url(server), pnp::ua::client::Anonymous{}, 5s);
        ns = c.namespaceIndex(pnp::sim::cell::kWorldNamespaceUri, 5s);
    }
};

TEST(SimCell, GroundTruthIsReadOnlyOpcUa) {
    TruthRig rig;
    const auto& cell = rig.cell;
    auto& c = rig.c;
    auto& truth = rig.truth;
    const auto ns = rig.ns;
    EXPECT_EQ(ns, truth.namespaceIndex());
    const auto joints = readDoubles(c, pnp::ua::NodeId(ns, "Robots.ur5.Joints"));
    ASSERT_EQ(joints.size(), 6u);
    for (int k = 0; k < 6; ++k) EXPECT_NEAR(joints[k], cell.robots[0].home[k], 1e-12);

    // The cube where the cell file puts it, on the table.
    auto pose = c.readValue(pnp::ua::NodeId(ns, "Objects.cube-green.Pose"), 5s);
    const auto* x = pose.scalar<pnp::ua::ExtensionObject>();
    ASSERT_NE(x, nullptr);
    auto frame = pnp::ua::fromExtensionObject<pnp::ua::ThreeDFrame>(*x);
    ASSERT_TRUE(frame);
    const auto* cube = cell.findObject("cube-green");
    ASSERT_NE(cube, nullptr);
    EXPECT_NEAR(
        (pnp::ua::spatial::toIsometry(*frame).translation() - cube->pose.translation()).norm(), 0.0,
        1e-12);
    auto holder = c.readValue(pnp::ua::NodeId(ns, "Objects.cube-green.Holder"), 5s);
    ASSERT_NE(holder.scalar<std::string>(), nullptr);
    EXPECT_EQ(*holder.scalar<std::string>(), cube->on.value_or(""));

    // Time advances; nobody may write the truth.
    const auto time1 = c.readValue(pnp::ua::NodeId(ns, "World.Time"), 5s);
    std::this_thread::sleep_for(100ms);
    const auto time2 = c.readValue(pnp::ua::NodeId(ns, "World.Time"), 5s);
    ASSERT_NE(time1.scalar<double>(), nullptr);
    ASSERT_NE(time2.scalar<double>(), nullptr);
    EXPECT_GT(*time2.scalar<double>(), *time1.scalar<double>());
    const auto status = c.writeValue(pnp::ua::NodeId(ns, "Robots.ur5.Joints"),
                                     pnp::ua::Variant(std::vector<double>(6, 0.0)), 5s);
    EXPECT_EQ(status, pnp::ua::status::BadNotWritable);
    EXPECT_EQ(readDoubles(c, pnp::ua::NodeId(ns, "Robots.ur5.Joints")), joints);
}

// What a 3D view needs besides the moving parts: the cell file's static facts, read-only.
TEST(SimCell, GroundTruthPublishesTheCellFilesStaticFacts) {
    TruthRig rig;
    const auto& cell = rig.cell;
    auto& c = rig.c;
    const auto ns = rig.ns;
    auto text = [&](const std::string& path) {
        const auto v = c.readValue(pnp::ua::NodeId(ns, path), 5s);
        const auto* s = v.scalar<std::string>();
        return s ? *s : std::string("<not a String>");
    };
    auto pose = [&](const std::string& path) -> std::optional<Eigen::Isometry3d> {
        const auto v = c.readValue(pnp::ua::NodeId(ns, path), 5s);
        const auto* x = v.scalar<pnp::ua::ExtensionObject>();
        if (!x) return std::nullopt;
        const auto f = pnp::ua::fromExtensionObject<pnp::ua::ThreeDFrame>(*x);
        if (!f) return std::nullopt;
        return pnp::ua::spatial::toIsometry(*f);
    };
    auto vector = [&](const std::string& path) -> std::optional<Eigen::Vector3d> {
        const auto v = c.readValue(pnp::ua::NodeId(ns, path), 5s);
        const auto* x = v.scalar<pnp::ua::ExtensionObject>();
        if (!x) return std::nullopt;
        const auto t = pnp::ua::fromExtensionObject<pnp::ua::ThreeDVector>(*x);
        if (!t) return std::nullopt;
        return pnp::ua::spatial::toVector(*t);
    };
    auto same = [](const std::optional<Eigen::Isometry3d>& a, const Eigen::Isometry3d& b) {
        return a && (a->translation() - b.translation()).norm() < 1e-9 &&
               (a->linear() - b.linear()).norm() < 1e-9;
    };
    auto names = [&](const std::string& folder) {
        std::set<std::string> out;
        for (const auto& r : c.browse(pnp::ua::NodeId(ns, folder), {}, 5s))
            out.insert(r.browseName.name);
        return out;
    };

    ASSERT_EQ(cell.robots.size(), 1u);
    for (const auto& r : cell.robots) {
        EXPECT_EQ(text("Robots." + r.name + ".Model"), r.modelName);
        EXPECT_EQ(r.modelName, "ur5");
        EXPECT_TRUE(same(pose("Robots." + r.name + ".Base"), r.base)) << r.name;
    }
    EXPECT_NEAR(pose("Robots.ur5.Base").value_or(Eigen::Isometry3d::Identity()).translation().x(),
                -0.3, 1e-12);

    std::set<std::string> expected;
    for (const auto& t : cell.tables) {
        expected.insert(t.name);
        EXPECT_TRUE(same(pose("Tables." + t.name + ".Pose"), t.pose)) << t.name;
        const auto size = vector("Tables." + t.name + ".Size");
        ASSERT_TRUE(size) << t.name;
        EXPECT_NEAR((*size - t.size).norm(), 0.0, 1e-12) << t.name;
    }
    EXPECT_EQ(names("Tables"), expected);
    EXPECT_EQ(expected, std::set<std::string>{"table"});

    expected.clear();
    for (const auto& d : cell.docks) {
        expected.insert(d.name);
        EXPECT_TRUE(same(pose("Docks." + d.name + ".Pose"), d.pose)) << d.name;
    }
    EXPECT_EQ(names("Docks"), expected);
    EXPECT_EQ(expected, (std::set<std::string>{"dock-1", "dock-2"}));

    for (const auto& o : cell.objects) {
        const auto size = vector("Objects." + o.name + ".Size");
        ASSERT_TRUE(size) << o.name;
        EXPECT_NEAR((*size - o.size).norm(), 0.0, 1e-12) << o.name;
        EXPECT_EQ(text("Objects." + o.name + ".Color"), o.color);
    }
    EXPECT_EQ(text("Objects.cube-green.Color"), "green");

    ASSERT_EQ(cell.tools.size(), 3u);
    for (const auto& t : cell.tools)
        EXPECT_TRUE(same(pose("Tools." + t.name + ".Tcp"), t.tcp)) << t.name;
    EXPECT_NEAR(pose("Tools.parallel-gripper.Tcp")
                    .value_or(Eigen::Isometry3d::Identity())
                    .translation()
                    .z(),
                0.2028, 1e-12);

    // Static, and read-only like the rest of the truth.
    EXPECT_EQ(c.writeValue(pnp::ua::NodeId(ns, "Robots.ur5.Model"),
                           pnp::ua::Variant(pnp::ua::String("ur10")), 5s),
              pnp::ua::status::BadNotWritable);
    EXPECT_EQ(c.writeValue(pnp::ua::NodeId(ns, "Tables.table.Size"),
                           pnp::ua::Variant(pnp::ua::toExtensionObject(
                               pnp::ua::spatial::toThreeDVector(Eigen::Vector3d(1, 1, 1)))),
                           5s),
              pnp::ua::status::BadNotWritable);
    EXPECT_EQ(text("Robots.ur5.Model"), "ur5");
}

TEST(SimCell, ServoTargetsOverRtdeMoveTheWorldsRobot) {
    const auto cell = thesisCell();
    Simulator sim(cell, testConfig());
    sim.start();
    const auto ep = sim.endpoints().at(0);
    pnp::rtde::Client rtde;
    ASSERT_TRUE(rtde.connect(ep.host, ep.port, pnp::rtde::deadlineIn(2000ms)).ok());
    ASSERT_TRUE(rtde.negotiateProtocolVersion(pnp::rtde::deadlineIn(2000ms)).ok());
    auto in = rtde.setupInputs(
        {"input_int_register_0", "input_double_register_0", "input_double_register_1",
         "input_double_register_2", "input_double_register_3", "input_double_register_4",
         "input_double_register_5"},
        pnp::rtde::deadlineIn(2000ms));
    ASSERT_TRUE(in.ok());
    ASSERT_TRUE(in->valid());
    auto out = rtde.setupOutputs(500.0, {"actual_q"}, pnp::rtde::deadlineIn(2000ms));
    ASSERT_TRUE(out.ok() && out->valid());
    ASSERT_TRUE(rtde.start(pnp::rtde::deadlineIn(2000ms)).ok());
    // Stream a target 0.1 rad away on the base joint, in small steps (the servo loop's way).
    auto home = cell.robots[0].home;
    double q0 = 0.0;
    for (int i = 0; i < 2000; ++i) {
        auto r = rtde.receive(pnp::rtde::deadlineIn(1000ms));
        ASSERT_TRUE(r.ok()) << r.status().message;
        const auto* s = std::get_if<pnp::rtde::DataSample>(&r.value());
        if (!s) continue;
        q0 = std::get<pnp::rtde::Vector6d>(s->values[0])[0];
        const double target = home[0] + std::min(0.1, 0.0005 * i);
        std::vector<pnp::rtde::Value> values{std::int32_t{1}};
        for (int k = 0; k < 6; ++k) values.emplace_back(k == 0 ? target : home[k]);
        ASSERT_TRUE(rtde.send(in->id, values, pnp::rtde::deadlineIn(1000ms)).ok());
        // The ramp stops dead at 0.25 rad/s: the robot may pass the end and come back; hold
        // the end for 150 more cycles before looking.
        if (i >= 200 + 150) break;
    }
    EXPECT_NEAR(q0, home[0] + 0.1, 1e-6);
    std::this_thread::sleep_for(50ms);  // snapshots are taken at 125 Hz
    const auto snap = sim.snapshot();
    EXPECT_NEAR(snap->robots.at(0).q[0], home[0] + 0.1, 1e-4);
}

}  // namespace

namespace {

// The whole robot chain — planner, control loop, UR hardware interface, RTDE, the simulated
// controller, the world — with every world step checked: no joint ever beyond the robot's
// speed or the controller's acceleration, a LIN's TCP never faster than asked, and a halt
// braking without a jump.
TEST(SimCellChain, LimitsHoldAtEveryWorldStep) {
    struct StepRecord {
        pnp::world::Joints q, qd;
        Eigen::Vector3d tcp;
    };
    std::mutex mutex;
    std::vector<StepRecord> steps;
    steps.reserve(20000);
    auto config = testConfig();
    config.onStep = [&](const pnp::world::World& w) {
        std::lock_guard lock(mutex);
        if (steps.size() < 20000)
            steps.push_back({w.robot(0).q, w.robot(0).qd, w.robot(0).tcp.translation()});
    };
    const auto cell = thesisCell();
    const auto& robot = cell.robots.at(0);
    Simulator sim(cell, config);
    sim.start();

    pnp::device::ur::UrConfig uc;
    uc.port = sim.endpoints().at(0).port;
    uc.model = robot.model;
    pnp::device::ur::UrHardware hardware(uc);
    pnp::robot::ControllerConfig cc;
    pnp::robot::PlannerConfig pc;
    pc.model = robot.model;
    pc.worldToBase = robot.base;
    for (int i = 0; i < 6; ++i) {
        cc.limits.maxVelocity[i] = robot.model.limits[i].maxVelocity;
        cc.limits.maxAcceleration[i] = robot.model.limits[i].maxAcceleration;
    }
    pc.defaults.joint = cc.limits;
    pnp::robot::Controller controller(hardware, cc);
    ASSERT_TRUE(controller.start(pnp::robot::Clock::now() + 5s).ok());
    pnp::robot::Planner planner(pc);
    auto run = [&](pnp::robot::Result<pnp::motion::Trajectory> plan, bool halfwayHalt) {
        ASSERT_TRUE(plan.ok()) << plan.error().message;
        auto motion = controller.execute(std::move(plan).value());
        ASSERT_TRUE(motion.ok()) << motion.error().message;
        if (halfwayHalt) {
            std::this_thread::sleep_for(400ms);
            (*motion)->halt();
        }
        auto r = (*motion)->wait(pnp::robot::Clock::now() + 20s);
        ASSERT_TRUE(r.has_value());
        EXPECT_EQ(r->end,
                  halfwayHalt ? pnp::robot::MotionEnd::kHalted : pnp::robot::MotionEnd::kCompleted)
            << r->message;
    };
    // A long PTP (the base joint at full speed), a LIN at 0.2 m/s, a PTP halted halfway.
    auto goal = controller.state()->q;
    goal[0] += 2.0;
    run(planner.jointPtp(controller.state()->q, {goal.begin(), goal.end()}, {}), false);
    pnp::robot::CartesianTarget t;
    t.pose = Eigen::Isometry3d::Identity();
    t.pose.linear() =
        Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX()).toRotationMatrix();
    t.pose.translation() = Eigen::Vector3d(-0.1, 0.4, 0.3);
    run(planner.cartesianPtp(controller.state()->q, t, {}), false);
    std::size_t linFrom = 0;
    {
        std::lock_guard lock(mutex);
        linFrom = steps.size();
    }
    t.pose.translation() = Eigen::Vector3d(0.15, 0.4, 0.3);
    pnp::robot::LinLimits lin;
    lin.maxVelocity = {0.2};
    run(planner.cartesianLinear(controller.state()->q, t, lin), false);
    std::size_t linTo = 0;
    {
        std::lock_guard lock(mutex);
        linTo = steps.size();
    }
    goal = controller.state()->q;
    goal[0] -= 2.0;
    run(planner.jointPtp(controller.state()->q, {goal.begin(), goal.end()}, {}), true);
    controller.stop();
    sim.stop();

    std::lock_guard lock(mutex);
    ASSERT_GT(steps.size(), 1000u);
    constexpr double dt = 0.002;
    for (std::size_t i = 1; i < steps.size(); ++i) {
        for (int j = 0; j < 6; ++j) {
            const double vmax = robot.model.limits[j].maxVelocity;
            const double amax = 4.0 * robot.model.limits[j].maxAcceleration;  // the controller's
            ASSERT_LE(std::abs(steps[i].qd[j]), vmax + 1e-9) << "step " << i << " joint " << j;
            ASSERT_LE(std::abs(steps[i].q[j] - steps[i - 1].q[j]), vmax * dt + 1e-9)
                << "step " << i << " joint " << j;
            ASSERT_LE(std::abs(steps[i].qd[j] - steps[i - 1].qd[j]), amax * dt + 1e-9)
                << "step " << i << " joint " << j;
        }
    }
    // The LIN's TCP speed, from the world: at most the 0.2 m/s asked (+1 % for the discrete
    // difference).
    for (std::size_t i = linFrom + 1; i < linTo && i < steps.size(); ++i)
        ASSERT_LE((steps[i].tcp - steps[i - 1].tcp).norm() / dt, 0.2 * 1.01) << "step " << i;
}

}  // namespace
