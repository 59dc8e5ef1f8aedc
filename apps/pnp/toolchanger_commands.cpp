// The Kelvin tool changer on the command line:
//   `pnp device kelvin-adc --adc HOST[:PORT]`: the changer's ADC board (Modbus TCP analog
//     input) as an OPC UA device, KelvinToolChangerType (src/device/kelvin/README.md);
//   `pnp component toolchanger --robot URL|auto [--adc URL|auto]`: the tool changer component
//     with ChangeTool / AttachTool / DetachTool / DropTool (src/component/toolchanger/README.md).
// Both register with discovery like every pnp server and run until SIGINT / SIGTERM.
#include <signal.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <functional>
#include <iostream>
#include <memory>

#include "commands.hpp"
#include "component/toolchanger/tool_changer.hpp"
#include "device/kelvin/kelvin_adc_device.hpp"
#include "device_commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"

namespace pnp::cli {

namespace {

struct KelvinAdcOptions {
    std::string adc;  // HOST[:PORT] of the board's Modbus TCP interface
    std::string deviceName = "ToolChanger";
    int unitId = 0xFF;
    int pollMs = 10;
    int timeoutMs = 50;
    ServeOptions serve;
};

int runKelvinAdc(KelvinAdcOptions& o) {
    std::pair<std::string, std::uint16_t> address;
    try {
        address = device::kelvin::parseModbusAddress(o.adc);
    } catch (const std::exception& e) {
        throw UsageError(std::string("--adc: ") + e.what());
    }
    if (o.serve.discovery.name.empty()) o.serve.discovery.name = "Kelvin ADC";
    const sigset_t stopSignals = blockStopSignals();

    return serveUntilStopped(
        o.serve, stopSignals, "pnp device kelvin-adc",
        [&](ua::server::Server& server) {
            device::kelvin::KelvinAdcDeviceOptions dopt;
            dopt.name = o.deviceName;
            dopt.adcHost = address.first;
            dopt.adcPort = address.second;
            dopt.unitId = o.unitId;
            dopt.pollPeriod = std::chrono::milliseconds(o.pollMs);
            dopt.responseTimeout = std::chrono::milliseconds(o.timeoutMs);
            return std::make_unique<device::kelvin::KelvinAdcDevice>(server, dopt);
        },
        [&](device::kelvin::KelvinAdcDevice& device, const std::string& discoveryStatus) {
            std::cerr << "pnp device kelvin-adc: DeviceSet/" << o.deviceName
                      << " (KelvinToolChangerType) reading Modbus TCP " << device.adcEndpoint()
                      << " every " << o.pollMs << " ms; " << discoveryStatus
                      << "; stop with Ctrl-C or SIGTERM" << std::endl;
        });
}

struct ToolChangerCliOptions {
    std::string robot;
    std::string adc = "auto";
    std::string componentName = "ToolChanger";
    bool noMdns = false;
    int findTimeoutMs = 5000;
    int toolTimeoutMs = 15000;
    int readyTimeoutMs = 0;      // 0: do not wait before serving
    double travelHeight = 0.10;  // m, world z
    ServeOptions serve;
};

int runToolChanger(ToolChangerCliOptions& o) {
    if (o.robot.empty()) throw UsageError("--robot URL|auto is required");
    for (const std::string* u : {&o.robot, &o.adc})
        if (*u != "auto" && !u->starts_with("opc.tcp://"))
            throw UsageError("--robot / --adc take an opc.tcp:// URL or auto, got \"" + *u + "\"");
    if (!std::isfinite(o.travelHeight)) throw UsageError("--travel-height must be finite");
    if (o.serve.discovery.name.empty()) o.serve.discovery.name = "Tool changer";
    const sigset_t stopSignals = blockStopSignals();

    // The detector's own mDNS browser (the server's responder is DiscoveryRuntime's).
    std::unique_ptr<mdns::Mdns> mdns =
        componentMdns(o.noMdns, o.serve, "pnp component toolchanger");
    component::toolchanger::ToolChangerOptions topt;
    topt.name = o.componentName;
    topt.robot = o.robot;
    topt.adc = o.adc;
    if (!o.serve.discovery.lds.empty()) topt.detector.watcher.ldsUrls = {o.serve.discovery.lds};
    topt.detector.useDiscovery = mdns != nullptr || !o.serve.discovery.lds.empty();
    topt.findTimeout = std::chrono::milliseconds(o.findTimeoutMs);
    topt.toolDetectTimeout = std::chrono::milliseconds(o.toolTimeoutMs);
    topt.travelHeight = o.travelHeight;

    return serveUntilStopped(
        o.serve, stopSignals, "pnp component toolchanger",
        [&](ua::server::Server& server) {
            return std::make_unique<component::toolchanger::ToolChangerComponent>(server, topt,
                                                                                  mdns.get());
        },
        [&](component::toolchanger::ToolChangerComponent& changer,
            const std::string& discoveryStatus) {
            std::cerr << "pnp component toolchanger: DeviceSet/" << o.componentName
                      << " with ChangeTool, AttachTool, DetachTool, DropTool; robot " << o.robot
                      << ", ADC " << o.adc << "; " << discoveryStatus
                      << "; stop with Ctrl-C or SIGTERM" << std::endl;
            if (o.readyTimeoutMs > 0) {
                const std::string why =
                    changer.waitReady(std::chrono::milliseconds(o.readyTimeoutMs));
                std::cerr << "pnp component toolchanger: "
                          << (why.empty() ? std::string("ready (robot and ADC found)")
                                          : "not ready: " + why)
                          << std::endl;
            }
        });
}

}  // namespace

std::function<int()> addKelvinAdcCommand(CLI::App& device) {
    auto o = std::make_shared<KelvinAdcOptions>();
    o->serve.port = 4846;
    CLI::App* cmd = device.add_subcommand(
        "kelvin-adc",
        "the Kelvin tool changer's ADC board (Modbus TCP analog input) as an OPC UA device: "
        "Voltage, State, ToolId (src/device/kelvin/README.md)");
    cmd->add_option("--adc", o->adc,
                    "the board's Modbus TCP interface HOST[:PORT] (default port 502)")
        ->required();
    cmd->add_option("--device-name", o->deviceName, "BrowseName below DeviceSet")
        ->capture_default_str();
    cmd->add_option("--unit-id", o->unitId, "Modbus unit id")
        ->capture_default_str()
        ->check(CLI::Range(0, 255));
    cmd->add_option("--poll", o->pollMs, "read the board every MS ms")
        ->capture_default_str()
        ->check(CLI::Range(1, 10000));
    cmd->add_option("--timeout", o->timeoutMs, "deadline of each Modbus call, ms")
        ->capture_default_str()
        ->check(CLI::Range(1, 10000));
    addServerOptions(cmd, o->serve);
    cmd->footer(
        "Prints `listening on opc.tcp://HOST:PORT` once ready.\n"
        "Example: pnp device kelvin-adc --adc 127.0.0.1:1502 --port 4846");
    return [o, cmd]() -> int {
        if (!*cmd) return -1;
        return runKelvinAdc(*o);
    };
}

std::function<int()> addComponentCommands(CLI::App& app) {
    auto o = std::make_shared<ToolChangerCliOptions>();
    o->serve.port = 4855;  // 4850 is `pnp sim`'s ground truth
    CLI::App* component =
        app.add_subcommand("component", "run a software component: skills built on other skills");
    component->require_subcommand(1);
    CLI::App* cmd = component->add_subcommand(
        "toolchanger",
        "the tool changer: ChangeTool, AttachTool, DetachTool, DropTool with the robot's "
        "CartesianLinearMove and the Kelvin ADC (src/component/toolchanger/README.md)");
    cmd->add_option("--robot", o->robot,
                    "the robot carrying the changer: its server's opc.tcp:// URL, or auto (the "
                    "only robot discovered)")
        ->required();
    cmd->add_option("--adc", o->adc, "the Kelvin ADC board's server URL, or auto (discovered)")
        ->capture_default_str();
    cmd->add_option("--component-name", o->componentName, "BrowseName below DeviceSet")
        ->capture_default_str();
    cmd->add_flag("--no-mdns", o->noMdns,
                  "find the robot, ADC and tools only through --lds and the given URLs");
    cmd->add_option("--find-timeout", o->findTimeoutMs,
                    "a run waits this long (ms) for the robot / ADC to be found")
        ->capture_default_str();
    cmd->add_option("--tool-timeout", o->toolTimeoutMs,
                    "after a lock, wait this long (ms) for the tool's server and skills")
        ->capture_default_str();
    cmd->add_option("--travel-height", o->travelHeight,
                    "world z (m) that the tool's grip point (no tool: the flange) stays above "
                    "while the arm travels to and from a dock; after an attach the tool is "
                    "lifted to it")
        ->capture_default_str()
        ->check(CLI::Range(-10.0, 10.0));
    cmd->add_option("--wait-ready", o->readyTimeoutMs,
                    "at start, wait up to MS ms for the robot and the ADC and say so (0: no)")
        ->capture_default_str();
    addServerOptions(cmd, o->serve);
    cmd->get_option("--lds")->description(
        "register with this LDS-ME, and find the robot, the ADC and the tools there too");
    cmd->footer(
        "Prints `listening on opc.tcp://HOST:PORT` once ready.\n"
        "Example: pnp component toolchanger --robot opc.tcp://127.0.0.1:4841 --adc auto");
    return [o, cmd]() -> int {
        if (!*cmd) return -1;
        return runToolChanger(*o);
    };
}

}  // namespace pnp::cli
