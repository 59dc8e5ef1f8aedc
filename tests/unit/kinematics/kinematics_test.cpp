#include "kinematics/kinematics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "kinematics/kdl_chain.hpp"
#include "kinematics/robot_model.hpp"
#include "test_util.hpp"

namespace pnp::kinematics {
namespace {

using test::angleError;
using test::poseError;
using test::randomJoints;

constexpr double kPi = std::numbers::pi;

// UR5 DH lengths, spelled out so the expected poses below do not reuse the model's table.
constexpr double d1 = 0.089159, a2 = -0.425, a3 = -0.39225, d4 = 0.10915, d5 = 0.09465, d6 = 0.0823;

Eigen::Isometry3d pose(const Eigen::Matrix3d& r, const Eigen::Vector3d& p) {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.linear() = r;
    t.translation() = p;
    return t;
}

// The expected poses are the DH products multiplied out by hand (see each comment).
TEST(Forward, Ur5AllZeros) {
    // T1..T3 leave Rx(π/2) and (a2 + a3, 0, d1); T4 adds (0, -d4, 0) and turns to Rx(π);
    // T5 adds (0, 0, -d5) and back to Rx(π/2); T6 adds (0, -d6, 0).
    Eigen::Matrix3d r;
    r << 1, 0, 0,  //
        0, 0, -1,  //
        0, 1, 0;
    const auto expected = pose(r, {a2 + a3, -d4 - d6, d1 - d5});
    EXPECT_LT(poseError(forward(ur5(), {0, 0, 0, 0, 0, 0}), expected), 1e-12);
    EXPECT_NEAR(expected.translation().x(), -0.81725, 1e-12);
    EXPECT_NEAR(expected.translation().y(), -0.19145, 1e-12);
    EXPECT_NEAR(expected.translation().z(), -0.005491, 1e-12);
}

TEST(Forward, Ur5Upright) {
    // q2 = -π/2: the upper arm points up, Rx(π/2) Rz(-π/2) = [0 1 0; 0 0 -1; -1 0 0];
    // the wrist adds (0, -d4, 0), (-d5, 0, 0), (0, -d6, 0).
    Eigen::Matrix3d r;
    r << 0, 1, 0,  //
        0, 0, -1,  //
        -1, 0, 0;
    const auto expected = pose(r, {-d5, -d4 - d6, d1 - a2 - a3});
    EXPECT_LT(poseError(forward(ur5(), {0, -kPi / 2, 0, 0, 0, 0}), expected), 1e-12);
}

TEST(Forward, Ur5BaseTurned) {
    // q1 = π/2: the zero pose turned by Rz(π/2).
    Eigen::Matrix3d r;
    r << 0, 0, 1,  //
        1, 0, 0,   //
        0, 1, 0;
    const auto expected = pose(r, {d4 + d6, a2 + a3, d1 - d5});
    EXPECT_LT(poseError(forward(ur5(), {kPi / 2, 0, 0, 0, 0, 0}), expected), 1e-12);
}

TEST(Forward, Ur5WristTurned) {
    // q5 = π/2: Rx(π) Rz(π/2) Rx(-π/2) = [0 0 -1; -1 0 0; 0 1 0]; d6 now along -x.
    Eigen::Matrix3d r;
    r << 0, 0, -1,  //
        -1, 0, 0,   //
        0, 1, 0;
    const auto expected = pose(r, {a2 + a3 - d6, -d4, d1 - d5});
    EXPECT_LT(poseError(forward(ur5(), {0, 0, 0, 0, kPi / 2, 0}), expected), 1e-12);
}

TEST(Forward, MatchesKdlOnRandomConfigurations) {
    std::mt19937_64 rng(42);
    for (const RobotModel& model : {ur3(), ur5(), ur10()}) {
        const KDL::Chain chain = toKdlChain(model);
        ASSERT_EQ(chain.getNrOfJoints(), 6u);
        for (int n = 0; n < 1000; ++n) {
            const Joints q = randomJoints(rng, 2 * kPi);
            const auto kdl = forwardKdl(chain, q);
            ASSERT_TRUE(kdl.ok());
            ASSERT_LT(poseError(forward(model, q), *kdl), 1e-12) << model.name << " #" << n;
        }
    }
}

TEST(Forward, ThetaOffsetsAreAddedToTheJoints) {
    RobotModel shifted = ur5();
    shifted.dh[1].thetaOffset = -kPi / 2;
    EXPECT_LT(
        poseError(forward(shifted, {0, 0, 0, 0, 0, 0}), forward(ur5(), {0, -kPi / 2, 0, 0, 0, 0})),
        1e-12);
    const auto kdl = forwardKdl(toKdlChain(shifted), Joints{0.1, 0.2, 0.3, 0.4, 0.5, 0.6});
    ASSERT_TRUE(kdl.ok());
    EXPECT_LT(poseError(forward(shifted, {0.1, 0.2, 0.3, 0.4, 0.5, 0.6}), *kdl), 1e-12);
}

// FK -> solveAll on random configurations: every solution reproduces the pose, no
// duplicates, and the original configuration is among them.
void roundTrips(const RobotModel& model, int count, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    int foundOriginal = 0;
    for (int n = 0; n < count; ++n) {
        const Joints q = randomJoints(rng);
        const Eigen::Isometry3d t = forward(model, q);
        const auto sols = solveAll(model, t);
        ASSERT_GE(sols.size(), 1u) << model.name << " #" << n;
        ASSERT_LE(sols.size(), 8u);
        bool original = false;
        for (size_t i = 0; i < sols.size(); ++i) {
            ASSERT_LT(poseError(forward(model, sols[i]), t), 1e-9) << model.name << " #" << n;
            for (size_t j = 0; j < i; ++j) ASSERT_GT(angleError(sols[i], sols[j]), 1e-9);
            original = original || angleError(sols[i], q) < 1e-9;
        }
        if (original) ++foundOriginal;
    }
    // Every solution reproduces the pose (checked above); with these seeds no configuration
    // is close enough to a singularity for the original to be off by more than 1e-9 rad.
    EXPECT_EQ(foundOriginal, count) << model.name;
}

TEST(Inverse, Ur5RoundTrips) { roundTrips(ur5(), 10000, 1); }
TEST(Inverse, Ur3RoundTrips) { roundTrips(ur3(), 1000, 2); }
TEST(Inverse, Ur10RoundTrips) { roundTrips(ur10(), 1000, 3); }

TEST(Inverse, EightSolutionsForAGenericPose) {
    const Joints q{0.3, -1.2, 1.5, -0.8, 1.1, 0.4};
    const auto t = forward(ur5(), q);
    const auto sols = solveAll(ur5(), t);
    ASSERT_EQ(sols.size(), 8u);
    int shoulder[2] = {0, 0}, wrist[2] = {0, 0}, elbow[2] = {0, 0};
    for (const Joints& s : sols) {
        EXPECT_LT(poseError(forward(ur5(), s), t), 1e-9);
        for (const double v : s) {
            EXPECT_GE(v, -kPi - 1e-12);
            EXPECT_LE(v, kPi + 1e-12);  // default seed 0: the equivalent nearest 0
        }
        ++shoulder[std::abs(std::remainder(s[0] - q[0], 2 * kPi)) < 1e-9 ? 0 : 1];
        ++wrist[s[4] > 0 ? 0 : 1];
        ++elbow[s[2] > 0 ? 0 : 1];
    }
    // Each branch (shoulder left/right, wrist flip, elbow up/down) is taken by four solutions.
    for (const int* branch : {shoulder, wrist, elbow}) {
        EXPECT_EQ(branch[0], 4);
        EXPECT_EQ(branch[1], 4);
    }
}

TEST(Inverse, UnreachablePosesAreRefused) {
    const auto far = pose(Eigen::Matrix3d::Identity(), {2.0, 0.0, 0.3});
    EXPECT_TRUE(solveAll(ur5(), far).empty());
    const auto r = solveNearest(ur5(), far, {});
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, ErrorCode::kOutOfReach);
    EXPECT_NE(r.error().message.find("out of reach"), std::string::npos);

    // Wrist centre on the base axis: inside the cylinder of radius d4 no q1 exists.
    Eigen::Matrix3d down;
    down << 1, 0, 0, 0, -1, 0, 0, 0, -1;  // tool z pointing down
    const auto inside = pose(down, {0.0, 0.0, 0.3 - d6});
    const auto r2 = solveNearest(ur5(), inside, {});
    ASSERT_FALSE(r2.ok());
    EXPECT_EQ(r2.error().code, ErrorCode::kOutOfReach);
}

TEST(Inverse, NearestToTheSeed) {
    std::mt19937_64 rng(7);
    std::normal_distribution<double> noise(0.0, 0.05);
    for (int n = 0; n < 1000; ++n) {
        const Joints q = randomJoints(rng);
        Joints seed = q;
        for (double& v : seed) v += noise(rng);
        const auto r = solveNearest(ur5(), forward(ur5(), q), seed);
        ASSERT_TRUE(r.ok()) << r.error().message;
        const Eigen::Isometry3d t = forward(ur5(), q);
        EXPECT_LT(poseError(forward(ur5(), *r), t), 1e-9);
        // Any other solution is at least as far from the seed.
        for (const Joints& s : solveAll(ur5(), t, seed)) {
            EXPECT_LE(jointDistance(*r, seed), jointDistance(s, seed) + 1e-12);
        }
    }
}

TEST(Inverse, TwoPiEquivalentNearestTheSeedWithinLimits) {
    const Joints q{0.3, -1.2, 1.5, -0.8, 1.1, 0.4};
    const auto t = forward(ur5(), q);
    // Seed one turn away: the solution follows the seed (joints have ±2π of travel).
    Joints seed = q;
    seed[0] -= 2 * kPi;
    seed[5] -= 2 * kPi;
    const auto r = solveNearest(ur5(), t, seed);
    ASSERT_TRUE(r.ok());
    EXPECT_NEAR((*r)[0], q[0] - 2 * kPi, 1e-9);
    EXPECT_NEAR((*r)[5], q[5] - 2 * kPi, 1e-9);
    // Seed beyond the limit: the nearest equivalent still inside ±2π.
    const auto r2 = solveNearest(ur5(), t, {7.5, 0, 0, 0, 0, 0});
    ASSERT_TRUE(r2.ok());
    EXPECT_LE((*r2)[0], 2 * kPi);
    for (const Joints& s : solveAll(ur5(), t, {9, 9, 9, 9, 9, 9})) {
        for (int i = 0; i < kAxes; ++i) {
            EXPECT_LE(s[i], 2 * kPi);
            EXPECT_GE(s[i], -1e-12);  // the equivalent nearest 9 is in [0, 2π]
        }
    }
}

TEST(Inverse, JointLimitsAreRespected) {
    const Joints q{0.3, -1.2, 1.5, -0.8, 1.1, 0.4};
    const auto t = forward(ur5(), q);
    RobotModel limited = ur5();
    limited.limits[2].minPosition = 0.0;  // elbow only on one side
    limited.limits[2].maxPosition = kPi;
    const auto sols = solveAll(limited, t);
    EXPECT_EQ(sols.size(), 4u);
    for (const Joints& s : sols) EXPECT_GE(s[2], 0.0);
    const auto r = solveNearest(limited, t, {0, 0, -1.5, 0, 0, 0});
    ASSERT_TRUE(r.ok());
    EXPECT_GE((*r)[2], 0.0);

    // No elbow angle of any solution within [0.01, 0.02]: every solution is outside.
    for (const Joints& s : solveAll(ur5(), t)) ASSERT_GT(std::abs(std::abs(s[2]) - 0.015), 0.01);
    limited.limits[2].minPosition = 0.01;
    limited.limits[2].maxPosition = 0.02;
    EXPECT_TRUE(solveAll(limited, t).empty());
    const auto r2 = solveNearest(limited, t, q);
    ASSERT_FALSE(r2.ok());
    EXPECT_EQ(r2.error().code, ErrorCode::kOutsideJointLimits);
    EXPECT_NE(r2.error().message.find("outside joint limits"), std::string::npos);
}

TEST(Inverse, AxisBoundsAreRespected) {
    const Joints q{0.3, -1.2, 1.5, -0.8, 1.1, 0.4};
    const auto t = forward(ur5(), q);
    AxisBounds b{{-10, -10, -10, -10, -10, -10}, {10, 10, 10, 10, 10, 10}};
    // Seed at the other shoulder solution, bounds that only allow the original shoulder.
    Joints other{};
    for (const Joints& s : solveAll(ur5(), t)) {
        if (angleError(s, q) > 1e-6 && std::abs(s[0] - q[0]) > 0.5) other = s;
    }
    b.min[0] = q[0] - 0.1;
    b.max[0] = q[0] + 0.1;
    const auto r = solveNearest(ur5(), t, other, b);
    ASSERT_TRUE(r.ok());
    EXPECT_NEAR((*r)[0], q[0], 1e-9);
    EXPECT_LT(poseError(forward(ur5(), *r), t), 1e-9);

    b.min[0] = q[0] + 0.1;  // nothing left in between
    b.max[0] = q[0] + 0.2;
    for (const Joints& s : solveAll(ur5(), t)) {
        ASSERT_FALSE(std::abs(std::remainder(s[0] - q[0] - 0.15, 2 * kPi)) < 0.05);
    }
    const auto r2 = solveNearest(ur5(), t, q, b);
    ASSERT_FALSE(r2.ok());
    EXPECT_EQ(r2.error().code, ErrorCode::kOutsideAxisBounds);
    EXPECT_NE(r2.error().message.find("outside axis bounds"), std::string::npos);

    b.min[3] = 1.0;  // empty interval
    b.max[3] = -1.0;
    const auto r3 = solveNearest(ur5(), t, q, b);
    ASSERT_FALSE(r3.ok());
    EXPECT_EQ(r3.error().code, ErrorCode::kInvalidArgument);
}

TEST(Inverse, WristSingularityKeepsTheSeedQ6) {
    const Joints q{0.2, -1.0, 1.2, 0.3, 0.0, 0.7};  // q5 = 0: axes 4 and 6 aligned
    const auto t = forward(ur5(), q);
    const auto r = solveNearest(ur5(), t, q);
    ASSERT_TRUE(r.ok());
    EXPECT_LT(angleError(*r, q), 1e-9);
    EXPECT_LT(poseError(forward(ur5(), *r), t), 1e-9);
    // Another seed q6: the solution keeps it and q4 compensates.
    Joints seed = q;
    seed[5] = -0.5;
    const auto sols = solveAll(ur5(), t, seed);
    ASSERT_FALSE(sols.empty());
    for (const Joints& s : sols) {
        EXPECT_LT(poseError(forward(ur5(), s), t), 1e-9);
        if (std::abs(std::sin(s[4])) < 1e-6) {
            EXPECT_DOUBLE_EQ(s[5], -0.5);
        }
    }
}

TEST(Inverse, ShoulderSingularityMergesTheShoulderSolutions) {
    // Wrist centre at horizontal distance d4 from the base axis: both q1 solutions coincide.
    const Joints q{0.4, -kPi / 2, 0.0, kPi / 2, 1.0, 0.5};
    const auto t = forward(ur5(), q);
    const auto sols = solveAll(ur5(), t);
    ASSERT_FALSE(sols.empty());
    EXPECT_LE(sols.size(), 4u);
    bool original = false;
    for (const Joints& s : sols) {
        EXPECT_LT(poseError(forward(ur5(), s), t), 1e-9);
        original = original || angleError(s, q) < 1e-6;
    }
    EXPECT_TRUE(original);
}

TEST(Inverse, FreeShoulderKeepsTheSeedQ1) {
    // With d4 = 0 a wrist centre on the base axis leaves q1 free.
    RobotModel m = ur5();
    m.dh[3].d = 0.0;
    ASSERT_TRUE(hasUrClosedForm(m));
    const Joints q{0.7, -kPi / 2, 0.0, kPi / 2, 1.0, 0.5};
    const auto t = forward(m, q);
    const Eigen::Vector3d wristCentre = t.translation() - d6 * t.linear().col(2);
    ASSERT_LT(wristCentre.head<2>().norm(), 1e-12);
    const auto r = solveNearest(m, t, q);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_LT(angleError(*r, q), 1e-9);
    for (const Joints& s : solveAll(m, t, q)) EXPECT_LT(poseError(forward(m, s), t), 1e-9);
}

TEST(Inverse, RejectsNonUrModelsAndNonFinitePoses) {
    RobotModel odd = ur5();
    odd.dh[3].a = 0.05;
    EXPECT_FALSE(hasUrClosedForm(odd));
    EXPECT_TRUE(hasUrClosedForm(ur10()));
    const auto t = forward(ur5(), {0.3, -1.2, 1.5, -0.8, 1.1, 0.4});
    EXPECT_TRUE(solveAll(odd, t).empty());
    const auto r = solveNearest(odd, t, {});
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, ErrorCode::kUnsupportedModel);

    Eigen::Isometry3d nan = t;
    nan.translation().x() = std::nan("");
    const auto r2 = solveNearest(ur5(), nan, {});
    ASSERT_FALSE(r2.ok());
    EXPECT_EQ(r2.error().code, ErrorCode::kInvalidArgument);
}

TEST(Inverse, WorkspaceBoundaryStretchedArm) {
    // Elbow stretched (q3 = 0): c3 = 1 up to rounding; the pose must still be solved.
    const Joints q{0.5, -0.7, 0.0, -0.3, 1.3, -0.2};
    const auto t = forward(ur5(), q);
    const auto r = solveNearest(ur5(), t, q);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_LT(poseError(forward(ur5(), *r), t), 1e-9);
    // Elbow up and down are one: at most shoulder × wrist = 4 solutions.
    const auto sols = solveAll(ur5(), t);
    EXPECT_LE(sols.size(), 4u);
    for (const Joints& s : sols) EXPECT_LT(poseError(forward(ur5(), s), t), 1e-9);
}

TEST(Inverse, NearTheWristSingularity) {
    for (const double q5 : {1e-4, 1e-7, 1e-10, 1e-13, -1e-9}) {
        const Joints q{0.2, -1.0, 1.2, 0.3, q5, 0.7};
        const auto t = forward(ur5(), q);
        const auto sols = solveAll(ur5(), t, q);
        ASSERT_FALSE(sols.empty()) << q5;
        for (const Joints& s : sols) EXPECT_LT(poseError(forward(ur5(), s), t), 1e-9) << q5;
        const auto r = solveNearest(ur5(), t, q);
        ASSERT_TRUE(r.ok());
        EXPECT_LT(poseError(forward(ur5(), *r), t), 1e-9) << q5;
        EXPECT_LT(angleError(*r, q), 1e-6) << q5;  // q4 + q6 split as in the seed
    }
}

TEST(Model, Ur5Values) {
    const RobotModel m = ur5();
    EXPECT_EQ(m.name, "UR5");
    EXPECT_DOUBLE_EQ(m.dh[0].d, 0.089159);
    EXPECT_DOUBLE_EQ(m.dh[1].a, -0.425);
    EXPECT_DOUBLE_EQ(m.dh[2].a, -0.39225);
    EXPECT_DOUBLE_EQ(m.dh[3].d, 0.10915);
    EXPECT_DOUBLE_EQ(m.dh[4].d, 0.09465);
    EXPECT_DOUBLE_EQ(m.dh[5].d, 0.0823);
    for (const JointLimits& l : m.limits) {
        EXPECT_DOUBLE_EQ(l.minPosition, -2 * kPi);
        EXPECT_DOUBLE_EQ(l.maxPosition, 2 * kPi);
        EXPECT_DOUBLE_EQ(l.maxVelocity, kPi);
        EXPECT_DOUBLE_EQ(l.maxAcceleration, kPi);
    }
}

}  // namespace
}  // namespace pnp::kinematics
