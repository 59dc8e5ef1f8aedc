// Turns move requests (targets in the world frame for the robot's tool, or joint targets,
// with per-request limits and axis bounds) into trajectories for the controller: the
// validation every move skill needs, before anything moves. No OPC UA, no vendor.
#pragma once

#include <Eigen/Geometry>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "kinematics/robot_model.hpp"
#include "motion/motion.hpp"
#include "robot/hardware.hpp"

namespace pnp::robot {

struct PlannerConfig {
    kinematics::RobotModel model;
    Eigen::Isometry3d worldToBase = Eigen::Isometry3d::Identity();
    motion::Limits defaults;  // used when a request gives no limit; also the maxima
    motion::LinOptions lin;
};

// Per-request limits as the skills give them; empty = the defaults. Values above the
// defaults (the robot's maxima) or not finite or <= 0 are refused.
struct PtpLimits {
    std::vector<double> maxVelocity;      // 0, 1 (all axes) or 6 values: rad/s
    std::vector<double> maxAcceleration;  // rad/s²
};
struct LinLimits {
    // 0, 1 (linear), 2 (linear, angular) or 4 (x, y, z, angular: linear = min of x, y, z)
    std::vector<double> maxVelocity;      // m/s, rad/s
    std::vector<double> maxAcceleration;  // m/s², rad/s²
};

struct CartesianTarget {
    Eigen::Isometry3d pose;  // the tool frame's pose in the world frame
    Eigen::Isometry3d tool = Eigen::Isometry3d::Identity();  // flange -> tool frame
    std::optional<kinematics::AxisBounds> bounds;
};

namespace detail {
// A pose read by planning threads and set by another (the cell's calibration): copyable so
// that Planner stays a value type.
class GuardedPose {
  public:
    explicit GuardedPose(const Eigen::Isometry3d& pose) : pose_(pose) {}
    GuardedPose(const GuardedPose& other) : pose_(other.get()) {}
    GuardedPose& operator=(const GuardedPose& other) {
        if (this != &other) set(other.get());
        return *this;
    }
    Eigen::Isometry3d get() const {
        std::lock_guard lock(mutex_);
        return pose_;
    }
    void set(const Eigen::Isometry3d& pose) {
        std::lock_guard lock(mutex_);
        pose_ = pose;
    }

  private:
    mutable std::mutex mutex_;
    Eigen::Isometry3d pose_;
};
}  // namespace detail

class Planner {
  public:
    explicit Planner(PlannerConfig config);

    void setWorldToBase(const Eigen::Isometry3d& worldToBase);
    Eigen::Isometry3d worldToBase() const;
    const kinematics::RobotModel& model() const;

    // Each checks everything first (finite values, array lengths, limits, reach, joint
    // limits, axis bounds, singularities along a line) and names the problem in Error.
    Result<motion::Trajectory> cartesianPtp(const Joints& current, const CartesianTarget& target,
                                            const PtpLimits& limits) const;
    Result<motion::Trajectory> cartesianLinear(const Joints& current, const CartesianTarget& target,
                                               const LinLimits& limits) const;
    Result<motion::Trajectory> jointPtp(const Joints& current, const std::vector<double>& target,
                                        const PtpLimits& limits) const;
    // The TCP on a straight line to forward(target), ending in exactly that configuration
    // (refused when the line would end in another one).
    Result<motion::Trajectory> jointLinear(const Joints& current, const std::vector<double>& target,
                                           const Eigen::Isometry3d& tool,
                                           const LinLimits& limits) const;
    // A joint target for a position stream: finite, 6 values, within the joint limits.
    Result<Joints> checkJoints(const std::vector<double>& target) const;

    // The tool frame's pose in the world frame at q.
    Eigen::Isometry3d toolPose(const Joints& q, const Eigen::Isometry3d& tool) const;

    // Added: the pieces of the requests above, for skills that check before they plan.
    // The joints that put the target's tool frame at its pose, nearest `current`.
    Result<Joints> solve(const Joints& current, const CartesianTarget& target) const;
    // The request's limits resolved against the defaults (the maxima), checked.
    Result<motion::JointLimits> jointLimits(const PtpLimits& limits) const;
    Result<motion::CartesianLimits> cartesianLimits(const LinLimits& limits) const;

  private:
    PlannerConfig config_;  // config_.worldToBase is not used: worldToBase_ is the live one
    detail::GuardedPose worldToBase_;
};

}  // namespace pnp::robot
