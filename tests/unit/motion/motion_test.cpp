#include "motion/motion.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <vector>

#include "test_robots.hpp"

namespace pnp::motion {
namespace {

using test::gantry;
using test::poseOf;

constexpr double kTol = 1e-9;

Limits testLimits() {
    Limits l;
    l.joint.maxVelocity = {1.0, 0.8, 1.2, 2.0, 1.5, 2.5};
    l.joint.maxAcceleration = {2.0, 3.0, 2.5, 4.0, 5.0, 3.5};
    l.cartesian = {0.25, 1.0, 1.0, 4.0};
    return l;
}

// Dense check, analytic and by finite differences of the sampled positions.
void expectWithinJointLimits(const Trajectory& traj, const JointLimits& l, int samples = 20000) {
    const double T = traj.duration();
    if (T == 0.0) return;
    const double dt = T / samples;
    std::vector<JointSample> s(static_cast<std::size_t>(samples) + 1);
    for (int j = 0; j <= samples; ++j) s[static_cast<std::size_t>(j)] = traj.sample(j * dt);
    for (std::size_t j = 0; j < s.size(); ++j) {
        for (std::size_t i = 0; i < 6; ++i) {
            ASSERT_LE(std::abs(s[j].velocity[i]), l.maxVelocity[i] * (1 + kTol)) << j << " " << i;
            ASSERT_LE(std::abs(s[j].acceleration[i]), l.maxAcceleration[i] * (1 + kTol))
                << j << " " << i;
            if (j > 0) {
                const double v = (s[j].position[i] - s[j - 1].position[i]) / dt;
                ASSERT_LE(std::abs(v), l.maxVelocity[i] * (1 + 1e-6) + 1e-9);
            }
            if (j > 0 && j + 1 < s.size()) {
                const double a =
                    (s[j + 1].position[i] - 2 * s[j].position[i] + s[j - 1].position[i]) /
                    (dt * dt);
                // Second differences straddle the acceleration jumps: allow a little slack.
                ASSERT_LE(std::abs(a), l.maxAcceleration[i] * (1 + 1e-3) + 1e-6);
            }
        }
    }
}

double lineDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    const Eigen::Vector3d d = (b - a).normalized();
    const Eigen::Vector3d r = p - a;
    return (r - r.dot(d) * d).norm();
}

double angleBetween(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
    return Eigen::AngleAxisd(a.transpose() * b).angle();
}

// ---------------------------------------------------------------- PTP

TEST(Ptp, LimitsNeverExceededAndAxesSynchronised) {
    const Limits l = testLimits();
    const std::vector<std::pair<Joints, Joints>> moves = {
        {{0, 0, 0, 0, 0, 0}, {1, -0.5, 0.2, 3, -1, 0.1}},
        {{0.3, 0.1, -2, 1, 1, 1}, {0.31, 0.1, 2, 1, 0.9, -3}},
        {{0, 0, 0, 0, 0, 0}, {0.001, 0.002, 0, 0, 0, -0.003}},  // triangle profile
        {{1, 2, 3, 4, 5, 6}, {-1, -2, -3, -4, -5, -6}},
    };
    for (const auto& [a, b] : moves) {
        auto r = planPtp(a, b, l.joint);
        ASSERT_TRUE(r.ok()) << r.error().message;
        const Trajectory& t = r.value();
        EXPECT_EQ(t.kind(), Trajectory::Kind::Ptp);
        expectWithinJointLimits(t, l.joint);
        // The goal exactly, every axis at rest.
        const JointSample end = t.sample(t.duration());
        for (std::size_t i = 0; i < 6; ++i) {
            EXPECT_EQ(end.position[i], b[i]);
            EXPECT_EQ(end.velocity[i], 0.0);
        }
        EXPECT_EQ(t.sample(0.0).position, a);
        // Synchronised: every moving axis moves during the whole motion (no early stop).
        double slowest = 0.0;
        for (std::size_t i = 0; i < 6; ++i) {
            const double d = std::abs(b[i] - a[i]);
            slowest = std::max(slowest, TimingLaw::restToRest(0, d, l.joint.maxVelocity[i],
                                                              l.joint.maxAcceleration[i])
                                            .duration());
        }
        EXPECT_GE(t.duration(), slowest * (1 - 1e-12));
        for (int k = 1; k < 100; ++k) {
            const JointSample s = t.sample(t.duration() * k / 100.0);
            for (std::size_t i = 0; i < 6; ++i) {
                if (b[i] != a[i]) {
                    EXPECT_NE(s.velocity[i], 0.0);
                }
            }
        }
        // Some axis is at one of its limits (the profile is not needlessly slow).
        double peak = 0.0;
        for (int k = 0; k <= 2000; ++k) {
            const JointSample s = t.sample(t.duration() * k / 2000.0);
            for (std::size_t i = 0; i < 6; ++i) {
                peak = std::max(peak, std::abs(s.velocity[i]) / l.joint.maxVelocity[i]);
                peak = std::max(peak, std::abs(s.acceleration[i]) / l.joint.maxAcceleration[i]);
            }
        }
        EXPECT_NEAR(peak, 1.0, 1e-9);
    }
}

TEST(Ptp, SingleAxisMatchesItsOwnTrapezoid) {
    const Limits l = testLimits();
    auto r = planPtp({0, 0, 0, 0, 0, 0}, {0, 0, 0, 2.0, 0, 0}, l.joint);
    ASSERT_TRUE(r.ok());
    EXPECT_NEAR(r.value().duration(), TimingLaw::restToRest(0, 2.0, 2.0, 4.0).duration(), 1e-12);
}

TEST(Ptp, ZeroLengthMove) {
    const Joints q{0.1, 0.2, 0.3, 0.4, 0.5, 0.6};
    auto r = planPtp(q, q, testLimits().joint);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r.value().duration(), 0.0);
    EXPECT_EQ(r.value().sample(0.0).position, q);
    EXPECT_EQ(r.value().sample(1.0).velocity, Joints{});
}

TEST(Ptp, InvalidLimitsRefused) {
    JointLimits l = testLimits().joint;
    l.maxVelocity[2] = 0.0;
    auto r = planPtp({}, {1, 1, 1, 1, 1, 1}, l);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("axis 2"), std::string::npos);
}

// ---------------------------------------------------------------- LIN

const Joints kStart{0.1, -0.2, 0.3, 0.1, 0.2, -0.3};

TEST(Lin, TcpOnStraightLineAndShortestRotation) {
    const Limits l = testLimits();
    const Eigen::Isometry3d goal = poseOf(0.6, 0.2, -0.1, 0.5, -0.3, 0.4);
    auto r = planLin(kStart, goal, gantry(), l);
    ASSERT_TRUE(r.ok()) << r.error().message;
    const Trajectory& t = r.value();
    const Eigen::Isometry3d start = test::gantryForward(kStart);
    const Eigen::Vector3d a = start.translation(), b = goal.translation();
    const double total = angleBetween(start.rotation(), goal.rotation());
    for (int k = 0; k <= 5000; ++k) {
        const double time = t.duration() * k / 5000.0;
        const Eigen::Isometry3d fk = test::gantryForward(t.sample(time).position);
        EXPECT_LT(lineDistance(fk.translation(), a, b), 1e-9);
        const Eigen::Isometry3d p = *t.pose(time);
        EXPECT_LT(lineDistance(p.translation(), a, b), 1e-12);
        // On the geodesic between the two orientations.
        EXPECT_NEAR(angleBetween(start.rotation(), p.rotation()) +
                        angleBetween(p.rotation(), goal.rotation()),
                    total, 1e-9);
        // The joints (interpolated between IK samples) follow the orientation closely.
        EXPECT_LT(angleBetween(fk.rotation(), p.rotation()), 1e-5);
    }
    const Eigen::Isometry3d end = test::gantryForward(t.sample(t.duration()).position);
    EXPECT_LT((end.translation() - b).norm(), 1e-12);
    EXPECT_LT(angleBetween(end.rotation(), goal.rotation()), 1e-12);
    EXPECT_EQ(t.sample(0.0).position, kStart);
    expectWithinJointLimits(t, l.joint);
}

TEST(Lin, ShortestRotationAcrossPi) {
    // Yaw +3.0 -> -3.0: the short way is 2 pi - 6 ~ 0.283 rad through yaw = pi.
    const Joints q{0, 0, 0, 0, 0, 3.0};
    auto r = planLin(q, poseOf(0, 0, 0, 0, 0, -3.0), gantry(), testLimits());
    ASSERT_TRUE(r.ok()) << r.error().message;
    const Trajectory& t = r.value();
    const double shortWay = 2 * std::numbers::pi - 6.0;
    const Eigen::Matrix3d r0 = test::rpy(0, 0, 3.0);
    double maxAngle = 0.0;
    for (int k = 0; k <= 1000; ++k)
        maxAngle =
            std::max(maxAngle, angleBetween(r0, t.pose(t.duration() * k / 1000.0)->rotation()));
    EXPECT_NEAR(maxAngle, shortWay, 1e-9);
    // Mid-way the yaw is pi; the joint keeps going past pi (no 2 pi unwinding).
    const Joints mid = t.sample(t.duration() / 2).position;
    EXPECT_NEAR(mid[5], std::numbers::pi, 1e-6);
    EXPECT_NEAR(t.sample(t.duration()).position[5], 2 * std::numbers::pi - 3.0, 1e-9);
    // Rotation about z only: joint 5 follows the angle one to one, so the angular velocity
    // limit (1 rad/s) and joint 5's acceleration limit (3.5 < 4 rad/s^2) set the duration.
    EXPECT_NEAR(t.duration(), TimingLaw::restToRest(0, shortWay, 1.0, 3.5).duration(), 1e-6);
}

TEST(Lin, CartesianLimitsRespected) {
    const Limits l = testLimits();
    const Eigen::Isometry3d goal = poseOf(-0.5, 0.7, 0.4, -0.2, 0.1, 1.2);
    auto r = planLin(kStart, goal, gantry(), l);
    ASSERT_TRUE(r.ok()) << r.error().message;
    const Trajectory& t = r.value();
    const int n = 20000;
    const double dt = t.duration() / n;
    double peakLin = 0.0, peakAng = 0.0;
    Eigen::Isometry3d prev = *t.pose(0.0);
    double prevV = 0.0, prevW = 0.0;
    for (int k = 1; k <= n; ++k) {
        const Eigen::Isometry3d p = *t.pose(k * dt);
        const double v = (p.translation() - prev.translation()).norm() / dt;
        const double w = angleBetween(prev.rotation(), p.rotation()) / dt;
        EXPECT_LE(v, l.cartesian.maxLinearVelocity * (1 + 1e-6));
        EXPECT_LE(w, l.cartesian.maxAngularVelocity * (1 + 1e-6));
        if (k > 1) {
            EXPECT_LE(std::abs(v - prevV) / dt, l.cartesian.maxLinearAcceleration * (1 + 1e-3));
            EXPECT_LE(std::abs(w - prevW) / dt, l.cartesian.maxAngularAcceleration * (1 + 1e-3));
        }
        peakLin = std::max(peakLin, v / l.cartesian.maxLinearVelocity);
        peakAng = std::max(peakAng, w / l.cartesian.maxAngularVelocity);
        prev = p;
        prevV = v;
        prevW = w;
    }
    // One of the two is the binding limit.
    EXPECT_GT(std::max(peakLin, peakAng), 0.99);
    expectWithinJointLimits(t, l.joint);
}

TEST(Lin, SlowJointsSlowTheTimingLawDown) {
    Limits l = testLimits();
    const Eigen::Isometry3d goal = poseOf(0.3, -0.1, 0.3, 0.9, 0.3, -0.8);
    auto fast = planLin(kStart, goal, gantry(), l);
    l.joint.maxVelocity = {1, 1, 1, 0.05, 0.05, 0.05};
    l.joint.maxAcceleration = {2, 2, 2, 0.02, 0.02, 0.02};
    auto slow = planLin(kStart, goal, gantry(), l);
    ASSERT_TRUE(fast.ok() && slow.ok());
    EXPECT_GT(slow.value().duration(), 5 * fast.value().duration());
    expectWithinJointLimits(slow.value(), l.joint);
}

TEST(Lin, NearSingularButReachablePathAccepted) {
    // x = sin(q0) up to x = 0.9: dq0/dx grows but stays bounded.
    const Limits l = testLimits();
    auto r = planLin({0, 0, 0, 0, 0, 0}, poseOf(0.9, 0, 0, 0, 0, 0), test::stretchedArm(), l);
    ASSERT_TRUE(r.ok()) << r.error().message;
    expectWithinJointLimits(r.value(), l.joint);
    EXPECT_NEAR(r.value().sample(r.value().duration()).position[0], std::asin(0.9), 1e-12);
}

TEST(Lin, OutOfReachRefusedWithFraction) {
    auto r = planLin({0, 0, 0, 0, 0, 0}, poseOf(2.0, 0, 0, 0, 0, 0), gantry(), testLimits());
    ASSERT_FALSE(r.ok());
    ASSERT_TRUE(r.error().fraction.has_value());
    EXPECT_NEAR(*r.error().fraction, 0.5, 1e-9);
    EXPECT_NEAR(r.error().position->x(), 1.0, 1e-9);
    EXPECT_NE(r.error().message.find("out of reach"), std::string::npos);
    EXPECT_NE(r.error().message.find("0.5000"), std::string::npos) << r.error().message;
    EXPECT_NE(r.error().message.find("x=1.000000"), std::string::npos) << r.error().message;
}

TEST(Lin, IkJumpRefusedAsSingular) {
    auto r = planLin({0, 0, 0, 0, 0, 0}, poseOf(1.0, 0, 0, 0, 0, 0), test::jumpingGantry(),
                     testLimits());
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("singularity"), std::string::npos) << r.error().message;
    EXPECT_NEAR(*r.error().fraction, 0.5, 1e-6);
    EXPECT_NEAR(r.error().position->x(), 0.5, 1e-6);
}

TEST(Lin, SmallIkJumpRefused) {
    // A 0.05 rad jump of axis 4 past x = 0.3: small, but no joint can follow it.
    Kinematics k = gantry();
    k.inverse = [](const Eigen::Isometry3d& x, const Joints& seed) {
        auto q = test::gantryInverse(x, seed);
        if (q && x.translation().x() > 0.3) (*q)[4] += 0.05;
        return q;
    };
    auto r = planLin({0, 0, 0, 0, 0, 0}, poseOf(0.8, 0.1, 0, 0, 0, 0.2), k, testLimits());
    ASSERT_FALSE(r.ok());
    EXPECT_NEAR(r.error().position->x(), 0.3, 1e-6) << r.error().message;
}

TEST(Lin, UnboundedJointVelocityMidPathRefused) {
    auto r = planLin({std::cbrt(-0.5), 0, 0, 0, 0, 0}, poseOf(0.5, 0, 0, 0, 0, 0),
                     test::cubeGantry(), testLimits());
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("singularity"), std::string::npos) << r.error().message;
    EXPECT_NEAR(*r.error().fraction, 0.5, 1e-6);
}

TEST(Lin, SingularityAtStretchedArmRefused) {
    auto r =
        planLin({0, 0, 0, 0, 0, 0}, poseOf(1.0, 0, 0, 0, 0, 0), test::stretchedArm(), testLimits());
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("singularity"), std::string::npos) << r.error().message;
    EXPECT_GT(*r.error().fraction, 0.999);
}

TEST(Lin, ZeroLengthMove) {
    auto r = planLin(kStart, test::gantryForward(kStart), gantry(), testLimits());
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_EQ(r.value().duration(), 0.0);
    EXPECT_EQ(r.value().sample(0.0).position, kStart);
}

// ---------------------------------------------------------------- stop / resume

void checkStopResume(const Trajectory& t, const JointLimits& l, double fraction,
                     const std::function<void(const Joints&)>& onPath, const Joints& goal) {
    SCOPED_TRACE(fraction);
    const double tStop = t.duration() * fraction;
    const Trajectory s = t.stop(tStop);
    // No jump in position or velocity.
    const JointSample before = t.sample(tStop);
    const JointSample after = s.sample(0.0);
    for (std::size_t i = 0; i < 6; ++i) {
        EXPECT_EQ(after.position[i], before.position[i]);
        EXPECT_NEAR(after.velocity[i], before.velocity[i], 1e-12);
    }
    // Maximum allowed deceleration: v / a_max.
    const PathState st = t.pathState(tStop);
    EXPECT_NEAR(s.duration(), st.v / t.pathAccelerationLimit(), 1e-9);
    EXPECT_LE(s.endParameter(), 1.0);
    EXPECT_GE(s.endParameter(), st.s);
    // Decelerates continuously and ends at rest on the path.
    double prevV = st.v;
    for (int k = 0; k <= 1000; ++k) {
        const PathState p = s.pathState(s.duration() * k / 1000.0);
        EXPECT_LE(p.v, prevV + 1e-15);
        // Within the path bounds that keep the Cartesian and joint limits.
        EXPECT_LE(p.v, t.pathVelocityLimit() * (1 + 1e-12));
        EXPECT_LE(std::abs(p.a), t.pathAccelerationLimit() * (1 + 1e-12));
        prevV = p.v;
        onPath(s.sample(s.duration() * k / 1000.0).position);
    }
    EXPECT_EQ(s.sample(s.duration()).velocity, Joints{});
    expectWithinJointLimits(s, l, 2000);

    const Trajectory r = s.resume(s.endParameter());
    EXPECT_EQ(r.sample(0.0).position, s.sample(s.duration()).position);
    EXPECT_EQ(r.sample(0.0).velocity, Joints{});
    EXPECT_EQ(r.sample(r.duration()).position, goal);
    for (int k = 0; k <= 1000; ++k) onPath(r.sample(r.duration() * k / 1000.0).position);
    expectWithinJointLimits(r, l, 4000);
}

TEST(StopResume, Ptp) {
    const Limits l = testLimits();
    const Joints a{0, 0, 0, 0, 0, 0}, b{1, -0.5, 0.2, 3, -1, 0.1};
    auto t = planPtp(a, b, l.joint);
    ASSERT_TRUE(t.ok());
    auto onPath = [&](const Joints& q) {
        // Collinear with a -> b, between them.
        const double lambda = (q[3] - a[3]) / (b[3] - a[3]);
        EXPECT_GE(lambda, 0.0);
        EXPECT_LE(lambda, 1.0);
        for (std::size_t i = 0; i < 6; ++i) EXPECT_NEAR(q[i], a[i] + lambda * (b[i] - a[i]), 1e-12);
    };
    for (double f : {0.0, 0.05, 0.3, 0.5, 0.9, 0.999, 1.0})
        checkStopResume(t.value(), l.joint, f, onPath, b);
}

TEST(StopResume, Lin) {
    const Limits l = testLimits();
    const Eigen::Isometry3d goal = poseOf(0.6, 0.2, -0.1, 0.5, -0.3, 0.4);
    auto t = planLin(kStart, goal, gantry(), l);
    ASSERT_TRUE(t.ok());
    const Eigen::Vector3d a = test::gantryForward(kStart).translation();
    auto onPath = [&](const Joints& q) {
        EXPECT_LT(lineDistance(test::gantryForward(q).translation(), a, goal.translation()), 1e-9);
    };
    EXPECT_LE(t.value().pathVelocityLimit() * (goal.translation() - a).norm(),
              l.cartesian.maxLinearVelocity * (1 + 1e-12));
    EXPECT_LE(t.value().pathAccelerationLimit() * (goal.translation() - a).norm(),
              l.cartesian.maxLinearAcceleration * (1 + 1e-12));
    const Joints end = t.value().sample(t.value().duration()).position;
    for (double f : {0.02, 0.3, 0.5, 0.8, 0.97})
        checkStopResume(t.value(), l.joint, f, onPath, end);
    // A stop during a stop (halt while suspending) is still fine.
    const Trajectory s1 = t.value().stop(t.value().duration() * 0.4);
    const Trajectory s2 = s1.stop(s1.duration() * 0.5);
    EXPECT_NEAR(s2.endParameter(), s1.endParameter(), 1e-12);
}

// ---------------------------------------------------------------- determinism

TEST(Determinism, SameInputsBitIdenticalSamples) {
    const Limits l = testLimits();
    const Eigen::Isometry3d goal = poseOf(-0.4, 0.5, 0.1, 0.3, 0.2, -1.0);
    auto sampleAll = [&] {
        std::vector<JointSample> out;
        auto lin = planLin(kStart, goal, gantry(), l);
        auto ptp = planPtp(kStart, {1, 2, 3, 4, 5, 6}, l.joint);
        EXPECT_TRUE(lin.ok() && ptp.ok());
        for (const Trajectory* t : {&lin.value(), &ptp.value()})
            for (int k = 0; k <= 3000; ++k) out.push_back(t->sample(t->duration() * k / 3000.0));
        const Trajectory st = lin.value().stop(lin.value().duration() / 3);
        for (int k = 0; k <= 300; ++k) out.push_back(st.sample(st.duration() * k / 300.0));
        return out;
    };
    const auto x = sampleAll();
    const auto y = sampleAll();
    ASSERT_EQ(x.size(), y.size());
    EXPECT_EQ(std::memcmp(x.data(), y.data(), x.size() * sizeof(JointSample)), 0);
}

}  // namespace
}  // namespace pnp::motion
