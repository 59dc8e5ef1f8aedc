// The OPC UA face of any robot (docs: src/device/robot/README.md): an OPC 40010-1
// MotionDeviceSystem whose MotionDevice is a skill controller (SkillMotionDeviceType) with the
// six move skills of urn:pnp:ua:skills:robotics, driven by a vendor-neutral robot::Controller
// and robot::Planner. Nothing here names a vendor.
//
//   robot::Controller controller(hardware, {...});
//   robot::Planner planner({...});
//   controller.start(deadline);
//   ua::server::Server server(config);
//   RobotDevice device(server, controller, planner, {.name = "UR5", .identity = identityOf(hw)});
//   server.start();
//
// Build it before Server::start(); destroy it before the Server and the Controller (it halts
// running skills, waits until the arm is at rest and stops its update thread).
//
// Threads: skills run on their workers (skill runtime); the controller's onState callback only
// copies the latest sample; a thread of this class writes the Robotics nodes at a bounded
// rate; method handlers and write callbacks (SetTool, ClearTool, WorldToRobotBase, streamed
// targets) run on the network thread and never wait for planning or motion.
#pragma once

#include <Eigen/Geometry>
#include <chrono>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "robot/controller.hpp"
#include "robot/planner.hpp"
#include "skill/server/controller.hpp"
#include "ua/server/server.hpp"

namespace pnp::device::robot {

namespace rb = pnp::robot;

// A set-up error (model not loaded, bad options); the message names the problem.
class RobotDeviceError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

// What the Robotics model shows about the arm and its controller.
struct DeviceIdentity {
    std::string manufacturer;
    std::string model;  // e.g. "UR5"
    std::string serialNumber;
    std::string productCode;  // empty: the model
};
DeviceIdentity identityOf(const rb::HardwareInterface& hardware);

struct RobotDeviceOptions {
    // BrowseNames: DeviceSet/<name>System, .../MotionDevices/<name> (the skill controller),
    // Controllers/<name>Controller, SafetyStates/<name>SafetyState.
    std::string name = "Robot";
    DeviceIdentity identity;
    // How often the Robotics nodes (axes, safety) are written at most: the controller
    // samples at 500 Hz; OPC UA clients sample far slower.
    std::chrono::milliseconds publishPeriod{20};
    // A skill waits for its motion in slices of this length (progress, Halt, deadline).
    std::chrono::milliseconds waitSlice{10};
    // After a Halt: the time the arm gets to come to rest before the run gives up waiting.
    std::chrono::milliseconds restTimeout{10000};
    ua::UInt16 namespaceIndex = 1;
};

// The motion limits a planner defaults to for an arm: its joint limits, and Cartesian
// limits of motion::CartesianLimits{}.
motion::Limits defaultLimits(const kinematics::RobotModel& model);

// The skills' BrowseNames below MotionDevices/<name>/Skills.
namespace skill_names {
inline constexpr const char* CartesianPtpMove = "CartesianPtpMove";
inline constexpr const char* CartesianLinearMove = "CartesianLinearMove";
inline constexpr const char* JointPtpMove = "JointPtpMove";
inline constexpr const char* JointLinearMove = "JointLinearMove";
inline constexpr const char* CartesianLinearForceMove = "CartesianLinearForceMove";
inline constexpr const char* PositionStream = "PositionStream";
}  // namespace skill_names

class RobotDevice {
  public:
    // Loads the models (skills, Robotics, DI) and builds the nodes and skills. Throws
    // RobotDeviceError (or skill::server::SkillError / ua::server::NodeSetError).
    RobotDevice(ua::server::Server& server, rb::Controller& controller, rb::Planner& planner,
                RobotDeviceOptions options = {});
    ~RobotDevice();
    RobotDevice(const RobotDevice&) = delete;
    RobotDevice& operator=(const RobotDevice&) = delete;

    const ua::NodeId& systemNode() const;        // DeviceSet/<name>System
    const ua::NodeId& motionDeviceNode() const;  // the SkillMotionDeviceType instance
    const ua::NodeId& controllerNode() const;    // Controllers/<name>Controller
    const ua::NodeId& safetyStateNode() const;   // SafetyStates/<name>SafetyState
    // Axes/Axis<i+1>/ParameterSet/ActualPosition, i = 0..5.
    const ua::NodeId& actualPositionNode(int axis) const;
    // A skill by its BrowseName (skill_names); null if there is none.
    ua::NodeId skillNode(const std::string& name) const;
    std::vector<skill::server::SkillHandle> skills() const;

    // The frames the skills use now (thread-safe).
    Eigen::Isometry3d worldToBase() const;
    std::string activeTool() const;  // "" = the flange

    struct Impl;

  private:
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::device::robot
