#pragma once

#include <Eigen/Geometry>
#include <kdl/chain.hpp>
#include <kdl/frames.hpp>
#include <span>
#include <string>

#include "kinematics/result.hpp"
#include "kinematics/robot_model.hpp"

namespace pnp::kinematics {

// A KDL chain of six revolute (RotZ) segments built from the model's DH table: base ->
// flange, the same frames as forward(). For generic robots and to cross-check the closed form.
KDL::Chain toKdlChain(const RobotModel& model);

// The chain from `baseLink` to `tipLink` of a URDF file (kdl_parser). Errors: kFileNotFound,
// kParseError, kLinkNotFound. Never throws.
Result<KDL::Chain> chainFromUrdf(const std::string& path, const std::string& baseLink,
                                 const std::string& tipLink);

Eigen::Isometry3d toEigen(const KDL::Frame& frame);
KDL::Frame toKdl(const Eigen::Isometry3d& pose);

// FK of any KDL chain (KDL::ChainFkSolverPos_recursive). q must hold one value per joint of
// the chain; kInvalidArgument otherwise.
Result<Eigen::Isometry3d> forwardKdl(const KDL::Chain& chain, std::span<const double> q);

}  // namespace pnp::kinematics
