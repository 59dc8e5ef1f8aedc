// The OPC UA face of any gripper (docs: src/device/gripper/README.md): a skill controller
// below DI DeviceSet that implements IGripperType (its grip point: Type, Offset, Span) and
// IVendorNameplateType (Manufacturer, Model, SerialNumber from the hardware), with the skills
// Grasp, Release and — for a parallel gripper — MoveGripper over a GripperHardware. Nothing
// here names a vendor.
//
//   RobotiqHardware hardware(config);            // any GripperHardware
//   HardwareAccess access(hardware);
//   ua::server::Server server(config);
//   GripperDevice device(server, access, {.name = "Robotiq2F85"});
//   server.start();
//
// Build it before Server::start(); destroy it before the Server and the HardwareAccess (it
// halts running skills: their hardware call sees `cancel`, stops the device and returns).
//
// Threads: each skill runs its hardware calls on its own worker, bounded by a deadline;
// Halt (network thread) only sets the run's cancel flag. Status variables follow every
// Status the hardware reports through the HardwareAccess (from skills and the tool
// adapter's poller).
#pragma once

#include <chrono>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "device/gripper/gripper_hardware.hpp"
#include "device/gripper/hardware_access.hpp"
#include "skill/server/controller.hpp"
#include "ua/server/server.hpp"

namespace pnp::device::gripper {

// A set-up error (model not loaded, bad options); the message names the problem.
class GripperDeviceError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

struct GripperDeviceOptions {
    // BrowseName of the skill controller below DeviceSet (and its Name).
    std::string name = "Gripper";
    ua::UInt16 namespaceIndex = 1;
    // Each skill's hardware calls end by these deadlines (activation counts extra).
    std::chrono::milliseconds activateTimeout{10000};
    std::chrono::milliseconds graspTimeout{10000};
    std::chrono::milliseconds releaseTimeout{10000};
    std::chrono::milliseconds moveTimeout{10000};
    // A Halt stops the device; this bounds the stop command of a run that had no hardware
    // call in flight.
    std::chrono::milliseconds stopTimeout{200};
    // Jaw speed of Grasp / Release / MoveGripper (the skill types have no speed), m/s.
    double speed = 0.05;
};

// The skills' BrowseNames below <name>/Skills.
namespace skill_names {
inline constexpr const char* Grasp = "Grasp";
inline constexpr const char* Release = "Release";
inline constexpr const char* MoveGripper = "MoveGripper";  // parallel grippers only
}  // namespace skill_names

class GripperDevice {
  public:
    // Loads the skill model (and DI) unless present, builds the nodes and skills. Throws
    // GripperDeviceError (or skill::server::SkillError / ua::server::NodeSetError).
    GripperDevice(ua::server::Server& server, HardwareAccess& access,
                  GripperDeviceOptions options = {});
    ~GripperDevice();
    GripperDevice(const GripperDevice&) = delete;
    GripperDevice& operator=(const GripperDevice&) = delete;

    const ua::NodeId& node() const;       // the skill controller (DeviceSet/<name>)
    const ua::NodeId& gripPoint() const;  // GripPoints/GripPoint_1
    // A skill by its BrowseName (skill_names); null if there is none.
    ua::NodeId skillNode(const std::string& name) const;
    std::vector<skill::server::SkillHandle> skills() const;
    // The status variables below the device: Ready, Holding, Width (parallel) or Vacuum
    // (vacuum), Fault. Null if absent.
    ua::NodeId statusNode(const std::string& name) const;

    // Writes the hardware's identification again (it may know more once connected).
    void refreshIdentity();

    struct Impl;

  private:
    std::shared_ptr<Impl> impl_;
};

}  // namespace pnp::device::gripper
