// The robot's hardware interface (as ros2_control's): the small, typed boundary between the
// vendor-neutral control loop (robot::Controller) and one vendor's controller protocol
// (device/ur: RTDE). One implementation per vendor; nothing above it names a vendor.
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <chrono>
#include <cstdint>
#include <string>

#include "base/result.hpp"
#include "kinematics/robot_model.hpp"

namespace pnp::robot {

using Joints = kinematics::Joints;
using Clock = std::chrono::steady_clock;
using Deadline = Clock::time_point;

struct Error {
    std::string message;
};

template <class T>
using Result = base::Result<T, Error>;

struct Done {};  // the value of a Result that carries none

// What the controller reports about its safety system and program.
enum class SafetyState { kNormal, kReduced, kProtectiveStop, kEmergencyStop, kFault, kUnknown };
enum class ProgramState { kRunning, kPaused, kStopped, kUnknown };

// One sample of the robot, as its controller reports it. Frames: the robot's base frame.
struct State {
    Clock::time_point received{};  // when the sample arrived here
    double controllerTime = 0.0;   // s, the controller's own clock
    std::uint64_t sequence = 0;    // samples read since connect()
    Joints q{};                    // actual joint positions, rad
    Joints qd{};                   // actual joint velocities, rad/s
    Joints targetQ{};              // what the controller is servoing to
    Eigen::Isometry3d flange = Eigen::Isometry3d::Identity();  // base -> flange
    std::array<double, 6> tcpSpeed{};  // base frame: m/s then rad/s
    std::array<double, 6> force{};     // at the TCP, base frame: N then N·m
    SafetyState safety = SafetyState::kUnknown;
    ProgramState program = ProgramState::kUnknown;
    // True while the controller follows our joint commands (its servo program runs and
    // the watchdog has not tripped); false: commands are ignored until it is re-armed.
    bool following = false;
};

// A joint command for one control cycle: servo to q (already within the limits: the
// controller clamps speed and acceleration but a jump is a bug upstream), or hold still.
struct Command {
    bool servo = false;  // false: stop following (the controller decelerates and holds)
    Joints q{};
};

class HardwareInterface {
  public:
    virtual ~HardwareInterface() = default;

    // Connects and sets the controller up for streaming (handshake, recipes, start).
    virtual Result<Done> connect(Deadline deadline) = 0;
    virtual void disconnect() = 0;
    // Blocks until the next sample: the controller's cycle paces the control loop.
    virtual Result<State> read(Deadline deadline) = 0;
    virtual Result<Done> write(const Command& command, Deadline deadline) = 0;

    virtual double cycleTime() const = 0;  // s between samples, e.g. 0.002 at 500 Hz
    // The arm's model as this hardware describes it (kinematics and joint limits).
    virtual const kinematics::RobotModel& model() const = 0;
    // For the Robotics information model: manufacturer, model, serial number...
    virtual std::string manufacturer() const = 0;
    virtual std::string modelName() const = 0;
    virtual std::string serialNumber() const = 0;
    virtual std::string endpoint() const = 0;  // e.g. "rtde://127.0.0.1:30004"
};

}  // namespace pnp::robot
