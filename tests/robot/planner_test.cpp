#include "robot/planner.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <limits>
#include <numbers>
#include <thread>

#include "kinematics/kinematics.hpp"

namespace pnp::robot {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kPi = std::numbers::pi;

// A comfortable, non-singular UR5 configuration (elbow up, wrist bent).
const Joints kHome{0.2, -1.2, 1.4, -1.77, -1.57, 0.3};
const Joints kNear{0.5, -1.0, 1.2, -1.6, -1.4, 0.6};

Eigen::Isometry3d worldToBase() {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.translation() = Eigen::Vector3d(1.0, 0.5, 0.8);
    t.linear() = Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    return t;
}

Eigen::Isometry3d gripperTool() {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.translation() = Eigen::Vector3d(0.0, 0.02, 0.15);
    return t;
}

Planner makePlanner() {
    PlannerConfig c;
    c.model = kinematics::ur5();
    c.worldToBase = worldToBase();
    return Planner(c);  // defaults: the model's joint ratings, motion's Cartesian defaults
}

CartesianTarget targetAt(const Planner& p, const Joints& q) {
    CartesianTarget t;
    t.tool = gripperTool();
    t.pose = p.toolPose(q, t.tool);
    return t;
}

void expectPose(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double tol = 1e-5) {
    EXPECT_LT((a.translation() - b.translation()).norm(), tol);
    EXPECT_LT(Eigen::AngleAxisd(a.rotation().transpose() * b.rotation()).angle(), 1e-5);
}

std::string refusal(const Result<motion::Trajectory>& r) {
    EXPECT_FALSE(r.ok());
    return r.ok() ? std::string() : r.error().message;
}

TEST(Planner, CartesianPtpEndsAtTheTargetPose) {
    const Planner p = makePlanner();
    const CartesianTarget t = targetAt(p, kNear);
    auto r = p.cartesianPtp(kHome, t, {});
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_EQ(r->kind(), motion::Trajectory::Kind::Ptp);
    const Joints end = r->sample(r->duration()).position;
    expectPose(p.toolPose(end, t.tool), t.pose);
    for (std::size_t i = 0; i < end.size(); ++i)
        EXPECT_NEAR(r->sample(0).position[i], kHome[i], 1e-12);
}

TEST(Planner, CartesianPtpKeepsTheRequestedLimits) {
    const Planner p = makePlanner();
    auto fast = p.cartesianPtp(kHome, targetAt(p, kNear), {});
    auto slow = p.cartesianPtp(kHome, targetAt(p, kNear), PtpLimits{{0.5}, {1.0}});
    ASSERT_TRUE(fast.ok() && slow.ok());
    EXPECT_GT(slow->duration(), fast->duration());
    for (double t = 0.0; t <= slow->duration(); t += 0.01) {
        const auto s = slow->sample(t);
        for (std::size_t i = 0; i < 6; ++i) EXPECT_LE(std::abs(s.velocity[i]), 0.5 + 1e-9);
    }
}

TEST(Planner, CartesianLinearEndsAtTheTargetOnAStraightLine) {
    const Planner p = makePlanner();
    const CartesianTarget t = targetAt(p, kNear);
    auto r = p.cartesianLinear(kHome, t, LinLimits{{0.2}, {}});
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_EQ(r->kind(), motion::Trajectory::Kind::Lin);
    expectPose(p.toolPose(r->sample(r->duration()).position, t.tool), t.pose);
    // Every sample's tool position lies on the segment from start to target (world frame).
    const Eigen::Vector3d a = p.toolPose(kHome, t.tool).translation();
    const Eigen::Vector3d b = t.pose.translation();
    const Eigen::Vector3d dir = (b - a).normalized();
    for (int k = 0; k <= 20; ++k) {
        const Eigen::Vector3d x =
            p.toolPose(r->sample(r->duration() * k / 20.0).position, t.tool).translation();
        const Eigen::Vector3d rel = x - a;
        EXPECT_LT((rel - rel.dot(dir) * dir).norm(), 1e-4) << "sample " << k;
    }
}

TEST(Planner, JointLinearEndsInTheTargetConfiguration) {
    const Planner p = makePlanner();
    const std::vector<double> target(kNear.begin(), kNear.end());
    auto r = p.jointLinear(kHome, target, gripperTool(), {});
    ASSERT_TRUE(r.ok()) << r.error().message;
    const Joints end = r->sample(r->duration()).position;
    for (std::size_t i = 0; i < 6; ++i) EXPECT_NEAR(end[i], kNear[i], 1e-6);
}

TEST(Planner, JointLinearRefusesAnotherConfiguration) {
    const Planner p = makePlanner();
    // The same pose with axis 6 one turn further: a line ends at the nearer equivalent.
    std::vector<double> target(kNear.begin(), kNear.end());
    target[5] -= 2.0 * kPi;
    const std::string m = refusal(p.jointLinear(kHome, target, gripperTool(), {}));
    EXPECT_NE(m.find("another configuration"), std::string::npos) << m;
    EXPECT_NE(m.find("axis 5"), std::string::npos) << m;
}

TEST(Planner, JointPtpEndsAtTheTarget) {
    const Planner p = makePlanner();
    auto r = p.jointPtp(kHome, std::vector<double>(kNear.begin(), kNear.end()), {});
    ASSERT_TRUE(r.ok()) << r.error().message;
    const Joints end = r->sample(r->duration()).position;
    for (std::size_t i = 0; i < 6; ++i) EXPECT_NEAR(end[i], kNear[i], 1e-12);
}

TEST(Planner, RefusesNonFiniteNumbers) {
    const Planner p = makePlanner();
    CartesianTarget t = targetAt(p, kNear);
    Joints badCurrent = kHome;
    badCurrent[3] = kNaN;
    EXPECT_NE(
        refusal(p.cartesianPtp(badCurrent, t, {})).find("current joint position is not finite"),
        std::string::npos);
    EXPECT_NE(refusal(p.jointPtp(badCurrent, {0, 0, 0, 0, 0, 0}, {})).find("not finite"),
              std::string::npos);

    CartesianTarget badPose = t;
    badPose.pose.translation().x() = kNaN;
    EXPECT_NE(refusal(p.cartesianPtp(kHome, badPose, {})).find("TargetPosition"),
              std::string::npos);
    EXPECT_FALSE(p.cartesianLinear(kHome, badPose, {}).ok());

    CartesianTarget badTool = t;
    badTool.tool.translation().z() = std::numeric_limits<double>::infinity();
    EXPECT_NE(refusal(p.cartesianPtp(kHome, badTool, {})).find("tool frame"), std::string::npos);

    std::vector<double> target(kNear.begin(), kNear.end());
    target[1] = kNaN;
    EXPECT_NE(refusal(p.jointPtp(kHome, target, {})).find("TargetJointPosition[1]"),
              std::string::npos);

    EXPECT_NE(refusal(p.cartesianPtp(kHome, t, PtpLimits{{kNaN}, {}})).find("MaxVelocity[0]"),
              std::string::npos);
    EXPECT_NE(
        refusal(p.cartesianLinear(kHome, t, LinLimits{{}, {0.5, kNaN}})).find("MaxAcceleration[1]"),
        std::string::npos);

    CartesianTarget badBounds = t;
    badBounds.bounds = kinematics::AxisBounds{{-6, -6, -6, -6, -6, -6}, {6, 6, kNaN, 6, 6, 6}};
    EXPECT_NE(refusal(p.cartesianPtp(kHome, badBounds, {})).find("AxisBounds[2]"),
              std::string::npos);
}

TEST(Planner, RefusesScaledOrientations) {
    const Planner p = makePlanner();
    CartesianTarget t = targetAt(p, kNear);
    t.pose.linear() *= 2.0;
    EXPECT_NE(refusal(p.cartesianPtp(kHome, t, {})).find("not a rotation"), std::string::npos);
}

TEST(Planner, RefusesWrongLengths) {
    const Planner p = makePlanner();
    const CartesianTarget t = targetAt(p, kNear);
    EXPECT_NE(refusal(p.cartesianPtp(kHome, t, PtpLimits{{1, 1, 1}, {}}))
                  .find("MaxVelocity has 3 values"),
              std::string::npos);
    EXPECT_NE(refusal(p.cartesianLinear(kHome, t, LinLimits{{0.1, 0.1, 0.1}, {}}))
                  .find("MaxVelocity has 3 values"),
              std::string::npos);
    EXPECT_NE(refusal(p.jointPtp(kHome, {0, 0, 0, 0, 0}, {})).find("has 5 values"),
              std::string::npos);
    EXPECT_FALSE(p.checkJoints({0, 0, 0, 0, 0, 0, 0}).ok());
}

TEST(Planner, RefusesLimitsAboveTheMaximaOrNotPositive) {
    const Planner p = makePlanner();
    const CartesianTarget t = targetAt(p, kNear);
    const std::string m = refusal(p.cartesianPtp(kHome, t, PtpLimits{{1, 1, 10, 1, 1, 1}, {}}));
    EXPECT_NE(m.find("MaxVelocity[2] = 10 rad/s is above the robot's maximum 3.142"),
              std::string::npos)
        << m;
    EXPECT_NE(refusal(p.cartesianPtp(kHome, t, PtpLimits{{}, {0.0}})).find("greater than 0"),
              std::string::npos);
    EXPECT_NE(refusal(p.cartesianPtp(kHome, t, PtpLimits{{-1}, {}})).find("greater than 0"),
              std::string::npos);
    EXPECT_NE(refusal(p.cartesianLinear(kHome, t, LinLimits{{5.0}, {}})).find("above the robot"),
              std::string::npos);
    EXPECT_NE(refusal(p.cartesianLinear(kHome, t, LinLimits{{0.1, 0.1, 0.1, 50.0}, {}}))
                  .find("MaxVelocity[3] = 50 rad/s"),
              std::string::npos);
    auto four = p.cartesianLimits(LinLimits{{0.2, 0.1, 0.15, 0.5}, {0.4, 0.5}});
    ASSERT_TRUE(four.ok());
    EXPECT_DOUBLE_EQ(four->maxLinearVelocity, 0.1);  // min of x, y, z
    EXPECT_DOUBLE_EQ(four->maxAngularVelocity, 0.5);
    EXPECT_DOUBLE_EQ(four->maxLinearAcceleration, 0.4);
    EXPECT_DOUBLE_EQ(four->maxAngularAcceleration, 0.5);
}

TEST(Planner, RefusesTargetsOutOfReach) {
    const Planner p = makePlanner();
    CartesianTarget t = targetAt(p, kNear);
    t.pose.translation() = worldToBase() * Eigen::Vector3d(0.1, 2.5, 0.3);
    const std::string m = refusal(p.cartesianPtp(kHome, t, {}));
    EXPECT_NE(m.find("TargetPosition ("), std::string::npos) << m;
    EXPECT_NE(m.find("is out of reach"), std::string::npos) << m;
    EXPECT_NE(refusal(p.cartesianLinear(kHome, t, {})).find("is out of reach"), std::string::npos);
}

TEST(Planner, RefusesJointTargetsOutsideTheJointLimits) {
    const Planner p = makePlanner();
    std::vector<double> target(kNear.begin(), kNear.end());
    target[2] = 7.1;
    EXPECT_EQ(refusal(p.jointPtp(kHome, target, {})),
              "TargetJointPosition[2] = 7.1 rad is outside the joint limits [-6.283, 6.283]");
    EXPECT_FALSE(p.jointLinear(kHome, target, gripperTool(), {}).ok());
    EXPECT_FALSE(p.checkJoints(target).ok());
}

TEST(Planner, RefusesTargetsOutsideTheAxisBounds) {
    const Planner p = makePlanner();
    CartesianTarget t = targetAt(p, kNear);
    // Axis 1 may not pass 0.4 rad; kNear needs 0.5 and every other solution is further away.
    t.bounds = kinematics::AxisBounds{{-1.0, -3, -3, -3, -3, -1}, {0.4, 3, 3, 3, 3, 1}};
    std::string m = refusal(p.cartesianPtp(kHome, t, {}));
    EXPECT_EQ(m.rfind("AxisBounds:", 0), 0u) << m;
    // Inverted bounds, and a robot that stands outside them.
    t.bounds = kinematics::AxisBounds{{1.0, -3, -3, -3, -3, -1}, {0.4, 3, 3, 3, 3, 1}};
    m = refusal(p.cartesianPtp(kHome, t, {}));
    EXPECT_NE(m.find("AxisBounds[0]: the minimum 1 is above the maximum 0.4"), std::string::npos)
        << m;
    t.bounds = kinematics::AxisBounds{{0.3, -3, -3, -3, -3, -1}, {1.0, 3, 3, 3, 3, 1}};
    m = refusal(p.cartesianLinear(kHome, t, {}));
    EXPECT_NE(m.find("outside the bounds"), std::string::npos) << m;
    // Bounds that allow the target: planned, and the line stays within them.
    t.bounds = kinematics::AxisBounds{{0.0, -3, -3, -3, -3, -1}, {0.6, 3, 3, 3, 3, 1}};
    auto r = p.cartesianLinear(kHome, t, {});
    ASSERT_TRUE(r.ok()) << r.error().message;
    for (int k = 0; k <= 50; ++k) {
        const double q0 = r->sample(r->duration() * k / 50.0).position[0];
        EXPECT_GE(q0, 0.0);
        EXPECT_LE(q0, 0.6);
    }
}

TEST(Planner, RefusesALineThroughAWristSingularity) {
    const Planner p = makePlanner();
    // Axis 5 from +0.3 to -0.3 rad along the line: the wrist passes sin(q5) = 0.
    const Joints a{0.0, -1.5, 1.5, -1.5, 0.3, 0.0};
    Joints b = a;
    b[4] = -0.3;
    CartesianTarget t;
    t.pose = p.toolPose(b, t.tool);
    const std::string m = refusal(p.cartesianLinear(a, t, {}));
    EXPECT_EQ(m.rfind("the line passes a singularity at ", 0), 0u) << m;
    EXPECT_NE(m.find(" % ("), std::string::npos) << m;
}

TEST(Planner, RefusesALineThatLeavesTheReach) {
    const Planner p = makePlanner();
    // Flange pointing down, from one side of the base to the other: the wrist centre would
    // pass the unreachable cylinder around axis 1.
    Eigen::Isometry3d a = Eigen::Isometry3d::Identity();
    a.linear() = Eigen::AngleAxisd(kPi, Eigen::Vector3d::UnitX()).toRotationMatrix();
    a.translation() = Eigen::Vector3d(0.4, 0.05, 0.3);
    auto qa = kinematics::solveNearest(p.model(), a, {0, -1.5, 1.5, -1.5, -1.5, 0});
    ASSERT_TRUE(qa.ok());
    CartesianTarget t;
    t.pose = worldToBase() * a;
    t.pose.translation() = worldToBase() * Eigen::Vector3d(-0.4, 0.05, 0.3);
    const std::string m = refusal(p.cartesianLinear(*qa, t, {}));
    EXPECT_EQ(m.rfind("the line leaves the robot's reach at ", 0), 0u) << m;
    EXPECT_TRUE(p.cartesianPtp(*qa, t, {}).ok());  // a PTP gets there
}

TEST(Planner, WorldToBaseIsThreadSafe) {
    Planner p = makePlanner();
    std::atomic<bool> done{false};
    Eigen::Isometry3d a = worldToBase(), b = Eigen::Isometry3d::Identity();
    std::thread writer([&] {
        for (int i = 0; i < 20000 && !done; ++i) p.setWorldToBase(i % 2 ? a : b);
    });
    int torn = 0;
    for (int i = 0; i < 20000; ++i) {
        const Eigen::Isometry3d w = p.worldToBase();
        if (!w.isApprox(a) && !w.isApprox(b)) ++torn;
    }
    done = true;
    writer.join();
    EXPECT_EQ(torn, 0);
    Planner copy = p;  // still a value type
    EXPECT_TRUE(copy.worldToBase().isApprox(p.worldToBase()));
}

}  // namespace
}  // namespace pnp::robot
