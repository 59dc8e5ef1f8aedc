// Gantry kinematics for the motion benchmark: x, y, z = q0, q1, q2; rotation =
// Rz(q5) Ry(q4) Rx(q3); analytic inverse (the workspace is the box |x|, |y|, |z| <= 1).
#pragma once

#include <Eigen/Geometry>
#include <cmath>
#include <numbers>
#include <optional>

#include "motion/motion.hpp"

namespace pnp::motion::bench {

inline Eigen::Isometry3d gantryForward(const Joints& q) {
    Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
    x.translation() = Eigen::Vector3d(q[0], q[1], q[2]);
    x.linear() = (Eigen::AngleAxisd(q[5], Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(q[4], Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(q[3], Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    return x;
}

inline std::optional<Joints> gantryInverse(const Eigen::Isometry3d& x, const Joints& seed) {
    const Eigen::Vector3d p = x.translation();
    if (std::abs(p.x()) > 1.0 || std::abs(p.y()) > 1.0 || std::abs(p.z()) > 1.0)
        return std::nullopt;
    const Eigen::Matrix3d r = x.rotation();
    auto nearest = [](double a, double s) {
        constexpr double kTwoPi = 2.0 * std::numbers::pi;
        return a + kTwoPi * std::round((s - a) / kTwoPi);
    };
    // One Euler branch only (pitch in [-pi/2, pi/2]): enough away from the gimbal lock.
    return Joints{p.x(),
                  p.y(),
                  p.z(),
                  nearest(std::atan2(r(2, 1), r(2, 2)), seed[3]),
                  std::atan2(-r(2, 0), std::hypot(r(0, 0), r(1, 0))),
                  nearest(std::atan2(r(1, 0), r(0, 0)), seed[5])};
}

inline Kinematics gantry() { return {gantryForward, gantryInverse}; }

}  // namespace pnp::motion::bench
