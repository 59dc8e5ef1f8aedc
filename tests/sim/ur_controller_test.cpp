// The simulated UR controller without the network: the servo program driven by write() and
// step() directly, as the RTDE server and the simulator's loop do.
#include "sim/ur/ur_controller.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

#include "sim_helpers.hpp"

namespace pnp::sim::ur::test {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kEps = 1e-12;

// World + controller, stepped by hand.
struct Rig {
    explicit Rig(UrControllerConfig config = {}) : world(thesisCell()), ur(world, config) {
        const auto& limits = world.description().robots[0].model.limits;
        for (std::size_t j = 0; j < 6; ++j) {
            vmax[j] = config.maxVelocity > 0 ? config.maxVelocity : limits[j].maxVelocity;
            amax[j] =
                config.maxAcceleration > 0 ? config.maxAcceleration : 4 * limits[j].maxAcceleration;
        }
    }
    void send(std::int32_t mode, const Joints& targets) {
        ur.write("input_int_register_0", mode);
        for (std::size_t j = 0; j < 6; ++j) {
            ur.write("input_double_register_" + std::to_string(j), targets[j]);
        }
    }
    // One control period; checks the limits of the step on the way.
    void tick() {
        const Joints q0 = world.robot(0).q;
        const Joints v0 = world.robot(0).qd;
        ur.step(kDt);
        world.step(kDt);
        ur.publish();
        const Joints& q = world.robot(0).q;
        const Joints& v = world.robot(0).qd;
        for (std::size_t j = 0; j < 6; ++j) {
            ASSERT_LE(std::abs(v[j]), vmax[j] + kEps) << "joint " << j;
            ASSERT_LE(std::abs(q[j] - q0[j]), vmax[j] * kDt + kEps) << "joint " << j;
            ASSERT_LE(std::abs(v[j] - v0[j]), amax[j] * kDt + 1e-9) << "joint " << j;
        }
    }
    bool atRest() const { return world.robot(0).qd == Joints{}; }
    Joints home() const { return world.description().robots[0].home; }

    world::World world;
    UrController ur;
    Joints vmax{};
    Joints amax{};
};

Joints offset(Joints q, const Joints& d) {
    for (std::size_t j = 0; j < 6; ++j) q[j] += d[j];
    return q;
}

TEST(UrController, OutputsAtStart) {
    Rig rig;
    const Joints home = rig.home();
    EXPECT_EQ(std::get<std::int32_t>(rig.ur.read("robot_mode")), 7);
    EXPECT_EQ(std::get<std::int32_t>(rig.ur.read("safety_mode")), 1);
    EXPECT_EQ(std::get<std::uint32_t>(rig.ur.read("runtime_state")), 2u);
    EXPECT_EQ(std::get<double>(rig.ur.read("timestamp")), 0.0);
    EXPECT_EQ(std::get<rtde::Vector6d>(rig.ur.read("actual_q")), home);
    EXPECT_EQ(std::get<rtde::Vector6d>(rig.ur.read("target_q")), home);
    EXPECT_EQ(std::get<rtde::Vector6d>(rig.ur.read("tcp_offset")), rtde::Vector6d{});
    EXPECT_EQ(std::get<rtde::Vector6d>(rig.ur.read("actual_TCP_force")), rtde::Vector6d{});

    // The TCP pose in the base frame, rotation vector: FK of home (the flange: no offset).
    const auto pose = std::get<rtde::Vector6d>(rig.ur.read("actual_TCP_pose"));
    const Eigen::Isometry3d fk = kinematics::forward(rig.world.description().robots[0].model, home);
    const Eigen::Vector3d p(pose[0], pose[1], pose[2]);
    const Eigen::Vector3d r(pose[3], pose[4], pose[5]);
    EXPECT_TRUE(p.isApprox(fk.translation(), 1e-12));
    const Eigen::Matrix3d rotation = Eigen::AngleAxisd(r.norm(), r.normalized()).toRotationMatrix();
    EXPECT_TRUE(rotation.isApprox(fk.linear(), 1e-12));
    EXPECT_EQ(std::get<rtde::Vector6d>(rig.ur.read("target_TCP_pose")), pose);

    rig.tick();
    EXPECT_EQ(std::get<double>(rig.ur.read("timestamp")), kDt);
    EXPECT_FALSE(rig.ur.following());
    EXPECT_TRUE(rig.atRest());
}

TEST(UrController, RegistersAndUnknownNames) {
    Rig rig;
    // Inputs are kept as written and readable; wrong types and unknown names are ignored.
    rig.ur.write("input_int_register_7", std::int32_t{42});
    rig.ur.write("input_int_register_8", 1.5);
    rig.ur.write("no_such_variable", std::int32_t{1});
    rig.ur.write("actual_q", rtde::Vector6d{1, 1, 1, 1, 1, 1});  // an output: not writable
    EXPECT_EQ(std::get<std::int32_t>(*rig.ur.input("input_int_register_7")), 42);
    EXPECT_EQ(std::get<std::int32_t>(*rig.ur.input("input_int_register_8")), 0);
    EXPECT_EQ(std::get<std::int32_t>(rig.ur.read("input_int_register_7")), 42);
    EXPECT_FALSE(rig.ur.input("no_such_variable").has_value());
    EXPECT_EQ(std::get<rtde::Vector6d>(rig.ur.read("actual_q")), rig.home());
    // Output registers echo what was set (as a script's write_output_*_register).
    EXPECT_TRUE(rig.ur.setOutputRegister("output_double_register_3", 2.5));
    EXPECT_TRUE(rig.ur.setOutputRegister("output_int_register_30", std::int32_t{-4}));
    EXPECT_TRUE(rig.ur.setOutputRegister("output_bit_registers0_to_31", std::uint32_t{5}));
    EXPECT_FALSE(rig.ur.setOutputRegister("output_double_register_3", std::int32_t{1}));
    EXPECT_FALSE(rig.ur.setOutputRegister("actual_q", rtde::Vector6d{}));
    EXPECT_EQ(std::get<double>(rig.ur.read("output_double_register_3")), 2.5);
    EXPECT_EQ(std::get<std::int32_t>(rig.ur.read("output_int_register_30")), -4);
    EXPECT_EQ(std::get<std::uint32_t>(rig.ur.read("output_bit_registers0_to_31")), 5u);
    // Everything else of the catalogue reads as a zero of its type.
    for (const rtde::Variable& v : rtde::catalogue()) {
        EXPECT_EQ(rtde::typeOf(rig.ur.read(v.name)), v.type) << v.name;
    }
}

TEST(UrController, RejectsABadConfiguration) {
    world::World world(thesisCell());
    UrControllerConfig c;
    c.robot = 1;
    EXPECT_THROW((UrController{world, c}), std::out_of_range);
    c = {};
    c.watchdogTimeout = 0.0;
    EXPECT_THROW((UrController{world, c}), std::invalid_argument);
    c = {};
    c.maxVelocity = kNaN;
    EXPECT_THROW((UrController{world, c}), std::invalid_argument);
}

TEST(UrController, ServoReachesTheTargetWithoutOvershoot) {
    Rig rig;
    const Joints start = rig.home();
    const Joints target = offset(start, {0.5, -0.3, 0.2, 0.1, -0.4, 0.6});
    for (int i = 0; i < 2000 && !(rig.world.robot(0).q == target && rig.atRest()); ++i) {
        rig.send(1, target);
        ASSERT_NO_FATAL_FAILURE(rig.tick());
        for (std::size_t j = 0; j < 6; ++j) {
            const double travelled = (rig.world.robot(0).q[j] - start[j]);
            ASSERT_LE(std::abs(travelled), std::abs(target[j] - start[j]) + kEps) << j;
            ASSERT_GE(travelled * (target[j] - start[j]), 0.0) << j;
        }
    }
    EXPECT_TRUE(rig.ur.following());
    for (std::size_t j = 0; j < 6; ++j) EXPECT_NEAR(rig.world.robot(0).q[j], target[j], kEps);
    EXPECT_TRUE(rig.atRest());
    // 0.6 rad at π rad/s and 4π rad/s²: about 0.44 s; surely within 1 s.
    EXPECT_LE(rig.world.time(), 1.0);
}

TEST(UrController, BadTargetsAreRejectedWhole) {
    Rig rig;
    const Joints home = rig.home();
    const std::vector<Joints> bad = {
        offset(home, {0.1, 0.1, kNaN, 0.1, 0.1, 0.1}),
        offset(home, {0.1, 0.1, 0.1, 0.1, 0.1, std::numeric_limits<double>::infinity()}),
        {7.0, home[1], home[2], home[3], home[4], home[5]},  // beyond +2π
        {0.1, -7.0, 0.1, 0.1, 0.1, 0.1},
    };
    std::uint64_t rejected = 0;
    for (const Joints& b : bad) {
        for (int i = 0; i < 50; ++i) {
            rig.send(1, b);
            ASSERT_NO_FATAL_FAILURE(rig.tick());
            ASSERT_EQ(rig.world.robot(0).q, home);
            ASSERT_TRUE(rig.atRest());
        }
        EXPECT_GT(rig.ur.rejectedTargets(), rejected);
        rejected = rig.ur.rejectedTargets();
    }
    EXPECT_TRUE(rig.ur.following());

    // A good target moves it; a bad one on the way keeps the good one.
    const Joints good = offset(home, {0.2, 0, 0, 0, 0, 0});
    rig.send(1, good);
    for (int i = 0; i < 20; ++i) ASSERT_NO_FATAL_FAILURE(rig.tick());
    EXPECT_GT(rig.world.robot(0).q[0], home[0]);
    for (int i = 0; i < 1000 && !rig.atRest(); ++i) {
        rig.send(1, bad[0]);
        ASSERT_NO_FATAL_FAILURE(rig.tick());
    }
    for (std::size_t j = 0; j < 6; ++j) EXPECT_NEAR(rig.world.robot(0).q[j], good[j], kEps);
}

TEST(UrController, RegisterZeroStopsByDeceleration) {
    Rig rig;
    const Joints target = offset(rig.home(), {1.5, 0, 0, 0, 0, 0});
    for (int i = 0; i < 150; ++i) {
        rig.send(1, target);
        ASSERT_NO_FATAL_FAILURE(rig.tick());
    }
    const double speed = rig.world.robot(0).qd[0];
    ASSERT_GT(speed, 1.0);
    int steps = 0;
    for (; steps < 1000 && !rig.atRest(); ++steps) {
        const double before = rig.world.robot(0).qd[0];
        rig.send(0, target);
        ASSERT_NO_FATAL_FAILURE(rig.tick());
        ASSERT_LE(rig.world.robot(0).qd[0], before);  // never speeds up, never reverses
        ASSERT_GE(rig.world.robot(0).qd[0], 0.0);
    }
    EXPECT_TRUE(rig.atRest());
    EXPECT_FALSE(rig.ur.following());
    // Braking at 4π rad/s²: speed / a seconds, one step of rounding.
    EXPECT_LE(steps, static_cast<int>(std::ceil(speed / rig.amax[0] / kDt)) + 1);
    const Joints rest = rig.world.robot(0).q;
    for (int i = 0; i < 100; ++i) {
        rig.send(0, target);
        ASSERT_NO_FATAL_FAILURE(rig.tick());
    }
    EXPECT_EQ(rig.world.robot(0).q, rest);
}

TEST(UrController, WatchdogStopsAndWaitsForARearm) {
    UrControllerConfig config;
    config.watchdogTimeout = 0.1;  // 50 steps
    Rig rig(config);
    // Not armed before the register has been 1: silence alone does nothing.
    for (int i = 0; i < 200; ++i) ASSERT_NO_FATAL_FAILURE(rig.tick());
    EXPECT_FALSE(rig.ur.watchdogTripped());

    const Joints target = offset(rig.home(), {1.5, -0.5, 0, 0, 0, 0});
    for (int i = 0; i < 150; ++i) {
        rig.send(1, target);
        ASSERT_NO_FATAL_FAILURE(rig.tick());
    }
    ASSERT_GT(std::abs(rig.world.robot(0).qd[0]), 1.0);
    // Silence: 49 steps still follow, the 50th trips.
    for (int i = 0; i < 49; ++i) ASSERT_NO_FATAL_FAILURE(rig.tick());
    EXPECT_FALSE(rig.ur.watchdogTripped());
    EXPECT_TRUE(rig.ur.following());
    ASSERT_NO_FATAL_FAILURE(rig.tick());
    EXPECT_TRUE(rig.ur.watchdogTripped());
    EXPECT_FALSE(rig.ur.following());
    for (int i = 0; i < 1000 && !rig.atRest(); ++i) ASSERT_NO_FATAL_FAILURE(rig.tick());
    ASSERT_TRUE(rig.atRest());
    const Joints rest = rig.world.robot(0).q;

    // Inputs again with the register still 1: ignored.
    const Joints other = offset(rig.home(), {-0.5, 0, 0, 0, 0, 0});
    for (int i = 0; i < 100; ++i) {
        rig.send(1, other);
        ASSERT_NO_FATAL_FAILURE(rig.tick());
    }
    EXPECT_EQ(rig.world.robot(0).q, rest);
    EXPECT_TRUE(rig.ur.watchdogTripped());
    // Re-arm: 0, then 1.
    rig.send(0, other);
    ASSERT_NO_FATAL_FAILURE(rig.tick());
    EXPECT_EQ(rig.world.robot(0).q, rest);
    rig.send(1, other);
    ASSERT_NO_FATAL_FAILURE(rig.tick());
    EXPECT_FALSE(rig.ur.watchdogTripped());
    EXPECT_TRUE(rig.ur.following());
    for (int i = 0; i < 2000 && !(rig.world.robot(0).q == other && rig.atRest()); ++i) {
        rig.send(1, other);
        ASSERT_NO_FATAL_FAILURE(rig.tick());
    }
    for (std::size_t j = 0; j < 6; ++j) EXPECT_NEAR(rig.world.robot(0).q[j], other[j], kEps);
}

TEST(UrController, RearmWithinOneStepCounts) {
    // 0 then 1 written between two steps: the controller saw the 0 (the latch keeps it).
    UrControllerConfig config;
    config.watchdogTimeout = 0.02;
    Rig rig(config);
    const Joints target = offset(rig.home(), {0.3, 0, 0, 0, 0, 0});
    rig.send(1, target);
    for (int i = 0; i < 30; ++i) ASSERT_NO_FATAL_FAILURE(rig.tick());
    ASSERT_TRUE(rig.ur.watchdogTripped());
    rig.send(0, target);
    rig.send(1, target);
    ASSERT_NO_FATAL_FAILURE(rig.tick());
    EXPECT_FALSE(rig.ur.watchdogTripped());
    EXPECT_TRUE(rig.ur.following());
}

TEST(UrController, ProtectiveStopOnContact) {
    world::CellDescription cell = thesisCell();
    // Start 5 mm above the table, flange down, away from the cube.
    cell.robots[0].home = flangeAt(cell, {0.1, -0.1, 0.005}, cell.robots[0].home);
    world::World world(cell);
    std::vector<std::string> log;
    UrControllerConfig config;
    config.log = [&](const std::string& line) { log.push_back(line); };
    UrController ur(world, config);
    const Joints start = world.robot(0).q;
    bool stopped = false;
    // Down at 2 cm/s: contact after 0.25 s, 250 N (12.5 mm) after another 0.63 s.
    for (int i = 1; i <= 2000 && !stopped; ++i) {
        const Joints t = flangeAt(cell, {0.1, -0.1, 0.005 - 0.02 * kDt * i}, start);
        ur.write("input_int_register_0", std::int32_t{1});
        for (std::size_t j = 0; j < 6; ++j) {
            ur.write("input_double_register_" + std::to_string(j), t[j]);
        }
        ur.step(kDt);
        world.step(kDt);
        ur.publish();
        stopped = ur.protectiveStop();
    }
    ASSERT_TRUE(stopped);
    EXPECT_GT(world.robot(0).tcpForce.norm(), 250.0);
    EXPECT_EQ(std::get<std::int32_t>(ur.read("safety_mode")), 3);
    EXPECT_NEAR(std::get<rtde::Vector6d>(ur.read("actual_TCP_force"))[2],
                world.robot(0).tcpForce.z(), 1e-9);
    EXPECT_FALSE(ur.following());
    // The operator is told once, with the force and where (the table's normal: +z).
    ASSERT_EQ(log.size(), 1u);
    EXPECT_EQ(log[0].rfind("ur5: protective stop: TCP force 2", 0), 0u) << log[0];
    EXPECT_NE(log[0].find("> 250.0 N at TCP (0.1"), std::string::npos) << log[0];
    // Comes to rest; targets (even re-armed, while still pressed) are ignored.
    for (int i = 0; i < 500; ++i) {
        ur.write("input_int_register_0", std::int32_t{i % 2});
        ur.step(kDt);
        world.step(kDt);
        ur.publish();
    }
    EXPECT_EQ(world.robot(0).qd, Joints{});
    EXPECT_TRUE(ur.protectiveStop());
    EXPECT_EQ(std::get<std::int32_t>(ur.read("safety_mode")), 3);
    // Not far into the table: the stop came within a few steps.
    EXPECT_GT(world.robot(0).tcp.translation().z(), -0.014);
    EXPECT_EQ(log.size(), 1u);  // still in the stop: nothing more told
}

// The servo program for a scripted input sequence; returns every step's joints and speeds.
std::vector<double> scriptedRun() {
    world::World world(thesisCell());
    UrControllerConfig config;
    config.watchdogTimeout = 0.05;
    UrController ur(world, config);
    const Joints home = world.robot(0).q;
    std::vector<double> trace;
    auto write = [&](std::int32_t mode, const Joints& t) {
        ur.write("input_int_register_0", mode);
        for (std::size_t j = 0; j < 6; ++j) {
            ur.write("input_double_register_" + std::to_string(j), t[j]);
        }
    };
    for (int i = 0; i < 3000; ++i) {
        const double s = 0.001 * i;
        Joints t = offset(home, {std::sin(s) * 0.8, 0.3 * s, -0.2 * s, 0.1, -0.1, std::cos(s)});
        if (i % 97 == 5) t[3] = kNaN;
        if (i < 1000) {
            write(1, t);
        } else if (i < 1200) {
            // silence: the watchdog trips
        } else if (i == 1200) {
            write(0, t);
        } else if (i < 2000) {
            write(1, t);
        } else if (i < 2100) {
            write(0, t);
        } else if (i % 3 != 0) {  // sparse inputs, within the watchdog
            write(1, t);
        }
        ur.step(kDt);
        world.step(kDt);
        ur.publish();
        const world::RobotState& r = world.robot(0);
        trace.insert(trace.end(), r.q.begin(), r.q.end());
        trace.insert(trace.end(), r.qd.begin(), r.qd.end());
        const auto pose = std::get<rtde::Vector6d>(ur.read("actual_TCP_pose"));
        trace.insert(trace.end(), pose.begin(), pose.end());
    }
    return trace;
}

TEST(UrController, SameInputsSameTrajectoryBitForBit) {
    const std::vector<double> a = scriptedRun();
    const std::vector<double> b = scriptedRun();
    ASSERT_EQ(a.size(), b.size());
    ASSERT_EQ(a.size(), 3000u * 18u);
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(double)), 0);
    // And it did move (the script is not a no-op).
    EXPECT_NE(a[0], a[a.size() - 18]);
}

}  // namespace
}  // namespace pnp::sim::ur::test
