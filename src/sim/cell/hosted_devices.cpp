#include "sim/cell/hosted_devices.hpp"

#include <stdexcept>
#include <string>

#include "modbus/modbus.hpp"
#include "sim/ecbpi/ecbpi.hpp"
#include "sim/ecbpi/iolink_master.hpp"
#include "sim/kelvin/kelvin_adc_input.hpp"
#include "sim/robotiq/robotiq_2f85.hpp"
#include "sim/wsg/wsg50.hpp"

namespace pnp::sim::cell {

namespace {

// Default ports when the cell's devices do not take free ones (the k-th device of a kind
// adds k): unprivileged stand-ins for the devices' own (Modbus TCP 502, WSG 1000).
constexpr std::uint16_t kIoLinkMasterPort = 5502;
constexpr std::uint16_t kWsgPort = 11000;
constexpr std::uint16_t kChangerAdcPort = 5602;
// The ECBPi's port on its IO-Link master.
constexpr std::size_t kEcbpiIoLinkPort = 1;

std::uint16_t portFor(const SimulatorConfig& config, std::uint16_t base, std::size_t k) {
    return config.ephemeralPorts ? 0 : static_cast<std::uint16_t>(base + k);
}

class RobotiqOnSerialLine : public HostedDevice {
  public:
    RobotiqOnSerialLine(world::World& world, std::size_t tool)
        : name_(world.description().tools[tool].name),
          gripper_(world, tool),
          slave_(pty_.masterFd(), robotiq::Robotiq2f85::rtuConfig(), gripper_) {}
    void start() override { slave_.start(); }
    void stop() override { slave_.stop(); }
    void step(double dt) override { gripper_.step(dt); }
    DeviceEndpoint endpoint() const override {
        auto e = DeviceEndpoint::tcp(name_, "robotiq-2f85", "modbus-rtu", "", 0);
        e.path = pty_.path();
        e.slave = robotiq::Robotiq2f85::kSlave;
        return e;
    }

  private:
    std::string name_;
    robotiq::Robotiq2f85 gripper_;
    modbus::PseudoTerminal pty_;
    modbus::RtuSlave slave_;
};

class EcbpiOnIoLinkMaster : public HostedDevice {
  public:
    EcbpiOnIoLinkMaster(world::World& world, std::size_t tool, modbus::TcpServerConfig tcp)
        : name_(world.description().tools[tool].name), server_(std::move(tcp), master_) {
        master_.attach(kEcbpiIoLinkPort, std::make_unique<ecbpi::Ecbpi>(world, tool));
    }
    void start() override { server_.start(); }
    void stop() override { server_.stop(); }
    void step(double dt) override { master_.step(dt); }
    DeviceEndpoint endpoint() const override {
        auto e = DeviceEndpoint::tcp(name_, "schmalz-ecbpi", "modbus-tcp", host_, server_.port());
        e.ioLinkPort = kEcbpiIoLinkPort;
        return e;
    }
    void setHost(std::string h) { host_ = std::move(h); }

  private:
    std::string name_;
    std::string host_;
    ecbpi::IoLinkMaster master_;
    modbus::TcpServer server_;
};

class WsgOnTcp : public HostedDevice {
  public:
    WsgOnTcp(world::World& world, std::size_t tool, wsg::Wsg50Config config)
        : name_(world.description().tools[tool].name),
          host_(config.bindAddress),
          gripper_(world, tool, std::move(config)) {}
    void start() override {}  // listens while powered (its step() follows the world)
    void stop() override {}
    void step(double dt) override { gripper_.step(dt); }
    DeviceEndpoint endpoint() const override {
        return DeviceEndpoint::tcp(name_, "schunk-wsg50", "wsg-tcp", host_, gripper_.port());
    }

  private:
    std::string name_;
    std::string host_;
    wsg::Wsg50 gripper_;
};

class ChangerAdcOnTcp : public HostedDevice {
  public:
    ChangerAdcOnTcp(world::World& world, std::size_t robot, modbus::TcpServerConfig tcp)
        : name_(world.description().robots[robot].name + "-changer"),
          host_(tcp.bindAddress),
          input_(world, robot),
          server_(std::move(tcp), input_) {}
    void start() override { server_.start(); }
    void stop() override { server_.stop(); }
    void step(double dt) override { input_.step(dt); }
    DeviceEndpoint endpoint() const override {
        return DeviceEndpoint::tcp(name_, "kelvin-adc-input", "modbus-tcp", host_, server_.port());
    }

  private:
    std::string name_;
    std::string host_;
    kelvin::KelvinAdcInput input_;
    modbus::TcpServer server_;
};

}  // namespace

const std::vector<std::string>& simulatedToolDevices() {
    static const std::vector<std::string> names{"robotiq-2f85", "schmalz-ecbpi", "schunk-wsg50"};
    return names;
}

std::vector<std::unique_ptr<HostedDevice>> makeHostedDevices(world::World& world,
                                                             const SimulatorConfig& config) {
    std::vector<std::unique_ptr<HostedDevice>> devices;
    std::size_t masters = 0, wsgs = 0;
    const auto& cell = world.description();
    for (std::size_t i = 0; i < cell.tools.size(); ++i) {
        const world::ToolDescription& t = cell.tools[i];
        if (t.device == "robotiq-2f85") {
            devices.push_back(std::make_unique<RobotiqOnSerialLine>(world, i));
        } else if (t.device == "schmalz-ecbpi") {
            modbus::TcpServerConfig tcp;
            tcp.bindAddress = config.bindAddress;
            tcp.port = portFor(config, kIoLinkMasterPort, masters++);
            auto d = std::make_unique<EcbpiOnIoLinkMaster>(world, i, tcp);
            d->setHost(config.bindAddress);
            devices.push_back(std::move(d));
        } else if (t.device == "schunk-wsg50") {
            wsg::Wsg50Config c;
            c.bindAddress = config.bindAddress;
            c.port = portFor(config, kWsgPort, wsgs++);
            devices.push_back(std::make_unique<WsgOnTcp>(world, i, c));
        } else {
            std::string known;
            for (const auto& n : simulatedToolDevices()) known += (known.empty() ? "" : ", ") + n;
            throw std::invalid_argument("tool '" + t.name + "' (line " + std::to_string(t.line) +
                                        "): no simulator for device '" + t.device +
                                        "' (known: " + known + ")");
        }
    }
    for (std::size_t r = 0; r < cell.robots.size(); ++r) {
        modbus::TcpServerConfig tcp;
        tcp.bindAddress = config.bindAddress;
        tcp.port = portFor(config, kChangerAdcPort, r);
        devices.push_back(std::make_unique<ChangerAdcOnTcp>(world, r, tcp));
    }
    return devices;
}

}  // namespace pnp::sim::cell
