#pragma once

#include <Eigen/Geometry>
#include <optional>
#include <vector>

#include "kinematics/result.hpp"
#include "kinematics/robot_model.hpp"

namespace pnp::kinematics {

// The transform of one DH row at joint position q (thetaOffset is added here).
Eigen::Isometry3d dhTransform(const DhRow& row, double q);

// Closed-form forward kinematics: base -> flange, the product of the six DH transforms.
// Works for any DH table; no limit check (FK of any joint vector is defined).
Eigen::Isometry3d forward(const RobotModel& model, const Joints& q);

// True when the DH table has the UR structure the closed-form IK needs: a1 = d2 = d3 = a4 =
// a5 = a6 = 0, a2, a3, d6 != 0, alpha = {π/2, 0, 0, π/2, -π/2, 0}. Offsets and lengths free.
bool hasUrClosedForm(const RobotModel& model);

// Every IK solution of the flange pose (0..8: shoulder left/right × wrist flip × elbow
// up/down), without duplicates, each within the joint limits: every angle is the
// 2π-equivalent inside the limits nearest to `seed` (solutions with no such equivalent are
// dropped). Wrist singularity (sin q5 ≈ 0: axes 4 and 6 aligned, only q4 + q6 is defined):
// q6 is set to seed[5] and q4 takes the rest, so a robot standing still keeps its q6 (likewise
// q1 = seed[0] when q1 is free: d4 = 0 and the wrist centre on the base axis).
// Empty for a model without hasUrClosedForm() or a non-finite pose.
std::vector<Joints> solveAll(const RobotModel& model, const Eigen::Isometry3d& flange,
                             const Joints& seed = {});

inline constexpr Joints kUnitWeights{1.0, 1.0, 1.0, 1.0, 1.0, 1.0};

// Σ w_i (a_i - b_i)²: the distance solveNearest minimises (plain, no wrapping: the
// candidates have already been moved to their 2π-equivalent nearest the seed).
double jointDistance(const Joints& a, const Joints& b, const Joints& weights = kUnitWeights);

// The IK solution nearest `seed` (jointDistance with `weights`) within the joint limits and,
// when given, the axis bounds. Errors, checked in this order: kUnsupportedModel,
// kInvalidArgument (non-finite pose or seed, empty bounds), kOutOfReach (no geometric
// solution), kOutsideJointLimits, kOutsideAxisBounds.
Result<Joints> solveNearest(const RobotModel& model, const Eigen::Isometry3d& flange,
                            const Joints& seed,
                            const std::optional<AxisBounds>& bounds = std::nullopt,
                            const Joints& weights = kUnitWeights);

}  // namespace pnp::kinematics
