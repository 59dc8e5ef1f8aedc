#pragma once

#include <cassert>
#include <string>
#include <utility>
#include <variant>

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

// A value or an Error (std::expected is C++23). Nothing in this module throws past its API.
template <class T>
class Result {
  public:
    Result(T value) : v_(std::move(value)) {}      // NOLINT(google-explicit-constructor)
    Result(Error error) : v_(std::move(error)) {}  // NOLINT(google-explicit-constructor)

    bool ok() const { return v_.index() == 0; }
    explicit operator bool() const { return ok(); }

    const T& value() const& {
        assert(ok());
        return std::get<0>(v_);
    }
    T& value() & {
        assert(ok());
        return std::get<0>(v_);
    }
    T&& value() && {
        assert(ok());
        return std::get<0>(std::move(v_));
    }
    const T& operator*() const& { return value(); }
    T& operator*() & { return value(); }
    const T* operator->() const { return &value(); }
    T* operator->() { return &value(); }

    const Error& error() const {
        assert(!ok());
        return std::get<1>(v_);
    }

  private:
    std::variant<T, Error> v_;
};

}  // namespace pnp::kinematics
