// The world's state: initial poses from the cell description, contact forces, stepping and
// snapshots.
#include "world/world.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>

#include "kinematics/kinematics.hpp"
#include "world/cell_file.hpp"

namespace pnp::world {
namespace {

const std::filesystem::path kThesisCell =
    std::filesystem::path(PNP_MODELS_DIR) / "cells" / "thesis.yaml";

CellDescription thesis() {
    Result<CellDescription> cell = loadCellFile(kThesisCell);
    if (!cell.ok()) {
        ADD_FAILURE() << cell.error().message;
        return {};
    }
    return *cell;
}

// Joints that put the flange (pointing down as at home) at `point` (world frame).
Joints flangeAt(const World& world, const Eigen::Vector3d& point) {
    const RobotDescription& r = world.description().robots.at(0);
    Eigen::Isometry3d goal = world.robot(0).flange;
    goal.translation() = point;
    auto q = kinematics::solveNearest(r.model, r.base.inverse() * goal, r.home);
    if (!q.ok()) {
        ADD_FAILURE() << q.error().message;
        return r.home;
    }
    return *q;
}

TEST(World, StartsFromTheDescription) {
    const CellDescription cell = thesis();
    ASSERT_EQ(cell.robots.size(), 1u);
    World world(cell);
    EXPECT_EQ(world.time(), 0.0);
    EXPECT_EQ(world.steps(), 0u);
    ASSERT_EQ(world.robotCount(), 1u);
    const RobotState& r = world.robot(0);
    EXPECT_EQ(r.name, "ur5");
    EXPECT_EQ(r.q, cell.robots[0].home);
    EXPECT_EQ(r.qd, Joints{});
    EXPECT_FALSE(r.tool.has_value());

    ASSERT_EQ(world.tools().size(), 3u);
    for (const ToolState& t : world.tools()) {
        EXPECT_FALSE(t.robot.has_value()) << t.name;
        EXPECT_FALSE(t.powered) << t.name;
        if (t.name == "wsg-gripper") {
            EXPECT_FALSE(t.dock.has_value()) << "on the shelf";
            continue;
        }
        ASSERT_TRUE(t.dock.has_value()) << t.name;
        EXPECT_EQ(cell.findDock(*t.dock)->tool, t.name);
    }
    ASSERT_EQ(world.objects().size(), 1u);
    EXPECT_EQ(world.objects()[0].name, "cube-green");
    EXPECT_EQ(world.objects()[0].holder, "table");
    EXPECT_TRUE(world.objects()[0].pose.isApprox(cell.objects[0].pose, 0.0));
}

TEST(World, HomeFlangeIsForwardKinematicsComposedWithTheBase) {
    const CellDescription cell = thesis();
    World world(cell);
    const RobotDescription& d = cell.robots[0];
    const Eigen::Isometry3d expected = d.base * kinematics::forward(d.model, d.home);
    EXPECT_TRUE(world.robot(0).flange.isApprox(expected, 1e-12));
    // No tool on the flange: the TCP is the flange.
    EXPECT_TRUE(world.robot(0).tcp.isApprox(expected, 1e-12));
    // Arm up, flange pointing down, well above the table: no contact.
    EXPECT_GT(expected.translation().z(), 0.2);
    EXPECT_NEAR(expected.linear().col(2).z(), -1.0, 1e-9);
    EXPECT_EQ(world.robot(0).tcpForce, Eigen::Vector3d::Zero());
}

TEST(World, ToolOnTheFlangeMovesTheTcp) {
    CellDescription cell = thesis();
    cell.robots[0].tool = "parallel-gripper";
    for (DockDescription& d : cell.docks) {
        if (d.tool == "parallel-gripper") d.tool.reset();
    }
    World world(cell);
    const RobotState& r = world.robot(0);
    ASSERT_EQ(r.tool, "parallel-gripper");
    const Eigen::Isometry3d expected = r.flange * cell.findTool("parallel-gripper")->tcp;
    EXPECT_TRUE(r.tcp.isApprox(expected, 1e-12));
    // 0.2028 m further down (the flange points down).
    EXPECT_NEAR(r.flange.translation().z() - r.tcp.translation().z(), 0.2028, 1e-9);
    for (const ToolState& t : world.tools()) {
        if (t.name == "parallel-gripper") {
            EXPECT_EQ(t.robot, "ur5");
            EXPECT_FALSE(t.dock.has_value());
        } else if (t.name == "vacuum-gripper") {
            EXPECT_EQ(t.dock, "dock-1");
            EXPECT_FALSE(t.robot.has_value());
        }
    }
}

TEST(World, SetJointsUpdatesThePosesAtOnce) {
    World world(thesis());
    const RobotDescription& d = world.description().robots[0];
    Joints q = d.home;
    q[0] += 0.3;
    q[4] -= 0.2;
    const Joints qd{0.1, 0, 0, 0, -0.1, 0};
    EXPECT_TRUE(world.setJoints(0, q, qd));
    EXPECT_EQ(world.robot(0).q, q);
    EXPECT_EQ(world.robot(0).qd, qd);
    EXPECT_TRUE(world.robot(0).flange.isApprox(d.base * kinematics::forward(d.model, q), 1e-12));
}

TEST(World, SetJointsRejectsNonFiniteAndClampsToTheLimits) {
    World world(thesis());
    const Joints home = world.robot(0).q;
    Joints bad = home;
    bad[2] = std::numeric_limits<double>::quiet_NaN();
    EXPECT_FALSE(world.setJoints(0, bad, Joints{}));
    EXPECT_EQ(world.robot(0).q, home);
    Joints fast{};
    fast[1] = std::numeric_limits<double>::infinity();
    EXPECT_FALSE(world.setJoints(0, home, fast));
    EXPECT_EQ(world.robot(0).q, home);

    Joints beyond = home;
    beyond[0] = 7.0;  // limit 2π
    EXPECT_TRUE(world.setJoints(0, beyond, Joints{1, 1, 1, 1, 1, 1}));
    EXPECT_EQ(world.robot(0).q[0], world.description().robots[0].model.limits[0].maxPosition);
    EXPECT_EQ(world.robot(0).qd[0], 0.0);
    EXPECT_EQ(world.robot(0).qd[1], 1.0);

    EXPECT_THROW(world.setJoints(1, home, Joints{}), std::out_of_range);
}

TEST(World, ContactForceOfATcpOneMillimetreIntoTheTable) {
    World world(thesis());
    ASSERT_TRUE(world.setJoints(0, flangeAt(world, {0.1, -0.1, -0.001}), Joints{}));
    world.step(0.002);
    const RobotState& r = world.robot(0);
    ASSERT_NEAR(r.tcp.translation().z(), -0.001, 1e-12);
    EXPECT_NEAR(r.tcpForce.x(), 0.0, 1e-9);
    EXPECT_NEAR(r.tcpForce.y(), 0.0, 1e-9);
    EXPECT_NEAR(r.tcpForce.z(), 20.0, 1e-9);

    // 1 mm above: no force.
    ASSERT_TRUE(world.setJoints(0, flangeAt(world, {0.1, -0.1, 0.001}), Joints{}));
    world.step(0.002);
    EXPECT_EQ(world.robot(0).tcpForce, Eigen::Vector3d::Zero());
}

TEST(World, ContactForceOnTopFacesAndItsLimits) {
    World world(thesis());
    // Table top at z = 0, 1.0 x 0.8 x 0.75 centred at the origin.
    EXPECT_NEAR(world.contactForceAt({0.3, 0.3, -0.002}).z(), 40.0, 1e-9);
    EXPECT_EQ(world.contactForceAt({0.3, 0.3, 0.0}), Eigen::Vector3d::Zero());    // touching
    EXPECT_EQ(world.contactForceAt({0.6, 0.0, -0.01}), Eigen::Vector3d::Zero());  // beside
    EXPECT_EQ(world.contactForceAt({0.0, 0.0, -0.80}), Eigen::Vector3d::Zero());  // below
    EXPECT_NEAR(world.contactForceAt({0.0, 0.0, -0.5}).z(), 2000.0, 1e-9);        // saturated
    // The cube (centre 0.05, 0.10, 0.02; 4 cm): its top face is at z = 0.04.
    EXPECT_NEAR(world.contactForceAt({0.05, 0.10, 0.039}).z(), 20.0, 1e-9);
    EXPECT_NEAR(world.contactForceAt({0.065, 0.115, 0.035}).z(), 100.0, 1e-9);
    EXPECT_EQ(world.contactForceAt({0.05, 0.10, 0.041}), Eigen::Vector3d::Zero());
    // Under the cube, in the table: the table's face (a point in two bodies takes the deepest
    // face whose body holds it; the cube ends at z = 0).
    EXPECT_NEAR(world.contactForceAt({0.05, 0.10, -0.001}).z(), 20.0, 1e-9);

    WorldConfig soft;
    soft.contactStiffness = 1000.0;
    soft.maxContactForce = 5.0;
    World other(thesis(), soft);
    EXPECT_NEAR(other.contactForceAt({0.3, 0.3, -0.002}).z(), 2.0, 1e-12);
    EXPECT_NEAR(other.contactForceAt({0.3, 0.3, -0.2}).z(), 5.0, 1e-12);
}

TEST(World, StepAdvancesTimeAndIgnoresABadDt) {
    World world(thesis());
    for (int i = 0; i < 500; ++i) world.step(0.002);
    EXPECT_EQ(world.steps(), 500u);
    EXPECT_NEAR(world.time(), 1.0, 1e-12);
    const double t = world.time();
    world.step(std::numeric_limits<double>::quiet_NaN());
    world.step(std::numeric_limits<double>::infinity());
    world.step(-1.0);
    world.step(0.0);  // a refresh
    EXPECT_EQ(world.time(), t);
    EXPECT_EQ(world.steps(), 500u);
}

TEST(World, SnapshotIsACopy) {
    World world(thesis());
    world.step(0.002);
    const Snapshot before = world.snapshot();
    EXPECT_EQ(before.time, world.time());
    EXPECT_EQ(before.step, 1u);
    ASSERT_EQ(before.robots.size(), 1u);
    EXPECT_EQ(before.robots[0].q, world.robot(0).q);
    EXPECT_TRUE(before.robots[0].flange.isApprox(world.robot(0).flange, 0.0));
    EXPECT_EQ(before.objects.size(), world.objects().size());
    EXPECT_EQ(before.tools.size(), world.tools().size());

    Joints q = world.robot(0).q;
    q[0] += 0.5;
    ASSERT_TRUE(world.setJoints(0, q, Joints{}));
    world.step(0.002);
    EXPECT_EQ(before.step, 1u);
    EXPECT_NE(before.robots[0].q, world.robot(0).q);
    EXPECT_EQ(before.robots[0].q, world.description().robots[0].home);
    EXPECT_FALSE(before.robots[0].flange.isApprox(world.robot(0).flange, 1e-6));
}

TEST(World, SameCallsSameStateBitForBit) {
    auto run = [] {
        World world(thesis());
        Joints q = world.robot(0).q;
        std::vector<double> trace;
        for (int i = 0; i < 300; ++i) {
            q[0] += 0.001;
            q[1] -= 0.0007;
            world.setJoints(0, q, Joints{0.5, -0.35, 0, 0, 0, 0});
            world.step(0.002);
            const RobotState& r = world.robot(0);
            for (int k = 0; k < 16; ++k) trace.push_back(r.tcp.matrix().data()[k]);
            for (int k = 0; k < 3; ++k) trace.push_back(r.tcpForce[k]);
        }
        return trace;
    };
    const std::vector<double> a = run();
    const std::vector<double> b = run();
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(double)), 0);
}

}  // namespace
}  // namespace pnp::world
