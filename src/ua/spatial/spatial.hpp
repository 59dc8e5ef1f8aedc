// OPC UA spatial data types (OPC 10000-5 §12.2x: 3DFrame, 3DVector) <-> Eigen. Part 5 leaves
// the orientation convention to the application; pnp's, everywhere (skills, the simulator's
// ground truth, the cell file): A, B, C in radians, rotations about the fixed axes X, Y, Z in
// that order, i.e. R = Rz(C) · Ry(B) · Rx(A) (URDF's roll-pitch-yaw). Positions in metres.
#pragma once

#include <Eigen/Geometry>
#include <optional>
#include <string>

#include "ua/types/ns0_types_model.hpp"

namespace pnp::ua::spatial {

Eigen::Isometry3d toIsometry(const ThreeDFrame& frame);
ThreeDFrame toFrame(const Eigen::Isometry3d& pose);  // B in [-π/2, π/2]

Eigen::Vector3d toVector(const ThreeDVector& v);
ThreeDVector toThreeDVector(const Eigen::Vector3d& v);

// True when every number of the frame is finite.
bool finite(const ThreeDFrame& frame);

// "(x, y, z)" of a pose's position in metres to the millimetre, for messages and logs.
std::string positionText(const Eigen::Isometry3d& pose);

}  // namespace pnp::ua::spatial
