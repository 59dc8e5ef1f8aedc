// The Robotiq 2F-85 adaptive gripper as a gripper::GripperHardware: Modbus RTU over its
// serial line (RS-485 via a USB converter, or the simulator's pseudo-terminal) with libmodbus,
// 115200 8N1, slave 9 by default; FC16 to the output registers at 0x03E8, FC04 from the input
// registers at 0x07D0 (robotiq_registers.hpp, the manual's §4).
//
// Every transaction has a response timeout within the caller's deadline (a dead line is
// kNoDevice); while a motion runs the status is polled at the device's 200 Hz. Grasp closes
// (rGTO, rPR 255, rSP / rFR from speed / force) and succeeds only when the fingers stopped on
// an object (gOBJ 2); closing to the end (gOBJ 3) is kRefused "no object between the
// fingers". Release opens fully; MoveGripper goes to a width (linear over the 85 mm stroke
// between the calibration's positions); `cancel` stops the fingers (rGTO 0). Not
// thread-safe: one caller at a time (gripper::HardwareAccess).
#pragma once

#include <Eigen/Geometry>
#include <chrono>
#include <cstdint>
#include <string>

#include "device/gripper/gripper_hardware.hpp"
#include "device/robotiq/robotiq_registers.hpp"

// libmodbus's context.
struct _modbus;

namespace pnp::device::robotiq {

namespace gripper = pnp::device::gripper;

struct RobotiqConfig {
    std::string serialPath = {};  // e.g. /dev/ttyUSB0, or the simulator's /dev/pts/N
    int slave = 9;
    int baud = 115200;
    // Flange -> the fingertips' grip point ("Tip"): 0.2028 m along z (the published cell's
    // Robotiq with its coupling).
    Eigen::Isometry3d tipOffset = Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.2028));
    std::string serialNumber = {};
    // Width <-> position bytes (robotiq_registers.hpp); open must be below closed.
    Calibration calibration = {};
    // One request/answer at most (the device answers within a few ms at 115200 baud).
    std::chrono::milliseconds transactionTimeout{100};
    // The status poll while a motion or activation runs: the device's 200 Hz.
    std::chrono::microseconds pollPeriod{5000};
    // Release opens at this speed and force (the manual's example: full speed, full force).
    double releaseSpeed = kMaxSpeed;
    double releaseForce = kMaxForce;
};

class RobotiqHardware : public gripper::GripperHardware {
  public:
    explicit RobotiqHardware(RobotiqConfig config);
    ~RobotiqHardware() override;
    RobotiqHardware(const RobotiqHardware&) = delete;
    RobotiqHardware& operator=(const RobotiqHardware&) = delete;

    gripper::Result<gripper::Done> connect(gripper::Deadline deadline) override;
    void disconnect() override;
    gripper::Result<gripper::Done> activate(gripper::Deadline deadline,
                                            const std::atomic<bool>& cancel) override;
    gripper::Result<gripper::Status> grasp(const gripper::GraspRequest& request,
                                           gripper::Deadline deadline,
                                           const std::atomic<bool>& cancel) override;
    gripper::Result<gripper::Status> release(gripper::Deadline deadline,
                                             const std::atomic<bool>& cancel) override;
    gripper::Result<gripper::Status> move(const gripper::MoveRequest& request,
                                          gripper::Deadline deadline,
                                          const std::atomic<bool>& cancel) override;
    void stop(gripper::Deadline deadline) override;
    gripper::Result<gripper::Status> status(gripper::Deadline deadline) override;

    gripper::GripPoint gripPoint() const override;
    std::string manufacturer() const override { return "Robotiq"; }
    std::string modelName() const override { return "2F-85"; }
    std::string serialNumber() const override { return config_.serialNumber; }
    std::string endpoint() const override;

    // The raw registers (tests, diagnostics).
    gripper::Result<GripperStatus> readStatus(gripper::Deadline deadline);
    gripper::Result<gripper::Done> writeRequest(const Request& request, gripper::Deadline deadline);

  private:
    // What a motion waits for: the gripper took `position` and its fingers stopped.
    gripper::Result<GripperStatus> runTo(const Request& request, gripper::Deadline deadline,
                                         const std::atomic<bool>& cancel);
    gripper::Result<gripper::Done> open();
    gripper::Error noAnswer(const char* what) const;
    bool limitTransaction(gripper::Deadline deadline);

    RobotiqConfig config_;
    _modbus* ctx_ = nullptr;
    Request last_;  // the request written last (stop keeps its position, speed, force)
};

gripper::Status toStatus(const GripperStatus& s, const Calibration& calibration = {});

}  // namespace pnp::device::robotiq
