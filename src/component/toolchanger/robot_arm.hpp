// The robot as the tool changer component uses it: its CartesianLinearMove skill (found by
// the skill detector; any robot of the skill model) and the SetTool / ClearTool methods of
// its motion device (the skill controller the move skill belongs to). Targets are flange
// poses in the world frame once the active tool is cleared.
#pragma once

#include <Eigen/Geometry>
#include <chrono>
#include <memory>
#include <optional>
#include <stop_token>
#include <string>
#include <vector>

#include "skill/client/typed_clients.hpp"
#include "skill/detector/skill_detector.hpp"

namespace pnp::component::toolchanger {

struct MoveOutcome {
    bool completed = false;
    bool aborted = false;  // halted (by us on cancel, or by someone else)
    std::string message;   // why not completed
};

class RobotArm {
  public:
    // Connects to the skill's server and discovers the skill and the tool methods. Throws
    // ua::client::Error / std::runtime_error.
    RobotArm(const skill::detector::DetectedSkill& moveSkill, std::chrono::milliseconds timeout);
    ~RobotArm();
    RobotArm(const RobotArm&) = delete;
    RobotArm& operator=(const RobotArm&) = delete;

    const std::string& endpointUrl() const { return url_; }
    const std::string& name() const { return name_; }  // the motion device's name

    // A linear move of the active tool frame (the flange after clearTool("")) to `target`
    // (world frame). maxVelocity: {} (the robot's default) or {m/s, rad/s}. `cancel` halts
    // the robot's skill (it brakes along its path) and returns aborted.
    MoveOutcome moveLinear(const Eigen::Isometry3d& target, const std::vector<double>& maxVelocity,
                           std::chrono::milliseconds timeout, std::stop_token cancel);
    // SetTool(name, frame) / ClearTool(name) of the motion device; "" = why not.
    std::string setTool(const std::string& name, const Eigen::Isometry3d& flangeToTool);
    std::string clearTool(const std::string& name);  // "": deactivate the active tool

    // The motion device's ActualFlangePose (a pnp extension of the Robotics model: the
    // flange's actual pose in the world frame); nullopt with the reason in `error` when the
    // robot has no such variable or its value is not Good (no link, no sample yet).
    std::optional<Eigen::Isometry3d> flangePose(std::string& error);

  private:
    std::string url_;
    std::string name_;
    std::shared_ptr<ua::client::Client> client_;
    std::unique_ptr<skill::client::CartesianLinearMoveSkillClient> move_;
    ua::NodeId controller_, setTool_, clearTool_, flangePose_;
    std::chrono::milliseconds timeout_;
};

}  // namespace pnp::component::toolchanger
