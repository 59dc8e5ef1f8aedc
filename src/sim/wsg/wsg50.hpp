// The simulated Schunk WSG 50 parallel gripper: the device side of the WSG command set over TCP
// (wsg/protocol.hpp) for one tool of the world. A TCP server (default port 1000) with one
// network thread (poll) for its connections; the device state (jaw motion, grasping state,
// fast stop, force limit, acceleration) sits behind a mutex shared by that thread and the
// simulator's stepping thread, which calls step() — the only place the world is touched:
//   - motion commands (homing, pre-position, grasp, release) are answered E_CMD_PENDING at once
//     and with their result when step() finishes them, as the device does;
//   - a grasp closes until the world reports an object between the fingers at the current
//     opening (world.objectBetweenFingers) -> HOLDING, world.hold(); or until the nominal
//     width less the clamping travel -> NO PART FOUND, E_CMD_FAILED;
//   - release opens -> RELEASING, world.release(), then IDLE;
//   - power is the world's (world.toolPowered, read in step()): while unpowered the listening
//     socket is closed (kept bound, so the port stays ours and a connect is refused) and every
//     connection is dropped; on power-on it listens again on the same port, not homed.
// docs/wsg-50.md describes the subset served and every choice where the manual is silent.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "world/world.hpp"
#include "wsg/protocol.hpp"

namespace pnp::sim::wsg {

struct Wsg50Config {
    std::uint16_t port = pnp::wsg::kDefaultPort;  // 0 = any free port (see Wsg50::port())
    std::string bindAddress = "127.0.0.1";        // "0.0.0.0" to serve other hosts
    double stroke = 0.0;  // mm; 0 = the tool's stroke in the cell (m), or 110 (WSG 50-110)
    double minSpeed = 5.0, maxSpeed = 420.0;                   // mm/s (WSG 50 data sheet)
    double minForce = 5.0, maxForce = 80.0;                    // N
    double minAcceleration = 100.0, maxAcceleration = 5000.0;  // mm/s²
    double acceleration = 1000.0;                              // mm/s² at power-on
    double forceLimit = 40.0;                                  // N at power-on
    double homingSpeed = 200.0;                                // mm/s
    // How far past the nominal part width a grasp closes before it reports NO PART FOUND
    // (the device's "clamping travel", set in its web interface).
    double clampingTravel = 5.0;  // mm
    double initialWidth = -1.0;   // mm, where the jaws are at start; < 0 = fully open
    std::uint8_t hardwareRevision = 1;
    std::uint16_t firmware = 0x4200;  // 4.2.0.0
    std::uint32_t serialNumber = 50001;
    std::size_t maxConnections = 4;  // more are accepted and closed at once
    // The web interface's "Enable error state on TCP disconnect": a connection that closes
    // without the disconnect announcement (0x07) raises a FAST STOP.
    bool fastStopOnDisconnect = false;
};

// What the device is doing, for tests and the ground truth.
struct Wsg50State {
    bool powered = false;
    bool listening = false;
    bool referenced = false;
    bool fastStop = false;
    bool moving = false;
    double width = 0.0;  // mm
    pnp::wsg::GraspingState grasping = pnp::wsg::GraspingState::kIdle;
    std::uint32_t systemFlags = 0;
    std::size_t connections = 0;
    std::uint64_t checksumErrors = 0;  // frames answered E_CHECKSUM_ERROR
};

class Wsg50 {
  public:
    // Binds the port at once (not listening until step() sees power). Throws std::out_of_range
    // for a tool index the cell does not have, std::invalid_argument for a non-positive or
    // inconsistent limit, std::runtime_error when the address cannot be bound.
    Wsg50(world::World& world, std::size_t tool, Wsg50Config config = {});
    ~Wsg50();
    Wsg50(const Wsg50&) = delete;
    Wsg50& operator=(const Wsg50&) = delete;

    // The simulator's stepping thread: power, jaw motion, object detection, final answers.
    // dt in s; a non-finite or negative dt only reads the power.
    void step(double dt);

    // The bound port (the one chosen when the config said 0); the same across power cycles.
    std::uint16_t port() const { return port_; }
    Wsg50State state() const;

  private:
    enum class MotionKind { kHoming, kPosition, kGrasp, kRelease };
    struct Motion {
        MotionKind kind = MotionKind::kPosition;
        double target = 0.0;      // mm
        double speed = 0.0;       // mm/s
        std::uint64_t owner = 0;  // the connection that gets the final answer
        bool started = false;
    };
    struct Connection {
        int fd = -1;
        pnp::wsg::Decoder decoder;
        std::vector<std::uint8_t> outbox;
        bool announced = false;  // sent the disconnect announcement
        bool closing = false;
    };

    void run();
    // Under mutex_ (network thread).
    void updateListener();
    void acceptAll();
    void serve(std::uint64_t id, Connection& c);
    void flush(Connection& c);
    void closeConnection(std::uint64_t id);
    void handle(std::uint64_t id, Connection& c, const pnp::wsg::Frame& frame);
    void reply(Connection& c, std::uint8_t id, pnp::wsg::Status status,
               const std::vector<std::uint8_t>& values = {});
    void replyTo(std::uint64_t id, std::uint8_t command, pnp::wsg::Status status);
    pnp::wsg::Status startMotion(std::uint64_t owner, MotionKind kind, double target, double speed);
    void finishMotion(pnp::wsg::Status status);
    void abortMotion();
    std::uint32_t systemFlags() const;
    void wake();
    // Under mutex_ (stepping thread).
    void advance(double dt);
    void powerChanged(bool powered);

    world::World& world_;
    const std::size_t tool_;
    Wsg50Config config_;
    std::uint16_t port_ = 0;

    mutable std::mutex mutex_;
    // Guarded by mutex_.
    bool powered_ = false;
    bool listening_ = false;
    int listener_ = -1;  // bound; listening only while powered
    std::map<std::uint64_t, Connection> connections_;
    std::uint64_t nextConnection_ = 1;
    double width_ = 0.0;     // mm
    double velocity_ = 0.0;  // mm/s, signed (+ opens)
    bool referenced_ = false;
    bool fastStop_ = false;
    std::uint32_t eventFlags_ = 0;  // blocked, stopped, target reached, command failure
    pnp::wsg::GraspingState grasping_ = pnp::wsg::GraspingState::kIdle;
    std::optional<Motion> motion_;
    std::optional<std::size_t> held_;  // the world's object index we hold
    double acceleration_ = 0.0;
    double forceLimit_ = 0.0;
    pnp::wsg::GraspingStatistics statistics_;
    std::uint64_t checksumErrors_ = 0;
    bool releaseHeld_ = false;  // step() must tell the world we let go

    int wakeRead_ = -1;
    int wakeWrite_ = -1;
    std::atomic<bool> stop_{false};
    std::thread thread_;
};

}  // namespace pnp::sim::wsg
