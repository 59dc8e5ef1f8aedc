// The Universal Robots hardware interface: robot::HardwareInterface over RTDE (protocol
// version 2, port 30004). The robot runs our servo URScript (models/urscript/pnp_servo.script):
// while input_int_register_0 = 1 it servos (servoj) to the joint targets in
// input_double_register_0..5, and its watchdog stops the arm when the inputs stop coming.
// This class only maps that contract to the vendor-neutral State / Command; the control
// loop (robot::Controller) owns the timing. Not thread-safe: one thread (the loop) uses it.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "kinematics/robot_model.hpp"
#include "robot/hardware.hpp"
#include "rtde/client.hpp"

namespace pnp::device::ur {

// The vendor-neutral robot layer (pnp::robot), not its OPC UA face (pnp::device::robot).
namespace robot = ::pnp::robot;

struct UrConfig {
    std::string host = "127.0.0.1";
    std::uint16_t port = rtde::kDefaultPort;  // 30004
    double frequency = 500.0;  // Hz of the output recipe: 500 e-Series, at most 125 on a CB3
    kinematics::RobotModel model = kinematics::ur5();
    // Each handshake request within connect() waits at most this long (and never beyond
    // connect()'s deadline).
    std::chrono::milliseconds requestTimeout{1000};
    std::string serialNumber;  // not on RTDE (the dashboard server has it); "" = unknown
};

// "ur3", "ur5", "ur10" (any case, an "e" suffix allowed: "UR5e"); nullopt otherwise.
std::optional<kinematics::RobotModel> modelByName(std::string_view name);

// RTDE codes (UR's RTDE guide), public for the tests and the simulator's counterpart.
robot::SafetyState safetyFromUr(std::int32_t safetyMode);
robot::ProgramState programFromUr(std::uint32_t runtimeState);
inline constexpr std::int32_t kRobotModeRunning = 7;

class UrHardware final : public robot::HardwareInterface {
  public:
    explicit UrHardware(UrConfig config);
    ~UrHardware() override;

    robot::Result<robot::Done> connect(robot::Deadline deadline) override;
    void disconnect() override;
    robot::Result<robot::State> read(robot::Deadline deadline) override;
    robot::Result<robot::Done> write(const robot::Command& command,
                                     robot::Deadline deadline) override;

    double cycleTime() const override { return 1.0 / config_.frequency; }
    const kinematics::RobotModel& model() const override { return config_.model; }
    std::string manufacturer() const override { return "Universal Robots"; }
    std::string modelName() const override { return config_.model.name; }
    std::string serialNumber() const override;
    std::string endpoint() const override;

    // The controller's software version after connect() (e.g. 5.15.0.0), else nullopt.
    std::optional<rtde::ControllerVersion> controllerVersion() const { return version_; }
    // The last text message the controller sent (warnings, errors), for diagnostics.
    std::string lastControllerMessage() const { return lastText_; }

  private:
    robot::Result<robot::Done> setup(robot::Deadline deadline);
    robot::Deadline requestDeadline(robot::Deadline deadline) const;
    robot::Error fail(const std::string& what, const rtde::Status& status) const;

    UrConfig config_;
    rtde::Client client_;
    std::optional<rtde::ControllerVersion> version_;
    std::uint8_t outputRecipe_ = 0;
    std::uint8_t inputRecipe_ = 0;
    std::uint64_t sequence_ = 0;
    double answering_ = 0.0;  // timestamp of the last state read (input_double_register_6)
    std::string lastText_;
};

}  // namespace pnp::device::ur
