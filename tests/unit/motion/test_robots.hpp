// Test robots for pnp_motion: a 6-axis gantry (x, y, z = q0, q1, q2; rotation =
// Rz(q5) Ry(q4) Rx(q3)) with an analytic inverse, and variants that are singular or jump.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>

#include "motion/motion.hpp"

namespace pnp::motion::test {

inline Eigen::Matrix3d rpy(double r, double p, double y) {
    return (Eigen::AngleAxisd(y, Eigen::Vector3d::UnitZ()) *
            Eigen::AngleAxisd(p, Eigen::Vector3d::UnitY()) *
            Eigen::AngleAxisd(r, Eigen::Vector3d::UnitX()))
        .toRotationMatrix();
}

inline Eigen::Isometry3d gantryForward(const Joints& q) {
    Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
    x.translation() = Eigen::Vector3d(q[0], q[1], q[2]);
    x.linear() = rpy(q[3], q[4], q[5]);
    return x;
}

// a + 2 pi n nearest to seed: revolute axes without end stops.
inline double nearest(double a, double seed) {
    constexpr double kTwoPi = 2.0 * std::numbers::pi;
    return a + kTwoPi * std::round((seed - a) / kTwoPi);
}

// Workspace: the box |x|, |y|, |z| <= 1.
inline std::optional<Joints> gantryInverse(const Eigen::Isometry3d& x, const Joints& seed) {
    const Eigen::Vector3d p = x.translation();
    if (std::abs(p.x()) > 1.0 || std::abs(p.y()) > 1.0 || std::abs(p.z()) > 1.0)
        return std::nullopt;
    const Eigen::Matrix3d r = x.rotation();
    const double pitch = std::atan2(-r(2, 0), std::hypot(r(0, 0), r(1, 0)));
    const double yaw = std::atan2(r(1, 0), r(0, 0));
    const double roll = std::atan2(r(2, 1), r(2, 2));
    // Second solution (pi - pitch, roll + pi, yaw + pi); take the one nearer the seed.
    const double pi = std::numbers::pi;
    Joints a{p.x(),
             p.y(),
             p.z(),
             nearest(roll, seed[3]),
             nearest(pitch, seed[4]),
             nearest(yaw, seed[5])};
    Joints b{p.x(),
             p.y(),
             p.z(),
             nearest(roll + pi, seed[3]),
             nearest(pi - pitch, seed[4]),
             nearest(yaw + pi, seed[5])};
    auto dist = [&](const Joints& q) {
        double d = 0.0;
        for (int i = 3; i < 6; ++i) d += std::abs(q[i] - seed[i]);
        return d;
    };
    return dist(a) <= dist(b) ? a : b;
}

inline Kinematics gantry() { return {gantryForward, gantryInverse}; }

// Gantry whose IK flips axis 3 by a full turn once x > 0.5 (a configuration change: the
// same pose, but a jump no joint could follow).
inline Kinematics jumpingGantry() {
    return {gantryForward, [](const Eigen::Isometry3d& x, const Joints& seed) {
                auto q = gantryInverse(x, seed);
                if (q && x.translation().x() > 0.5) {
                    (*q)[3] = nearest((*q)[3], seed[3]);
                    if (std::abs((*q)[3] - seed[3]) < 1.0) (*q)[3] += 2.0 * std::numbers::pi;
                }
                return q;
            }};
}

// x = q0^3: dq0/dx = 1 / (3 x^(2/3)) is unbounded at x = 0 (a singularity inside the path).
inline Kinematics cubeGantry() {
    return {[](const Joints& q) {
                Joints g = q;
                g[0] = q[0] * q[0] * q[0];
                return gantryForward(g);
            },
            [](const Eigen::Isometry3d& x, const Joints& seed) {
                auto q = gantryInverse(x, seed);
                if (q) (*q)[0] = std::cbrt(x.translation().x());
                return q;
            }};
}

// x = sin(q0): stretched "arm" at x = 1, where dq0/dx is unbounded.
inline Kinematics stretchedArm() {
    return {[](const Joints& q) {
                Joints g = q;
                g[0] = std::sin(q[0]);
                return gantryForward(g);
            },
            [](const Eigen::Isometry3d& x, const Joints& seed) {
                auto q = gantryInverse(x, seed);
                if (q) (*q)[0] = std::asin(std::clamp(x.translation().x(), -1.0, 1.0));
                return q;
            }};
}

inline Eigen::Isometry3d poseOf(double x, double y, double z, double r, double p, double yw) {
    return gantryForward({x, y, z, r, p, yw});
}

}  // namespace pnp::motion::test
