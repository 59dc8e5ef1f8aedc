#include "ua/spatial/spatial.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace pnp::ua::spatial {

Eigen::Isometry3d toIsometry(const ThreeDFrame& f) {
    const auto& p = f.cartesianCoordinates;
    const auto& o = f.orientation;
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = (Eigen::AngleAxisd(o.c, Eigen::Vector3d::UnitZ()) *
                     Eigen::AngleAxisd(o.b, Eigen::Vector3d::UnitY()) *
                     Eigen::AngleAxisd(o.a, Eigen::Vector3d::UnitX()))
                        .toRotationMatrix();
    pose.translation() = Eigen::Vector3d(p.x, p.y, p.z);
    return pose;
}

ThreeDFrame toFrame(const Eigen::Isometry3d& pose) {
    const Eigen::Matrix3d r = pose.linear();
    ThreeDFrame f;
    f.cartesianCoordinates = {pose.translation().x(), pose.translation().y(),
                              pose.translation().z()};
    // R = Rz(c) Ry(b) Rx(a): r20 = -sin b. At the gimbal lock (cos b ≈ 0) a is set to 0 and
    // c carries the whole rotation about z, so the frame still converts back exactly.
    const double sb = -r(2, 0);
    const double b = std::asin(std::clamp(sb, -1.0, 1.0));
    double a = 0.0;
    double c = 0.0;
    if (std::abs(std::cos(b)) > 1e-9) {
        a = std::atan2(r(2, 1), r(2, 2));
        c = std::atan2(r(1, 0), r(0, 0));
    } else {
        c = std::atan2(-r(0, 1), r(1, 1));
    }
    f.orientation = {a, b, c};
    return f;
}

Eigen::Vector3d toVector(const ThreeDVector& v) { return {v.x, v.y, v.z}; }

ThreeDVector toThreeDVector(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

bool finite(const ThreeDFrame& f) {
    const auto& p = f.cartesianCoordinates;
    const auto& o = f.orientation;
    return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z) && std::isfinite(o.a) &&
           std::isfinite(o.b) && std::isfinite(o.c);
}

std::string positionText(const Eigen::Isometry3d& pose) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "(%.3f, %.3f, %.3f)", pose.translation().x(),
                  pose.translation().y(), pose.translation().z());
    return buf;
}

}  // namespace pnp::ua::spatial
