// The world's tools: the Kelvin changer locked only by the robot's turn in a dock, tool power,
// grip physics (an object between the fingers, a cup sealed on a face, held objects
// following the grip point, released ones resting on what is below) and operator actions.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "kinematics/kinematics.hpp"
#include "world/cell_file.hpp"
#include "world/world.hpp"

namespace pnp::world {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDt = 0.002;

CellDescription thesis() {
    auto cell = loadCellFile(std::filesystem::path(PNP_MODELS_DIR) / "cells" / "thesis.yaml");
    if (!cell.ok()) {
        ADD_FAILURE() << cell.error().message;
        return {};
    }
    return *cell;
}

std::size_t toolIndex(const World& world, const std::string& name) {
    for (std::size_t i = 0; i < world.tools().size(); ++i)
        if (world.tools()[i].name == name) return i;
    ADD_FAILURE() << "no tool " << name;
    return 0;
}

std::size_t objectIndex(const World& world, const std::string& name) {
    for (std::size_t i = 0; i < world.objects().size(); ++i)
        if (world.objects()[i].name == name) return i;
    ADD_FAILURE() << "no object " << name;
    return 0;
}

Eigen::Isometry3d turned(Eigen::Isometry3d pose, double angle) {
    pose.rotate(Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()));
    return pose;
}

Eigen::Isometry3d raised(Eigen::Isometry3d pose, double dz) {
    pose.translation().z() += dz;
    return pose;
}

// Puts robot 0's flange at `goal` (world frame) and steps the world once.
void moveFlange(World& world, const Eigen::Isometry3d& goal) {
    const RobotDescription& r = world.description().robots.at(0);
    auto q = kinematics::solveNearest(r.model, r.base.inverse() * goal, world.robot(0).q);
    ASSERT_TRUE(q.ok()) << q.error().message;
    ASSERT_TRUE(world.setJoints(0, *q, {}));
    world.step(kDt);
    ASSERT_LT((world.robot(0).flange.translation() - goal.translation()).norm(), 1e-6);
}

// Turns the flange about its z axis from `from` to `to` (rad, relative to `dock`) in steps
// of 1°, recording the changer states seen.
std::vector<ChangerLock> turn(World& world, const Eigen::Isometry3d& dock, double from, double to) {
    std::vector<ChangerLock> seen;
    const int n = static_cast<int>(std::ceil(std::abs(to - from) / (kPi / 180.0)));
    for (int i = 0; i <= n; ++i) {
        moveFlange(world, turned(dock, from + (to - from) * i / n));
        if (seen.empty() || seen.back() != world.robot(0).changer)
            seen.push_back(world.robot(0).changer);
    }
    return seen;
}

TEST(WorldChanger, AttachAndDetachByTurningInTheDock) {
    World world(thesis());
    const double lock = WorldConfig{}.lockAngle;
    const DockDescription& dock = *world.description().findDock("dock-2");
    const std::size_t gripper = toolIndex(world, "parallel-gripper");
    EXPECT_EQ(world.robot(0).changer, ChangerLock::kOpen);
    EXPECT_EQ(world.robot(0).changerVoltage, 0.0);
    EXPECT_FALSE(world.toolPowered(gripper));

    // Approach above, go down at the open angle: in the dock, still open, nothing attached.
    moveFlange(world, raised(turned(dock.pose, -lock), 0.10));
    EXPECT_FALSE(world.robot(0).dock.has_value());
    moveFlange(world, turned(dock.pose, -lock));
    EXPECT_EQ(world.robot(0).dock, "dock-2");
    EXPECT_EQ(world.robot(0).changer, ChangerLock::kOpen);

    // The turn: open -> intermediate (2.1 V) -> locked with tool 1 (5.7 V).
    EXPECT_EQ(turn(world, dock.pose, -lock, 0.0),
              (std::vector<ChangerLock>{ChangerLock::kOpen, ChangerLock::kIntermediate,
                                        ChangerLock::kLocked}));
    EXPECT_EQ(world.robot(0).tool, "parallel-gripper");
    EXPECT_DOUBLE_EQ(world.robot(0).changerVoltage, 5.7);
    EXPECT_TRUE(world.toolPowered(gripper));
    EXPECT_EQ(world.tools()[gripper].robot, "ur5");
    EXPECT_FALSE(world.tools()[gripper].dock.has_value());

    // Leaving: the tool comes along, its grip point 0.2028 m out of the flange.
    moveFlange(world, raised(dock.pose, 0.10));
    const auto grip = world.gripPoint(gripper);
    ASSERT_TRUE(grip.has_value());
    EXPECT_NEAR(
        (grip->translation() - world.robot(0).flange * Eigen::Vector3d(0, 0, 0.2028)).norm(), 0.0,
        1e-9);
    EXPECT_NEAR((world.robot(0).tcp.translation() - grip->translation()).norm(), 0.0, 1e-9);

    // Back into the (now empty) dock, turn back: the tool stays there, unpowered.
    moveFlange(world, dock.pose);
    EXPECT_EQ(turn(world, dock.pose, 0.0, -lock),
              (std::vector<ChangerLock>{ChangerLock::kLocked, ChangerLock::kIntermediate,
                                        ChangerLock::kOpen}));
    EXPECT_FALSE(world.robot(0).tool.has_value());
    EXPECT_EQ(world.tools()[gripper].dock, "dock-2");
    EXPECT_FALSE(world.toolPowered(gripper));
    EXPECT_EQ(world.robot(0).changerVoltage, 0.0);
    moveFlange(world, raised(turned(dock.pose, -lock), 0.10));
    EXPECT_EQ(world.tools()[gripper].dock, "dock-2");
}

TEST(WorldChanger, NoLockWithoutTheTurnOrOutsideADock) {
    World world(thesis());
    const double lock = WorldConfig{}.lockAngle;
    const DockDescription& dock = *world.description().findDock("dock-1");
    // Entering at the locked angle does not engage the cam: it stays open, nothing attached.
    moveFlange(world, raised(dock.pose, 0.10));
    moveFlange(world, dock.pose);
    EXPECT_EQ(world.robot(0).changer, ChangerLock::kOpen);
    EXPECT_FALSE(world.robot(0).tool.has_value());
    // 5 mm off the dock: the same turn does nothing.
    Eigen::Isometry3d off = dock.pose;
    off.translation().x() += 0.005;
    moveFlange(world, raised(turned(off, -lock), 0.05));
    moveFlange(world, turned(off, -lock));
    turn(world, off, -lock, 0.0);
    EXPECT_EQ(world.robot(0).changer, ChangerLock::kOpen);
    EXPECT_FALSE(world.robot(0).tool.has_value());
    EXPECT_EQ(world.tools()[toolIndex(world, "vacuum-gripper")].dock, "dock-1");
}

TEST(WorldChanger, LockedInAnEmptyDockSaysNoTool) {
    World world(thesis());
    const double lock = WorldConfig{}.lockAngle;
    ASSERT_EQ(world.takeToolOut("vacuum-gripper"), "");
    const DockDescription& dock = *world.description().findDock("dock-1");
    moveFlange(world, turned(dock.pose, -lock));
    turn(world, dock.pose, -lock, 0.0);
    EXPECT_EQ(world.robot(0).changer, ChangerLock::kLocked);
    EXPECT_FALSE(world.robot(0).tool.has_value());
    EXPECT_DOUBLE_EQ(world.robot(0).changerVoltage, 4.9);
}

TEST(WorldChanger, Voltages) {
    EXPECT_EQ(World::changerVoltage(ChangerLock::kOpen, 3), 0.0);
    EXPECT_EQ(World::changerVoltage(ChangerLock::kIntermediate, 3), 2.1);
    EXPECT_EQ(World::changerVoltage(ChangerLock::kLocked, 0), 4.9);
    EXPECT_EQ(World::changerVoltage(ChangerLock::kLocked, 1), 5.7);
    EXPECT_EQ(World::changerVoltage(ChangerLock::kLocked, 10), 14.1);
}

// A cell whose robot starts with `tool` locked on its flange.
World withTool(const std::string& tool) {
    CellDescription cell = thesis();
    for (DockDescription& d : cell.docks)
        if (d.tool == tool) d.tool.reset();
    cell.robots[0].tool = tool;
    return World(cell);
}

// The flange pose (pointing down) that puts `tool`'s grip point at `point`.
Eigen::Isometry3d flangeForGrip(const World& world, const std::string& tool,
                                const Eigen::Vector3d& point) {
    Eigen::Isometry3d flange = world.robot(0).flange;
    const Eigen::Isometry3d grip = flange * world.description().findTool(tool)->tcp;
    flange.translation() += point - grip.translation();
    return flange;
}

TEST(WorldGrip, ParallelFingersFindTheCubeOnlyAroundIt) {
    World world = withTool("parallel-gripper");
    const std::size_t g = toolIndex(world, "parallel-gripper");
    EXPECT_TRUE(world.toolPowered(g));
    EXPECT_EQ(world.robot(0).changer, ChangerLock::kLocked);
    const std::size_t cube = objectIndex(world, "cube-green");
    const Eigen::Vector3d centre = world.objects()[cube].pose.translation();

    // Empty air above the cube: nothing between the fingers.
    moveFlange(world,
               flangeForGrip(world, "parallel-gripper", centre + Eigen::Vector3d(0, 0, 0.05)));
    EXPECT_FALSE(world.objectBetweenFingers(g, 0.085).has_value());
    // Around the cube: found, 4 cm wide; not with the fingers open only 3 cm.
    moveFlange(world, flangeForGrip(world, "parallel-gripper", centre));
    auto contact = world.objectBetweenFingers(g, 0.085);
    ASSERT_TRUE(contact.has_value());
    EXPECT_EQ(contact->object, cube);
    EXPECT_NEAR(contact->width, 0.04, 1e-9);
    EXPECT_FALSE(world.objectBetweenFingers(g, 0.03).has_value());
    // 3 cm beside it: the fingers' line misses it.
    moveFlange(world,
               flangeForGrip(world, "parallel-gripper", centre + Eigen::Vector3d(0, 0.03, 0)));
    EXPECT_FALSE(world.objectBetweenFingers(g, 0.085).has_value());
}

TEST(WorldGrip, AHeldObjectFollowsAndRestsWhereReleased) {
    World world = withTool("parallel-gripper");
    const std::size_t g = toolIndex(world, "parallel-gripper");
    const std::size_t cube = objectIndex(world, "cube-green");
    const Eigen::Vector3d centre = world.objects()[cube].pose.translation();
    moveFlange(world, flangeForGrip(world, "parallel-gripper", centre));
    ASSERT_TRUE(world.hold(g, cube));
    EXPECT_EQ(world.held(g), cube);
    EXPECT_EQ(world.objects()[cube].holder, "parallel-gripper");
    EXPECT_TRUE(world.hold(g, cube)) << "holding what it holds is no change";

    // Lift and carry it to the thesis's place position (-0.05, -0.10), 3 cm above the table.
    const Eigen::Vector3d place(-0.05, -0.10, 0.02);
    moveFlange(world,
               flangeForGrip(world, "parallel-gripper", centre + Eigen::Vector3d(0, 0, 0.05)));
    EXPECT_NEAR(world.objects()[cube].pose.translation().z(), centre.z() + 0.05, 1e-9);
    moveFlange(world,
               flangeForGrip(world, "parallel-gripper", place + Eigen::Vector3d(0, 0, 0.03)));
    EXPECT_NEAR(
        (world.objects()[cube].pose.translation() - (place + Eigen::Vector3d(0, 0, 0.03))).norm(),
        0.0, 1e-9);
    // Released, it drops onto the table: centre 2 cm above it, upright.
    world.release(g);
    EXPECT_FALSE(world.held(g).has_value());
    EXPECT_EQ(world.objects()[cube].holder, "table");
    EXPECT_NEAR((world.objects()[cube].pose.translation() - place).norm(), 0.0, 1e-9);
    EXPECT_NEAR(world.objects()[cube].pose.linear().col(2).z(), 1.0, 1e-9);
}

// The cube turned as the fingers, its centre `offset` along their axis from the grip point
// (tracking error); the fingers open `opening`. Returns the fingers' axis (world frame).
Eigen::Vector3d cubeOffTheGripPoint(World& world, double offset, double opening) {
    const std::size_t g = toolIndex(world, "parallel-gripper");
    const std::size_t cube = objectIndex(world, "cube-green");
    world.setFingerOpening(g, opening);
    const Eigen::Vector3d centre = world.objects()[cube].pose.translation();
    const Eigen::Vector3d across = world.gripPoint(g)->linear().col(0);
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translation() = centre;
    pose.rotate(Eigen::AngleAxisd(std::atan2(across.y(), across.x()), Eigen::Vector3d::UnitZ()));
    EXPECT_EQ(world.placeObject("cube-green", pose), "");
    moveFlange(world, flangeForGrip(world, "parallel-gripper", centre - offset * across));
    return across;
}

TEST(WorldGrip, ClosingFingersPushAnOffCentreCubeToTheirCentre) {
    for (const double offset : {0.001, -0.001, 0.0005}) {
        World world = withTool("parallel-gripper");
        const std::size_t g = toolIndex(world, "parallel-gripper");
        const std::size_t cube = objectIndex(world, "cube-green");
        cubeOffTheGripPoint(world, offset, 0.05);
        EXPECT_EQ(world.robot(0).tcpForce, Eigen::Vector3d::Zero());
        // Closing by 0.1 mm a step onto the 40 mm cube: the first tip to touch pushes it along
        // the table; no tip ever goes into it, so no force.
        double maxForce = 0.0;
        for (int i = 1; i <= 100; ++i) {
            world.setFingerOpening(g, 0.05 - 0.0001 * i);
            world.step(kDt);
            maxForce = std::max(maxForce, world.robot(0).tcpForce.norm());
        }
        EXPECT_EQ(maxForce, 0.0) << offset;
        const Eigen::Isometry3d grip = *world.gripPoint(g);
        Eigen::Vector3d inGrip = grip.inverse() * world.objects()[cube].pose.translation();
        EXPECT_NEAR(inGrip.x(), 0.0, 1e-9) << "centred between the fingers at 40 mm";
        EXPECT_EQ(world.objects()[cube].holder, "table");
        EXPECT_NEAR(world.objects()[cube].pose.translation().z(), 0.02, 1e-12) << "it slid";
        // Opening again leaves it where it is.
        world.setFingerOpening(g, 0.06);
        world.step(kDt);
        inGrip = grip.inverse() * world.objects()[cube].pose.translation();
        EXPECT_NEAR(inGrip.x(), 0.0, 1e-9);
    }
}

TEST(WorldGrip, HeldBetweenTheJawsCentredAndReleasedWithoutForce) {
    World world = withTool("parallel-gripper");
    const std::size_t g = toolIndex(world, "parallel-gripper");
    const std::size_t cube = objectIndex(world, "cube-green");
    // The jaws at the cube's width, the cube 0.3 mm off their centre (within the fingers'
    // clearance): held, it sits centred between them.
    cubeOffTheGripPoint(world, 0.0003, 0.0406);
    world.setFingerOpening(g, 0.04);
    ASSERT_TRUE(world.hold(g, cube));
    const Eigen::Isometry3d grip = *world.gripPoint(g);
    EXPECT_NEAR((grip.inverse() * world.objects()[cube].pose.translation()).x(), 0.0, 1e-12);
    // Let go with the tips on its side faces: they touch, they do not push into its top.
    world.release(g);
    world.step(kDt);
    EXPECT_EQ(world.objects()[cube].holder, "table");
    EXPECT_EQ(world.robot(0).tcpForce, Eigen::Vector3d::Zero());
}

TEST(WorldGrip, FingersComingDownOntoACubeStillPushIntoItsTop) {
    World world = withTool("parallel-gripper");
    const std::size_t g = toolIndex(world, "parallel-gripper");
    const std::size_t cube = objectIndex(world, "cube-green");
    // Open 30 mm over the 40 mm cube, lowered to its middle: both tips 20 mm into its top face.
    cubeOffTheGripPoint(world, 0.0, 0.03);
    EXPECT_NEAR(world.robot(0).tcpForce.z(), 2 * 20000.0 * 0.02, 1e-6);
    // Closing them further pushes nothing sideways: the tips are inside, not at a side face.
    const Eigen::Vector3d before = world.objects()[cube].pose.translation();
    world.setFingerOpening(g, 0.02);
    world.step(kDt);
    EXPECT_EQ(world.objects()[cube].pose.translation(), before);
    EXPECT_NEAR(world.robot(0).tcpForce.z(), 2 * 20000.0 * 0.02, 1e-6);
    EXPECT_FALSE(world.objectBetweenFingers(g, 0.02).has_value()) << "wider than the opening";
}

TEST(WorldGrip, ReleasedBesideTheTableItFallsToTheFloor) {
    World world = withTool("parallel-gripper");
    const std::size_t g = toolIndex(world, "parallel-gripper");
    const std::size_t cube = objectIndex(world, "cube-green");
    moveFlange(world,
               flangeForGrip(world, "parallel-gripper", world.objects()[cube].pose.translation()));
    ASSERT_TRUE(world.hold(g, cube));
    // The table is 1.0 x 0.8 around the origin: y 0.45 is beside it.
    moveFlange(world, flangeForGrip(world, "parallel-gripper", Eigen::Vector3d(0.05, 0.45, 0.1)));
    world.release(g);
    EXPECT_EQ(world.objects()[cube].holder, "floor");
    EXPECT_NEAR(world.objects()[cube].pose.translation().z(), -0.75 + 0.02, 1e-9);
}

TEST(WorldGrip, TheCupSealsOnlyOnTheTopFace) {
    World world = withTool("vacuum-gripper");
    const std::size_t v = toolIndex(world, "vacuum-gripper");
    const std::size_t cube = objectIndex(world, "cube-green");
    const Eigen::Vector3d top =
        world.objects()[cube].pose.translation() + Eigen::Vector3d(0, 0, 0.02);
    moveFlange(world, flangeForGrip(world, "vacuum-gripper", top + Eigen::Vector3d(0, 0, 0.02)));
    EXPECT_FALSE(world.objectUnderCup(v).has_value()) << "2 cm above the face";
    moveFlange(world, flangeForGrip(world, "vacuum-gripper", top + Eigen::Vector3d(0, 0, 0.001)));
    EXPECT_EQ(world.objectUnderCup(v), cube);
    moveFlange(world, flangeForGrip(world, "vacuum-gripper", top - Eigen::Vector3d(0, 0, 0.002)));
    EXPECT_EQ(world.objectUnderCup(v), cube) << "pressed in 2 mm";
    // 1 cm off centre, the 3 cm cup's rim hangs over the 4 cm face's edge: no seal.
    moveFlange(world, flangeForGrip(world, "vacuum-gripper", top + Eigen::Vector3d(0.01, 0, 0)));
    EXPECT_FALSE(world.objectUnderCup(v).has_value());
    // On the table beside the cube: not an object.
    moveFlange(world, flangeForGrip(world, "vacuum-gripper", Eigen::Vector3d(0.2, 0.1, 0.0)));
    EXPECT_FALSE(world.objectUnderCup(v).has_value());
    // The parallel gripper has no cup, the vacuum gripper no fingers.
    EXPECT_FALSE(world.objectBetweenFingers(v, 0.085).has_value());
}

TEST(WorldOperator, ToolsAndObjectsMovedByHand) {
    World world(thesis());
    EXPECT_NE(world.putToolInDock("parallel-gripper", "dock-1"), "") << "dock-1 is taken";
    EXPECT_NE(world.putToolInDock("nope", "dock-1"), "");
    EXPECT_NE(world.putToolInDock("parallel-gripper", "nope"), "");
    ASSERT_EQ(world.takeToolOut("vacuum-gripper"), "");
    EXPECT_FALSE(world.tools()[toolIndex(world, "vacuum-gripper")].dock.has_value());
    ASSERT_EQ(world.putToolInDock("parallel-gripper", "dock-1"), "");
    EXPECT_EQ(world.tools()[toolIndex(world, "parallel-gripper")].dock, "dock-1");

    const std::size_t cube = objectIndex(world, "cube-green");
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translation() = Eigen::Vector3d(0.1, -0.2, 0.3);
    ASSERT_EQ(world.placeObject("cube-green", pose), "");
    EXPECT_EQ(world.objects()[cube].holder, "table");
    EXPECT_NEAR(world.objects()[cube].pose.translation().z(), 0.02, 1e-12);
    ASSERT_EQ(world.removeObject("cube-green"), "");
    EXPECT_EQ(world.objects()[cube].holder, kRemoved);
    EXPECT_NE(world.removeObject("nope"), "");
    pose.translation().x() = std::nan("");
    EXPECT_NE(world.placeObject("cube-green", pose), "");
}

TEST(WorldOperator, ATaskOnAToolOnTheFlangeIsRefused) {
    World world = withTool("vacuum-gripper");
    EXPECT_NE(world.takeToolOut("vacuum-gripper"), "");
    EXPECT_NE(world.putToolInDock("vacuum-gripper", "dock-1"), "");
}

}  // namespace
}  // namespace pnp::world

namespace pnp::world {
namespace {

TEST(WorldOperator, LocksAndUnlocksAToolByHand) {
    World world(thesis());
    const std::size_t v = toolIndex(world, "vacuum-gripper");
    EXPECT_NE(world.attachToolByHand("nope", "vacuum-gripper"), "");
    EXPECT_NE(world.attachToolByHand("ur5", "nope"), "");
    ASSERT_EQ(world.attachToolByHand("ur5", "vacuum-gripper"), "");
    EXPECT_EQ(world.robot(0).tool, "vacuum-gripper");
    EXPECT_EQ(world.robot(0).changer, ChangerLock::kLocked);
    EXPECT_DOUBLE_EQ(world.robot(0).changerVoltage, 6.7);
    EXPECT_TRUE(world.toolPowered(v));
    EXPECT_FALSE(world.tools()[v].dock.has_value());
    EXPECT_NE(world.attachToolByHand("ur5", "parallel-gripper"), "") << "one at a time";
    ASSERT_EQ(world.detachToolByHand("ur5"), "");
    EXPECT_FALSE(world.toolPowered(v));
    EXPECT_FALSE(world.robot(0).tool.has_value());
    EXPECT_EQ(world.robot(0).changerVoltage, 0.0);
    EXPECT_NE(world.detachToolByHand("ur5"), "");
    EXPECT_EQ(world.putToolInDock("vacuum-gripper", "dock-1"), "");
}

}  // namespace
}  // namespace pnp::world
