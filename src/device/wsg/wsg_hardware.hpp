// The Schunk WSG 50's hardware interface: gripper::GripperHardware over the WSG command set on
// TCP (wsg/protocol.hpp), the gripper's own protocol, so the same adapter drives the real
// gripper (its IP address, TCP port 1000, docs/wsg-50.md) and the simulator (sim/wsg).
//
// Every call has a deadline for connecting, sending and receiving; a call that finds no
// connection opens one first (a gripper that was unpowered is picked up again). A motion is
// answered E_CMD_PENDING and then with its result; while waiting, `cancel` is checked every
// 20 ms and stops the gripper (STOP, 0x22). Calls are serialised; stop() may come from another
// thread while a call runs (it then only sends the STOP).
#pragma once

#include <Eigen/Geometry>
#include <atomic>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "device/gripper/gripper_hardware.hpp"
#include "wsg/protocol.hpp"

namespace pnp::device::wsg {

namespace gripper = pnp::device::gripper;

// Flange -> grip point of a WSG 50 with standard fingers on the cell's tool changer: the
// middle between the finger tips, 0.19 m out along the flange's z axis (the tool's TCP; set it
// to the TCP of the tool as mounted).
Eigen::Isometry3d defaultGripPointOffset();

struct WsgHardwareConfig {
    std::string host = "127.0.0.1";
    std::uint16_t port = pnp::wsg::kDefaultPort;
    Eigen::Isometry3d gripPointOffset = defaultGripPointOffset();
    double stroke = 0.110;      // m: the jaws' opening range 0..stroke (WSG 50-110)
    double minSpeed = 0.005;    // m/s, the gripper's range (refused before sending)
    double maxSpeed = 0.420;    // m/s
    double minForce = 5.0;      // N
    double maxForce = 80.0;     // N
    double releaseSpeed = 0.1;  // m/s, release opens fully at this speed
};

// "HOST[:PORT]" (port default 1000); nullopt for an empty host or a bad port.
std::optional<std::pair<std::string, std::uint16_t>> parseAddress(std::string_view address);

class WsgHardware final : public gripper::GripperHardware {
  public:
    explicit WsgHardware(WsgHardwareConfig config = {});
    ~WsgHardware() override;
    WsgHardware(const WsgHardware&) = delete;
    WsgHardware& operator=(const WsgHardware&) = delete;

    // Opens the TCP connection and reads the system information (0x50): kNoDevice when
    // nothing answers within the deadline (unpowered, wrong address).
    gripper::Result<gripper::Done> connect(gripper::Deadline deadline) override;
    // Announces the disconnect (0x07, so the gripper raises no fast stop) and closes.
    void disconnect() override;
    // Acknowledges a fast stop, then homes (0x20) if the gripper is not referenced.
    gripper::Result<gripper::Done> activate(gripper::Deadline deadline,
                                            const std::atomic<bool>& cancel) override;
    // Sets the force limit (0x32), grasps (0x25); succeeds only when the gripper then reports
    // HOLDING. NO PART FOUND: kRefused "no object between the fingers".
    gripper::Result<gripper::Status> grasp(const gripper::GraspRequest& request,
                                           gripper::Deadline deadline,
                                           const std::atomic<bool>& cancel) override;
    // Release (0x26) to the full stroke at config.releaseSpeed.
    gripper::Result<gripper::Status> release(gripper::Deadline deadline,
                                             const std::atomic<bool>& cancel) override;
    // Pre-position (0x21, absolute, stop on block).
    gripper::Result<gripper::Status> move(const gripper::MoveRequest& request,
                                          gripper::Deadline deadline,
                                          const std::atomic<bool>& cancel) override;
    void stop(gripper::Deadline deadline) override;
    gripper::Result<gripper::Status> status(gripper::Deadline deadline) override;

    gripper::GripPoint gripPoint() const override;
    std::string manufacturer() const override { return "SCHUNK"; }
    std::string modelName() const override;     // "WSG 50" (from 0x50 once connected)
    std::string serialNumber() const override;  // "" before the first connect
    std::string endpoint() const override;      // "tcp://HOST:PORT"
    // "4.2.0.0" once connected.
    std::string firmwareVersion() const;

  private:
    using Response = pnp::wsg::Response;
    using Command = pnp::wsg::Command;

    gripper::Result<gripper::Done> ensureConnected(gripper::Deadline deadline);
    gripper::Result<gripper::Done> open(gripper::Deadline deadline);
    void closeSocket();
    gripper::Result<gripper::Done> send(Command command, const std::vector<std::uint8_t>& payload,
                                        gripper::Deadline deadline);
    // The next answer to `command` (others are dropped); kCancelled when `cancel` is set.
    gripper::Result<Response> await(Command command, gripper::Deadline deadline,
                                    const std::atomic<bool>* cancel);
    // A command answered once, its status E_SUCCESS.
    gripper::Result<Response> request(Command command, const std::vector<std::uint8_t>& payload,
                                      gripper::Deadline deadline, std::string_view what);
    // A motion: E_CMD_PENDING, then the result; the result's status is returned as it is.
    gripper::Result<std::uint16_t> motion(Command command, const std::vector<std::uint8_t>& payload,
                                          gripper::Deadline deadline,
                                          const std::atomic<bool>& cancel, std::string_view what);
    // Stops a running motion and waits briefly for its result (E_CMD_ABORTED).
    void stopMotion(Command running, gripper::Deadline deadline);
    gripper::Result<gripper::Status> readStatus(gripper::Deadline deadline);
    gripper::Error deviceError(std::string_view what, std::uint16_t status) const;
    std::string where() const;

    const WsgHardwareConfig config_;

    std::mutex io_;    // one call at a time
    std::mutex send_;  // writers of the socket (a call, or stop() while a call runs)
    int fd_ = -1;      // changed under io_ and send_
    pnp::wsg::Decoder decoder_;
    std::deque<pnp::wsg::Frame> inbox_;  // decoded, not yet awaited

    mutable std::mutex info_;
    std::optional<pnp::wsg::SystemInformation> information_;
};

}  // namespace pnp::device::wsg
