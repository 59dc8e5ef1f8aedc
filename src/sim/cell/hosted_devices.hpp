// The tools' and tool changers' device simulators as the cell hosts them: each stepped with
// the world on the stepping thread and served on its own real transport (a Robotiq on a
// pseudo-terminal, an ECBPi behind an IO-Link master on Modbus TCP, a WSG 50 on TCP, a
// Kelvin changer's analog state through an ADC input on Modbus TCP).
#pragma once

#include <memory>
#include <vector>

#include "sim/cell/simulator.hpp"
#include "world/world.hpp"

namespace pnp::sim::cell {

class HostedDevice {
  public:
    virtual ~HostedDevice() = default;
    virtual void start() = 0;  // opens the transport; throws std::system_error
    virtual void stop() = 0;
    virtual void step(double dt) = 0;  // the stepping thread, after the world's step
    virtual DeviceEndpoint endpoint() const = 0;
};

// The devices of every tool (by its `device`) and of every robot's tool changer. Throws
// std::invalid_argument naming a tool whose device has no simulator.
std::vector<std::unique_ptr<HostedDevice>> makeHostedDevices(world::World& world,
                                                             const SimulatorConfig& config);

// The device names a cell file's tools may use.
const std::vector<std::string>& simulatedToolDevices();

}  // namespace pnp::sim::cell
