// `pnp device ur`: a Universal Robots arm on OPC UA — UrHardware (RTDE) under the
// vendor-neutral robot::Controller and Planner, shown by RobotDevice as an OPC 40010-1
// MotionDeviceSystem with the move skills (src/device/robot/README.md). Registers with
// discovery like every pnp server; runs until SIGINT / SIGTERM, then halts any motion.
// Also what every device and component command shares (device_commands.hpp).
#include <signal.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>

// clang-format off
// First: inside pnp::device::ur this header names pnp::robot as `robot::`, which would find
// pnp::device::robot once robot_device.hpp has declared it.
#include "device/ur/ur_hardware.hpp"
// clang-format on

#include "commands.hpp"
#include "device/robot/robot_device.hpp"
#include "device_commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"
#include "robot/controller.hpp"
#include "robot/planner.hpp"
#include "ua/spatial/spatial.hpp"

namespace pnp::cli {

namespace {

struct UrDeviceOptions {
    std::string controller;  // HOST[:PORT] of the robot's RTDE interface
    std::string model = "ur5";
    std::string worldToBase;  // x,y,z,a,b,c (m, rad); empty: identity
    double frequency = 500.0;
    int connectTimeoutMs = 10000;
    std::string serialNumber;
    ServeOptions serve;
};

// "host", "host:port", "[v6]:port" -> host and port (default RTDE port).
std::pair<std::string, std::uint16_t> splitHostPort(const std::string& text) {
    std::string host = text;
    std::string port;
    if (!text.empty() && text.front() == '[') {
        const auto close = text.find(']');
        if (close == std::string::npos) throw UsageError("--controller: missing ']' in " + text);
        host = text.substr(1, close - 1);
        if (close + 1 < text.size()) {
            if (text[close + 1] != ':') throw UsageError("--controller: bad address " + text);
            port = text.substr(close + 2);
        }
    } else if (const auto colon = text.rfind(':');
               colon != std::string::npos && text.find(':') == colon) {
        host = text.substr(0, colon);
        port = text.substr(colon + 1);
    }
    if (host.empty()) throw UsageError("--controller expects HOST[:PORT], got \"" + text + "\"");
    if (port.empty()) return {host, rtde::kDefaultPort};
    char* end = nullptr;
    const long p = std::strtol(port.c_str(), &end, 10);
    if (*end != '\0' || p < 1 || p > 65535)
        throw UsageError("--controller: bad port \"" + port + "\"");
    return {host, static_cast<std::uint16_t>(p)};
}

int runUrDevice(UrDeviceOptions& o) {
    const auto [host, port] = splitHostPort(o.controller);
    auto model = device::ur::modelByName(o.model);
    if (!model) throw UsageError("--model: unknown arm \"" + o.model + "\" (ur3, ur5, ur10)");
    const Eigen::Isometry3d worldToBase = o.worldToBase.empty()
                                              ? Eigen::Isometry3d::Identity()
                                              : parseFrame("--world-to-base", o.worldToBase);
    // The device's name is also the server's ApplicationName (and mDNS instance).
    std::string& name = o.serve.discovery.name;
    if (name.empty()) name = model->name;

    // Before any thread exists: every thread inherits the mask; this one sigwait()s.
    const sigset_t stopSignals = blockStopSignals();

    device::ur::UrConfig uc;
    uc.host = host;
    uc.port = port;
    uc.frequency = o.frequency;
    uc.model = *model;
    uc.serialNumber = o.serialNumber;
    device::ur::UrHardware hardware(uc);

    const motion::Limits limits = device::robot::defaultLimits(*model);
    robot::ControllerConfig cc;
    cc.limits = limits.joint;
    cc.log = [](const std::string& line) { std::cerr << "pnp device ur: " << line << std::endl; };
    robot::Controller controller(hardware, cc);
    auto started =
        controller.start(robot::Clock::now() + std::chrono::milliseconds(o.connectTimeoutMs));
    if (!started) {
        std::cerr << "error: robot controller " << hardware.endpoint() << ": "
                  << started.error().message << "\n";
        return kExitUaError;
    }
    robot::PlannerConfig pc;
    pc.model = *model;
    pc.worldToBase = worldToBase;
    pc.defaults = limits;
    robot::Planner planner(pc);

    const int rc = serveUntilStopped(
        o.serve, stopSignals, "pnp device ur",
        [&](ua::server::Server& server) {
            return std::make_unique<device::robot::RobotDevice>(
                server, controller, planner,
                device::robot::RobotDeviceOptions{.name = name,
                                                  .identity = device::robot::identityOf(hardware)});
        },
        [&](device::robot::RobotDevice&, const std::string& discoveryStatus) {
            std::cerr << "pnp device ur: " << name << " (" << model->name << ") at "
                      << hardware.endpoint();
            if (auto v = hardware.controllerVersion())
                std::cerr << ", controller software " << v->major << "." << v->minor << "."
                          << v->bugfix;
            std::cerr << "; DeviceSet/" << name << "System with the move skills; "
                      << discoveryStatus << "; stop with Ctrl-C or SIGTERM" << std::endl;
        });
    controller.stop();  // after the device: a running move was halted (the arm brakes to rest)
    return rc;
}

}  // namespace

void addServerOptions(CLI::App* cmd, ServeOptions& serve, const std::string& portNames,
                      const std::string& portHelp) {
    cmd->add_option(portNames, serve.port, portHelp)->capture_default_str();
    cmd->add_option("--host", serve.host, "address to listen on")->capture_default_str();
    addDiscoveryOptions(cmd, serve.discovery, false);
}

ua::server::ServerConfig serverConfig(const ServeOptions& serve) {
    ua::server::ServerConfig config;
    config.host = serve.host;
    config.port = serve.port;
    applyDiscoveryConfig(config, serve.discovery, false);
    return config;
}

Eigen::Isometry3d parseFrame(const std::string& option, const std::string& text) {
    std::vector<double> v;
    std::stringstream in(text);
    std::string item;
    while (std::getline(in, item, ',')) {
        char* end = nullptr;
        const double d = std::strtod(item.c_str(), &end);
        if (item.empty() || *end != '\0' || !std::isfinite(d))
            throw UsageError(option + ": \"" + item + "\" is not a finite number");
        v.push_back(d);
    }
    if (v.size() != 6)
        throw UsageError(option + " expects x,y,z,a,b,c (6 numbers), got \"" + text + "\"");
    ua::ThreeDFrame f;
    f.cartesianCoordinates = {v[0], v[1], v[2]};
    f.orientation = {v[3], v[4], v[5]};
    return ua::spatial::toIsometry(f);
}

void waitForStopSignal(const sigset_t& stopSignals, const std::string& who) {
    int sig = 0;
    while (sigwait(&stopSignals, &sig) != 0) {
    }
    std::cerr << who << ": " << (sig == SIGINT ? "SIGINT" : "SIGTERM") << ", stopping" << std::endl;
}

std::function<int()> addKelvinAdcCommand(CLI::App& device);  // toolchanger_commands.cpp

std::function<int()> addDeviceCommands(CLI::App& app) {
    auto o = std::make_shared<UrDeviceOptions>();
    o->serve.port = 4841;
    CLI::App* device = app.add_subcommand("device", "run a device adapter: a device on OPC UA");
    device->require_subcommand(1);
    CLI::App* ur = device->add_subcommand(
        "ur",
        "a Universal Robots arm (RTDE) as an OPC 40010-1 motion device with the move skills "
        "(src/device/robot/README.md)");
    ur->add_option("--controller", o->controller,
                   "the robot's RTDE interface HOST[:PORT] (default port 30004)")
        ->required();
    ur->add_option("--model", o->model, "the arm: ur3, ur5, ur10 (an e suffix is accepted)")
        ->capture_default_str();
    ur->add_option("--world-to-base", o->worldToBase,
                   "the robot base in the world frame x,y,z,a,b,c (m; rad about the fixed X, Y, "
                   "Z axes); default identity; writable later as WorldToRobotBase");
    ur->add_option("--frequency", o->frequency, "RTDE output frequency, Hz (500 e-Series, 125 CB3)")
        ->capture_default_str()
        ->check(CLI::Range(1.0, 500.0));
    ur->add_option("--connect-timeout", o->connectTimeoutMs,
                   "give up when the robot controller does not answer within MS ms")
        ->capture_default_str()
        ->check(CLI::Range(100, 600000));
    ur->add_option("--serial-number", o->serialNumber, "the arm's serial number (shown as such)");
    addServerOptions(ur, o->serve);
    // The discovery options' --name names the device too (BrowseNames, ApplicationName).
    ur->get_option("--name")->description(
        "the device's name: DeviceSet/<NAME>System, MotionDevices/<NAME>; also the "
        "ApplicationName and mDNS instance (default: the model, e.g. UR5)");
    ur->footer(
        "Prints `listening on opc.tcp://HOST:PORT` once ready; stops on SIGINT/SIGTERM (a "
        "running move is halted first).\n"
        "Example: pnp device ur --controller 192.168.1.10 --name UR5 --port 4841");
    const auto runGripper = addGripperDeviceCommands(device);  // robotiq, wsg, ecbpi
    const auto runKelvinAdc = addKelvinAdcCommand(*device);    // toolchanger_commands.cpp
    return [o, ur, runGripper, runKelvinAdc]() -> int {
        if (const int rc = runKelvinAdc(); rc >= 0) return rc;
        if (!*ur) return runGripper();
        return runUrDevice(*o);
    };
}

std::unique_ptr<mdns::Mdns> componentMdns(bool noMdns, const ServeOptions& serve,
                                          const std::string& who) {
    if (noMdns) return nullptr;
    try {
        auto m = std::make_unique<mdns::Mdns>(
            mdnsConfig(serve.discovery.mdnsInterfaces, serve.discovery.mdnsPort, 120));
        m->start();
        return m;
    } catch (const std::exception& e) {
        std::cerr << who << ": no mDNS (" << e.what() << "); only --lds and the given URLs"
                  << std::endl;
        return nullptr;
    }
}

}  // namespace pnp::cli
