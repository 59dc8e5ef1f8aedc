#pragma once

#include <string>

#include "base/result.hpp"

namespace pnp::kinematics {

// Why a call failed. The code is for programs, the message for people.
enum class ErrorCode {
    kOutOfReach,          // no geometric solution: the pose is outside the workspace
    kOutsideJointLimits,  // solutions exist, none within the robot's joint limits
    kOutsideAxisBounds,   // solutions within the joint limits exist, none within the bounds
    kUnsupportedModel,    // the closed form needs a UR-type DH table
    kInvalidArgument,     // NaN pose, empty bounds, wrong joint count ...
    kFileNotFound,        // URDF file missing or unreadable
    kParseError,          // URDF could not be parsed into a KDL tree
    kLinkNotFound,        // base or tip link not in the URDF (or not connected)
};

struct Error {
    ErrorCode code;
    std::string message;
};

// A value or an Error: nothing in this module throws past its API.
template <class T>
using Result = base::Result<T, Error>;

}  // namespace pnp::kinematics
