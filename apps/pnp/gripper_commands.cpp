// `pnp device robotiq | wsg | ecbpi`: a gripper on OPC UA — the vendor's GripperHardware
// under the vendor-neutral GripperDevice (src/device/gripper/README.md), served by a
// ToolAdapter only while the gripper answers (the tool's power: plugged in on the tool
// changer). Discovery like every pnp server: registered with the LDS-ME (found by mDNS, or
// --lds) while serving, unregistered when the gripper goes. Runs until SIGINT / SIGTERM.
#include <signal.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <functional>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "commands.hpp"
#include "device/gripper/tool_adapter.hpp"
#include "device/robotiq/robotiq_hardware.hpp"
#include "device_commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"
#include "ua/discovery/registrar.hpp"
#include "ua/discovery/txt_record.hpp"
#include "ua/spatial/spatial.hpp"
#ifdef PNP_HAVE_DEVICE_WSG
#include "device/wsg/wsg_hardware.hpp"
#endif
#ifdef PNP_HAVE_DEVICE_ECBPI
#include "device/ecbpi/ecbpi_hardware.hpp"
#endif

namespace pnp::cli {

namespace {

namespace gripper = device::gripper;

// What every gripper adapter takes besides its device's address.
struct GripperAdapterOptions {
    ServeOptions serve;
    std::string offset;  // x,y,z,a,b,c; empty: the vendor's default
    std::string serialNumber;
    int pollMs = 20;
    int pollTimeoutMs = 15;
    int graceMs = 100;
    bool noActivate = false;
    double speed = 0.05;
};

// The adapter's discovery: mDNS runs for the adapter's whole life (so the LDS-ME is already
// known when the gripper powers up: no mDNS query and its 20-120 ms answer delay on the
// way), and each power-up gets a Registrar, whose end unregisters (the LDS-ME sends the mDNS
// goodbye). --lds-me: the whole DiscoveryRuntime per power-up (as `pnp ua serve --lds-me`).
class AdapterDiscovery {
  public:
    AdapterDiscovery(const DiscoveryOptions& o, const std::string& host) : options_(o) {
        if (o.noRegister) {
            status_ = "not registering";
            return;
        }
        if (o.ldsMe) {
            status_ = "LDS-ME and registration on each power-up";
            return;
        }
        const MdnsScope scope = mdnsScope(host, o.mdnsInterfaces);
        if (!scope.multicast) status_ = kLoopbackNoMdns;
        if (scope.multicast && o.lds.empty()) {
            mdns_ =
                std::make_unique<mdns::Mdns>(mdnsConfig(scope.interfaces, o.mdnsPort, o.mdnsTtl));
            mdns_->start();
            // Keeps the LDS-MEs' announcements cached between power-ups.
            browse_ = mdns_->browse("_opcua-tcp._tcp", [](const mdns::DiscoveredService&, bool) {});
        }
        if (!o.lds.empty())
            status_ = "registering with " + o.lds;
        else if (mdns_)
            status_ = "registering with an LDS-ME found by mDNS";
        else if (status_.empty())
            status_ = "not registering";
    }
    ~AdapterDiscovery() {
        if (mdns_) {
            mdns_->stopBrowse(browse_);
            mdns_->stop();
        }
    }
    AdapterDiscovery(const AdapterDiscovery&) = delete;
    AdapterDiscovery& operator=(const AdapterDiscovery&) = delete;

    const std::string& status() const { return status_; }

    gripper::Announcement announce(ua::server::Server& server) {
        if (options_.ldsMe) return std::make_shared<DiscoveryRuntime>(server, options_);
        if (options_.noRegister || (!mdns_ && options_.lds.empty())) return {};
        ua::discovery::RegistrarConfig rc;
        rc.ldsUrl = options_.lds;
        rc.discoveryGroup = options_.group;
        if (!options_.name.empty()) rc.mdnsServerName = ua::discovery::dnsLabel(options_.name);
        rc.interval = std::chrono::milliseconds(options_.registerIntervalMs);
        auto registrar = std::shared_ptr<ua::discovery::Registrar>(
            new ua::discovery::Registrar(server, mdns_.get(), rc), [](ua::discovery::Registrar* r) {
                r->stop();  // unregisters: gone everywhere at once
                delete r;
            });
        registrar->onLdsChanged([](const std::string& url) {
            std::cerr << "pnp: registered with the LDS-ME " << url << std::endl;
        });
        registrar->start();
        return registrar;
    }

  private:
    DiscoveryOptions options_;
    std::unique_ptr<mdns::Mdns> mdns_;
    mdns::Mdns::BrowseId browse_ = 0;
    std::string status_;
};

// --calibration "OPEN,CLOSED": the 2F-85's gPO at its ends, 0 <= OPEN < CLOSED <= 255.
device::robotiq::Calibration parseCalibration(const std::string& text) {
    int open = -1;
    int closed = -1;
    char rest = 0;
    if (std::sscanf(text.c_str(), "%d,%d%c", &open, &closed, &rest) != 2 || open < 0 ||
        closed > 255 || open >= closed)
        throw UsageError(
            "--calibration expects OPEN,CLOSED with 0 <= OPEN < CLOSED <= 255, got \"" + text +
            "\"");
    return {.open = static_cast<std::uint8_t>(open), .closed = static_cast<std::uint8_t>(closed)};
}

std::string kindName(gripper::GripKind k) {
    return k == gripper::GripKind::kParallel ? "Parallel" : "Vacuum";
}

// The shared runner: one JSON line on stdout (endpoint, ApplicationUri, device), the power
// events on stderr, until SIGINT / SIGTERM.
int runGripperAdapter(const std::string& command, gripper::GripperHardware& hardware,
                      const std::string& defaultName, GripperAdapterOptions& o,
                      const sigset_t& stopSignals) {
    std::string& name = o.serve.discovery.name;
    if (name.empty()) name = defaultName;
    ua::server::ServerConfig config = serverConfig(o.serve);
    if (config.publicHost.empty()) {
        char buf[256] = {};
        config.publicHost = ::gethostname(buf, sizeof buf - 1) == 0 ? buf : "localhost";
    }

    applyUsers(config, o.serve.discovery.security, true);
    gripper::ToolAdapterOptions to;
    to.server = config;
    to.prepareServer = [&security = o.serve.discovery.security](ua::server::Server& s) {
        finishServerSecurity(s, security);
    };
    to.device.name = name;
    to.device.speed = o.speed;
    to.pollPeriod = std::chrono::milliseconds(o.pollMs);
    to.pollTimeout = std::chrono::milliseconds(o.pollTimeoutMs);
    to.graceTime = std::chrono::milliseconds(o.graceMs);
    to.activateOnPowerUp = !o.noActivate;

    std::unique_ptr<AdapterDiscovery> discovery;
    std::unique_ptr<gripper::ToolAdapter> adapter;
    try {
        discovery = std::make_unique<AdapterDiscovery>(o.serve.discovery, config.host);
        adapter = std::make_unique<gripper::ToolAdapter>(
            hardware, to, [d = discovery.get()](ua::server::Server& s) { return d->announce(s); });
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        return kExitUaError;
    }

    const gripper::GripPoint gp = hardware.gripPoint();
    auto printLine = [&](const std::string& url) {
        nlohmann::json j;
        j["endpointUrl"] = url;
        j["applicationUri"] = config.applicationUri;
        j["name"] = name;
        j["device"] = hardware.endpoint();
        j["manufacturer"] = hardware.manufacturer();
        j["model"] = hardware.modelName();
        const auto f = ua::spatial::toFrame(gp.offset);
        j["gripPoint"] = {
            {"name", gp.name},
            {"type", kindName(gp.kind)},
            {"offset",
             {f.cartesianCoordinates.x, f.cartesianCoordinates.y, f.cartesianCoordinates.z,
              f.orientation.a, f.orientation.b, f.orientation.c}},
            {"span", {gp.spanMin, gp.spanMax}}};
        std::vector<std::string> skills = {"Grasp", "Release"};
        if (gp.kind == gripper::GripKind::kParallel) skills.emplace_back("MoveGripper");
        j["skills"] = skills;
        std::cout << j.dump() << std::endl;  // one line, flushed: tests and scripts read it
    };
    // With a fixed port the endpoint is known before the gripper answers.
    bool printed = config.port != 0;
    if (printed)
        printLine("opc.tcp://" + config.publicHost + ":" + std::to_string(config.port) +
                  config.endpointPath);

    const std::string tag = "pnp device " + command + ": ";
    adapter->onEvent([&](const gripper::PowerEvent& e) {
        using Kind = gripper::PowerEvent::Kind;
        if (e.kind == Kind::kUp) {
            if (!printed) printLine(e.endpointUrl);
            printed = true;
            char ms[32];
            std::snprintf(ms, sizeof ms, "%.1f",
                          std::chrono::duration<double, std::milli>(e.startLatency).count());
            std::cerr << tag << "the gripper answers: serving " << e.endpointUrl
                      << " (first answer -> announced in " << ms << " ms)" << std::endl;
        } else if (e.kind == Kind::kDown) {
            std::cerr << tag << e.message << ": withdrawn, server stopped" << std::endl;
        } else {
            std::cerr << tag << e.message << std::endl;
        }
    });
    adapter->start();
    std::cerr << tag << name << " (" << hardware.manufacturer() << " " << hardware.modelName()
              << ") at " << hardware.endpoint() << "; served while it answers (polled every "
              << o.pollMs << " ms, gone after " << o.graceMs << " ms); " << discovery->status()
              << "; stop with Ctrl-C or SIGTERM" << std::endl;

    waitForStopSignal(stopSignals, "pnp device " + command);
    adapter->stop();  // unregisters, halts running skills, stops the server
    adapter.reset();
    discovery.reset();
    return kExitOk;
}

// The options every gripper adapter shares. `uaPort`: the OPC UA port's option names.
void addAdapterOptions(CLI::App* cmd, GripperAdapterOptions& o, const std::string& uaPort,
                       const std::string& defaultName, const std::string& offsetDefault) {
    cmd->add_option("--offset", o.offset,
                    "flange -> grip point x,y,z,a,b,c (m; rad about the fixed X, Y, Z axes); "
                    "default " +
                        offsetDefault);
    cmd->add_option("--serial-number", o.serialNumber,
                    "the gripper's serial number (shown as such)");
    cmd->add_option("--speed", o.speed, "jaw speed of the skills, m/s")
        ->capture_default_str()
        ->check(CLI::Range(0.001, 1.0));
    cmd->add_option("--poll-period", o.pollMs, "poll the gripper every MS ms")
        ->capture_default_str()
        ->check(CLI::Range(1, 10000));
    cmd->add_option("--poll-timeout", o.pollTimeoutMs, "each poll's deadline, ms")
        ->capture_default_str()
        ->check(CLI::Range(1, 10000));
    cmd->add_option("--grace", o.graceMs,
                    "withdraw the server after MS ms without an answer (power gone)")
        ->capture_default_str()
        ->check(CLI::Range(1, 600000));
    cmd->add_flag("--no-activate", o.noActivate,
                  "do not activate / home at power-up (the first skill does)");
    addServerOptions(cmd, o.serve, uaPort,
                     "OPC UA TCP port (0: a free port, kept across power-ups)");
    cmd->get_option("--name")->description(
        "the device's name: DeviceSet/<NAME>; also the ApplicationName and mDNS instance "
        "(default " +
        defaultName + ")");
}

}  // namespace

std::function<int()> addGripperDeviceCommands(CLI::App* device) {
    // One set of options per command (their OPC UA ports differ).
    auto options = [](std::uint16_t port) {
        auto o = std::make_shared<GripperAdapterOptions>();
        o->serve.port = port;
        return o;
    };
    auto o = options(4851);
    auto serial = std::make_shared<std::string>();
    auto slave = std::make_shared<int>(9);
    auto calibration = std::make_shared<std::string>();
    CLI::App* robotiq = device->add_subcommand(
        "robotiq",
        "a Robotiq 2F-85 (Modbus RTU) as a gripper device: Grasp, Release, MoveGripper, a "
        "Parallel grip point (src/device/gripper/README.md); served while the gripper answers");
    robotiq
        ->add_option("--serial", *serial,
                     "the serial line: /dev/ttyUSB0 (RS-485 converter), or `pnp sim`'s "
                     "pseudo-terminal")
        ->required();
    robotiq->add_option("--slave", *slave, "Modbus slave address")
        ->capture_default_str()
        ->check(CLI::Range(1, 247));
    robotiq->add_option("--calibration", *calibration,
                        "gPO fully open and with the fingers touching, OPEN,CLOSED (default "
                        "13,230: src/device/robotiq/README.md)");
    addAdapterOptions(robotiq, *o, "--port,--ua-port", "Robotiq", "0,0,0.2028,0,0,0");
    robotiq->footer(
        "Prints one JSON line (endpointUrl, applicationUri, device, gripPoint, skills); the "
        "server runs only while the gripper answers.\n"
        "Example: pnp device robotiq --serial /dev/ttyUSB0 --port 4851");

    std::vector<std::function<int()>> runners;
    runners.push_back([o, serial, slave, calibration, robotiq]() -> int {
        if (!*robotiq) return -1;
        device::robotiq::RobotiqConfig rc;
        rc.serialPath = *serial;
        rc.slave = *slave;
        if (!o->offset.empty()) rc.tipOffset = parseFrame("--offset", o->offset);
        rc.serialNumber = o->serialNumber;
        if (!calibration->empty()) rc.calibration = parseCalibration(*calibration);
        const sigset_t stopSignals = blockStopSignals();  // before any thread exists
        device::robotiq::RobotiqHardware hardware(rc);
        return runGripperAdapter("robotiq", hardware, "Robotiq", *o, stopSignals);
    });

#ifdef PNP_HAVE_DEVICE_WSG
    auto wo = options(4853);
    auto address = std::make_shared<std::string>();
    CLI::App* wsg = device->add_subcommand(
        "wsg",
        "a Schunk WSG 50 (its command set over TCP) as a gripper device: Grasp, Release, "
        "MoveGripper, a Parallel grip point; served while the gripper answers");
    wsg->add_option("--address", *address, "the gripper's HOST[:PORT] (default port 1000)")
        ->required();
    addAdapterOptions(wsg, *wo, "--port,--ua-port", "WSG50", "0,0,0.19,0,0,0");
    wsg->footer("Example: pnp device wsg --address 192.168.1.20 --port 4853");
    runners.push_back([o = wo, address, wsg]() -> int {
        if (!*wsg) return -1;
        auto hp = device::wsg::parseAddress(*address);
        if (!hp) throw UsageError("--address expects HOST[:PORT], got \"" + *address + "\"");
        device::wsg::WsgHardwareConfig wc;
        wc.host = hp->first;
        wc.port = hp->second;
        if (!o->offset.empty()) wc.gripPointOffset = parseFrame("--offset", o->offset);
        const sigset_t stopSignals = blockStopSignals();  // before any thread exists
        device::wsg::WsgHardware hardware(wc);
        return runGripperAdapter("wsg", hardware, "WSG50", *o, stopSignals);
    });
#endif

#ifdef PNP_HAVE_DEVICE_ECBPI
    auto eo = options(4852);
    auto iolink = std::make_shared<std::string>();
    auto ioPort = std::make_shared<std::size_t>(1);
    auto table = std::make_shared<std::string>();
    auto masterMap = std::make_shared<std::string>();
    CLI::App* ecbpi = device->add_subcommand(
        "ecbpi",
        "a Schmalz ECBPi vacuum gripper on an IO-Link master (Modbus TCP) as a gripper "
        "device: Grasp, Release, a Vacuum grip point; served while the gripper answers");
    ecbpi->add_option("--iolink", *iolink, "the IO-Link master's Modbus TCP HOST:PORT")->required();
    ecbpi->add_option("--port", *ioPort, "the master's IO-Link port the gripper is on")
        ->capture_default_str()
        ->check(CLI::Range(1, 64));
    ecbpi->add_option("--table", *table, "the gripper's process data table (default: installed)");
    ecbpi->add_option("--master-map", *masterMap, "the master's Modbus map (default: installed)");
    // --port is the IO-Link port here: the OPC UA port is --ua-port.
    addAdapterOptions(ecbpi, *eo, "--ua-port", "ECBPi", "0,0,0.1868,0,0,0");
    ecbpi->footer("Example: pnp device ecbpi --iolink 192.168.1.30:502 --port 1 --ua-port 4852");
    runners.push_back([o = eo, iolink, ioPort, table, masterMap, ecbpi]() -> int {
        if (!*ecbpi) return -1;
        device::ecbpi::EcbpiOptions options;
        options.ioLinkPort = *ioPort;
        options.table = *table;
        options.masterMap = *masterMap;
        options.serialNumber = o->serialNumber;
        if (!o->offset.empty()) options.offset = parseFrame("--offset", o->offset);
        auto parsed = device::ecbpi::parseIoLinkAddress(*iolink, options);
        if (!parsed) throw UsageError("--iolink: " + parsed.error());
        const sigset_t stopSignals = blockStopSignals();  // before any thread exists
        auto hardware = device::ecbpi::EcbpiHardware::create(*parsed);
        if (!hardware) {
            std::cerr << "error: " << hardware.error() << "\n";
            return kExitUaError;
        }
        return runGripperAdapter("ecbpi", **hardware, "ECBPi", *o, stopSignals);
    });
#endif

    return [runners]() -> int {
        for (const auto& run : runners)
            if (const int rc = run(); rc >= 0) return rc;
        return -1;
    };
}

}  // namespace pnp::cli
