#pragma once

#include <array>
#include <numbers>
#include <string>

namespace pnp::kinematics {

// Joint positions of a 6-axis arm in rad. A plain array (not an Eigen vector): a value type
// with no alignment rules, cheap to copy and to keep in std::vector.
inline constexpr int kAxes = 6;
using Joints = std::array<double, kAxes>;

// One row of a standard (distal) Denavit-Hartenberg table:
// T(i-1 -> i) = Rz(q + thetaOffset) * Tz(d) * Tx(a) * Rx(alpha). Lengths in m, angles in rad.
struct DhRow {
    double a = 0.0;
    double d = 0.0;
    double alpha = 0.0;
    double thetaOffset = 0.0;
};

struct JointLimits {
    double minPosition = -2.0 * std::numbers::pi;  // rad
    double maxPosition = 2.0 * std::numbers::pi;   // rad
    double maxVelocity = std::numbers::pi;         // rad/s
    double maxAcceleration = std::numbers::pi;     // rad/s^2
};

// The kinematic description of a 6-axis arm: base frame -> flange (tool0). A tool's
// flange-to-TCP offset is not part of it: callers compose poses (pose_tcp = flange * tcp).
struct RobotModel {
    std::string name;
    std::array<DhRow, kAxes> dh{};
    std::array<JointLimits, kAxes> limits{};
};

// Universal Robots arms, DH values as published by UR. Limits: ±2π, π rad/s (180°/s, the
// UR5 base/shoulder/elbow rating; the wrists are faster but we keep one figure per arm),
// π rad/s² as a conservative default acceleration (UR's own default is lower for joints
// moves; motion planning may scale it down further). The UR3 wrists' 360°/s are ignored too.
RobotModel ur3();
RobotModel ur5();
RobotModel ur10();

// Extra per-axis position bounds of one request (e.g. cable routing, cell layout). They
// narrow the joint limits, never widen them.
struct AxisBounds {
    Joints min;
    Joints max;
};

}  // namespace pnp::kinematics
