// A gripper's hardware interface: the small, typed boundary between the vendor-neutral
// gripper device (GripperDevice: the OPC UA skills Grasp / Release / MoveGripper and the
// IGripperType grip point) and one vendor's protocol (device/robotiq: Modbus RTU,
// device/ecbpi: IO-Link over Modbus TCP, device/wsg: the WSG command set over TCP). One
// implementation per vendor; nothing above it names a vendor.
//
// Every call blocks the caller (a skill's worker thread, never the network thread) until
// the device reports the outcome or the deadline passes; `cancel` (set by Halt) makes a
// running call stop the device and return kCancelled promptly.
#pragma once

#include <Eigen/Geometry>
#include <atomic>
#include <chrono>
#include <optional>
#include <string>

#include "base/result.hpp"

namespace pnp::device::gripper {

using Clock = std::chrono::steady_clock;
using Deadline = Clock::time_point;

enum class ErrorKind {
    kNoDevice,   // the device does not answer (unpowered, unplugged, wrong address)
    kProtocol,   // an answer that does not make sense (exception, bad frame)
    kFault,      // the device reports a fault (its code in the message)
    kRefused,    // a request the device cannot do (width beyond the stroke...)
    kTimeout,    // the deadline passed before the device reported the outcome
    kCancelled,  // `cancel` was set: the device was stopped
};

struct Error {
    ErrorKind kind;
    std::string message;  // for people: "no answer from slave 9 on /dev/pts/4"
};

template <class T>
using Result = base::Result<T, Error>;
struct Done {};

// How the gripper holds things (IGripperType / GripPointType of the skill model).
enum class GripKind { kParallel = 0, kVacuum = 1 };

struct GripPoint {
    std::string name = "Tip";  // the published cell code's name for the Robotiq's
    GripKind kind = GripKind::kParallel;
    // Flange -> grip point (the tool's TCP as a robot's SetTool takes it).
    Eigen::Isometry3d offset = Eigen::Isometry3d::Identity();
    double spanMin = 0.0;  // m, parallel: the jaws' opening range
    double spanMax = 0.0;  // m; vacuum: the cup's diameter in spanMax, spanMin 0
};

struct Status {
    bool ready = false;    // activated / homed / IO-Link port operating
    bool moving = false;   // jaws moving, vacuum building
    bool holding = false;  // an object is held (jaws stopped on it / vacuum part present)
    double width = 0.0;    // m, parallel: the jaws' opening
    double vacuum = 0.0;   // mbar below ambient, vacuum grippers
    std::string fault;     // empty: none
};

// What a grasp asks for: a parallel gripper closes (to `width`, 0 = fully) at `speed`
// with `force`; a vacuum gripper switches suction on and waits for the part.
struct GraspRequest {
    double width = 0.0;   // m
    double speed = 0.05;  // m/s
    double force = 20.0;  // N
};

struct MoveRequest {
    double width = 0.085;  // m
    double speed = 0.05;   // m/s
    double force = 20.0;   // N
};

class GripperHardware {
  public:
    virtual ~GripperHardware() = default;

    // Opens the transport and checks that the device answers (no activation, no motion).
    virtual Result<Done> connect(Deadline deadline) = 0;
    virtual void disconnect() = 0;
    // Makes the device ready (Robotiq activation, WSG homing, IO-Link port check); idempotent.
    virtual Result<Done> activate(Deadline deadline, const std::atomic<bool>& cancel) = 0;
    // Grasp: succeeds only when the device reports an object held; fails kRefused with
    // "no object" when the jaws closed on nothing / no part was sucked within the deadline.
    virtual Result<Status> grasp(const GraspRequest& request, Deadline deadline,
                                 const std::atomic<bool>& cancel) = 0;
    // Release: opens fully / blows off; succeeds when the device reports it released.
    virtual Result<Status> release(Deadline deadline, const std::atomic<bool>& cancel) = 0;
    // Parallel grippers: move the jaws to a width (kRefused outside the span; vacuum: kRefused).
    virtual Result<Status> move(const MoveRequest& request, Deadline deadline,
                                const std::atomic<bool>& cancel) = 0;
    // Stop any motion now (Halt); best effort, bounded by the deadline.
    virtual void stop(Deadline deadline) = 0;
    virtual Result<Status> status(Deadline deadline) = 0;

    virtual GripPoint gripPoint() const = 0;
    // For the device's identification (DI): manufacturer, model, serial number, endpoint.
    virtual std::string manufacturer() const = 0;
    virtual std::string modelName() const = 0;
    virtual std::string serialNumber() const = 0;
    virtual std::string endpoint() const = 0;  // e.g. "modbus-rtu:///dev/pts/4?slave=9"
};

}  // namespace pnp::device::gripper
