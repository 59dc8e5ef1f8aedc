#pragma once

#include <Eigen/Geometry>
#include <cmath>
#include <numbers>
#include <random>

#include "kinematics/robot_model.hpp"

namespace pnp::kinematics::test {

// Largest difference of position (m) and rotation-matrix entries (≈ rad for small errors).
inline double poseError(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
    return std::max((a.translation() - b.translation()).cwiseAbs().maxCoeff(),
                    (a.linear() - b.linear()).cwiseAbs().maxCoeff());
}

// Largest axis difference modulo 2π.
inline double angleError(const Joints& a, const Joints& b) {
    double worst = 0.0;
    for (int i = 0; i < kAxes; ++i) {
        worst = std::max(worst, std::abs(std::remainder(a[i] - b[i], 2.0 * std::numbers::pi)));
    }
    return worst;
}

inline Joints randomJoints(std::mt19937_64& rng, double range = std::numbers::pi) {
    std::uniform_real_distribution<double> dist(-range, range);
    Joints q;
    for (double& v : q) v = dist(rng);
    return q;
}

}  // namespace pnp::kinematics::test
