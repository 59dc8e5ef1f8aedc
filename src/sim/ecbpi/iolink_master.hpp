// A simulated IO-Link master with K ports (default 4) that exposes each port's status and
// process data over Modbus TCP (the map in models/iolink/modbus-master.yaml,
// docs/schmalz-ecbpi.md). It is the modbus::Registers behind a modbus::TcpServer; each port
// holds an IO-Link device model (or none). The master is powered by the cell: it always answers,
// whether or not a port's device has power.
//
// Threads: step() runs on the simulator's stepping thread (it steps the devices, which touch
// the world); the Modbus thread reads and writes the register images. Both under one mutex.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <vector>

#include "iolink/process_data.hpp"
#include "modbus/modbus.hpp"

namespace pnp::sim::ecbpi {

// An IO-Link device on a master port, as the master's cyclic exchange sees it.
class IoLinkDevice {
  public:
    virtual ~IoLinkDevice() = default;
    virtual std::uint16_t vendorId() const = 0;
    virtual std::uint32_t deviceId() const = 0;
    virtual std::size_t pdInBytes() const = 0;
    virtual std::size_t pdOutBytes() const = 0;
    // The outputs the master holds for the device (pdOutBytes() octets), before each step.
    virtual void setProcessDataOut(std::span<const std::uint8_t> pd) = 0;
    virtual void step(double dt) = 0;
    // kNoDevice while the device has no power: the port sees no device.
    virtual iolink::PortState portState() const = 0;
    // pdInBytes() octets; meaningful in kOperate only (the master publishes zeros otherwise).
    virtual std::vector<std::uint8_t> processDataIn() const = 0;
};

// One port as the master publishes it (a copy, for tests and the ground truth).
struct PortImage {
    iolink::PortState state = iolink::PortState::kNoDevice;
    std::vector<std::uint8_t> pdIn;   // map.pdMaxBytes octets
    std::vector<std::uint8_t> pdOut;  // map.pdMaxBytes octets
};

class IoLinkMaster : public modbus::Registers {
  public:
    // The simulated master's map (models/iolink/modbus-master.yaml); throws std::runtime_error
    // with the loader's message when that file does not load.
    IoLinkMaster();
    explicit IoLinkMaster(iolink::MasterMap map);
    ~IoLinkMaster() override;
    IoLinkMaster(const IoLinkMaster&) = delete;
    IoLinkMaster& operator=(const IoLinkMaster&) = delete;

    const iolink::MasterMap& map() const { return map_; }
    std::size_t ports() const { return map_.ports; }

    // Plugs `device` into `port` (1..ports(); std::out_of_range otherwise), replacing any
    // device there. The master owns it; the reference stays valid until detach / destruction.
    template <class Device>
    Device& attach(std::size_t port, std::unique_ptr<Device> device) {
        Device& ref = *device;
        attachDevice(port, std::move(device));
        return ref;
    }
    void detach(std::size_t port);

    // One cycle of every port (stepping thread): outputs to each device, the device's step,
    // its state and inputs back into the register image.
    void step(double dt);

    PortImage port(std::size_t port) const;

    // modbus::Registers (the Modbus thread). FC03 and FC04 read the same map.
    modbus::Exception readHolding(std::uint16_t address, std::span<std::uint16_t> out) override;
    modbus::Exception readInput(std::uint16_t address, std::span<std::uint16_t> out) override;
    modbus::Exception writeHolding(std::uint16_t address,
                                   std::span<const std::uint16_t> values) override;

  private:
    struct Port {
        std::unique_ptr<IoLinkDevice> device;
        iolink::PortState state = iolink::PortState::kNoDevice;
        std::vector<std::uint8_t> pdIn;
        std::vector<std::uint8_t> pdOut;
    };
    // Where a register is: its port (0-based) and offset in the port's block; false when the
    // address is in no port's block.
    bool locate(std::uint32_t address, std::size_t& port, std::uint32_t& offset) const;
    // One register's value; false when the address is not readable.
    bool readOne(std::uint32_t address, std::uint16_t& value) const;
    void attachDevice(std::size_t port, std::unique_ptr<IoLinkDevice> device);
    void publish(Port& p);

    iolink::MasterMap map_;
    mutable std::mutex mutex_;
    std::vector<Port> ports_;
};

}  // namespace pnp::sim::ecbpi
