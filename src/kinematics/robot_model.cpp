#include "kinematics/robot_model.hpp"

#include <numbers>

namespace pnp::kinematics {

namespace {

constexpr double kPi = std::numbers::pi;

// The UR family shares alpha and the zero a1, d2, d3, a4..a6; only the lengths differ.
RobotModel urArm(std::string name, double d1, double a2, double a3, double d4, double d5,
                 double d6) {
    RobotModel m;
    m.name = std::move(name);
    m.dh = {{
        {0.0, d1, kPi / 2, 0.0},
        {a2, 0.0, 0.0, 0.0},
        {a3, 0.0, 0.0, 0.0},
        {0.0, d4, kPi / 2, 0.0},
        {0.0, d5, -kPi / 2, 0.0},
        {0.0, d6, 0.0, 0.0},
    }};
    return m;  // limits: the JointLimits defaults (±2π, π rad/s, π rad/s²)
}

}  // namespace

RobotModel ur3() { return urArm("UR3", 0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819); }

RobotModel ur5() { return urArm("UR5", 0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823); }

RobotModel ur10() { return urArm("UR10", 0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922); }

}  // namespace pnp::kinematics
