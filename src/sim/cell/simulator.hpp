// The simulated cell's hardware in one process (`pnp sim`): the physical world, stepped at a
// fixed rate, and the device side of every simulated device on its own real transport (for
// now the UR controller over RTDE/TCP). The world is the ground truth; its snapshot is what
// the ground-truth OPC UA view (ground_truth.hpp) and tests read. Adapters only ever see
// the devices' protocols.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "world/cell_description.hpp"
#include "world/world.hpp"

namespace pnp::sim::ur {
class UrController;
}

namespace pnp::sim::cell {

// The thesis cell (models/cells/thesis.yaml of the source tree), or $PNP_CELL when set.
std::filesystem::path defaultCellFile();

struct SimulatorConfig {
    double rate = 500.0;                    // world steps per second (fixed dt = 1 / rate)
    std::string bindAddress = "127.0.0.1";  // where device endpoints listen
    bool ephemeralPorts = false;            // every device on a free port (tests, many cells)
    double snapshotRate = 125.0;            // snapshots for readers per second (≤ rate)
    // Called on the stepping thread after every step (tests and benchmarks that check each
    // step of the world); keep it short.
    std::function<void(const world::World&)> onStep;
    // Events an operator should read (a robot's protective stop and its cause), on the
    // stepping thread; rare.
    std::function<void(const std::string&)> log;
};

// Where an adapter finds a simulated device.
struct DeviceEndpoint {
    std::string name;      // the thing in the cell file (robot name, tool name...)
    std::string device;    // what is simulated, e.g. "ur-controller", "robotiq-2f85"
    std::string protocol;  // "rtde", "modbus-rtu", "modbus-tcp", "wsg-tcp"
    std::string host;      // TCP devices
    std::uint16_t port = 0;
    std::string path;            // serial devices: the line to open (a pseudo-terminal)
    int slave = 0;               // Modbus RTU: the slave address
    std::size_t ioLinkPort = 0;  // behind an IO-Link master: the device's port on it

    // "HOST:PORT" or the serial line's path.
    std::string address() const;
    static DeviceEndpoint tcp(std::string name, std::string device, std::string protocol,
                              std::string host, std::uint16_t port);
};

struct StepStats {
    std::uint64_t steps = 0;
    std::uint64_t overruns = 0;   // steps that started more than one period late
    double stepCostMedian = 0.0;  // s of CPU-side work per step (recent window)
    double stepCostP99 = 0.0;
    double lateMax = 0.0;   // s, the latest a step started
    bool realtime = false;  // the stepping thread got SCHED_FIFO
};

class Simulator {
  public:
    Simulator(world::CellDescription cell, SimulatorConfig config = {});
    ~Simulator();  // stop()
    Simulator(const Simulator&) = delete;
    Simulator& operator=(const Simulator&) = delete;

    // Starts every device server, then the stepping thread. Throws std::system_error when a
    // port is taken (the message names the device and the port).
    void start();
    void stop();

    std::vector<DeviceEndpoint> endpoints() const;
    // The world as of the latest snapshot (at snapshotRate).
    std::shared_ptr<const world::Snapshot> snapshot() const;
    const world::CellDescription& description() const;
    // Runs `action` on the stepping thread before the next step (the world belongs to that
    // thread): operator actions, test set-ups. Before start() it runs at once, here.
    void post(std::function<void(world::World&)> action);
    // The simulated UR controller of robot `index` (its counters and inputs, for tests).
    const sim::ur::UrController& urController(std::size_t index) const;
    StepStats stats() const;
    double rate() const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::sim::cell
