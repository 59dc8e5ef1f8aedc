// `pnp sim`: the simulated cell's hardware (src/sim/cell). Prints one JSON line with every
// device's address and the ground truth's endpoint, then runs until SIGINT / SIGTERM.
#include <signal.h>

#include <CLI/CLI.hpp>
#include <functional>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"
#include "sim/cell/ground_truth.hpp"
#include "sim/cell/simulator.hpp"
#include "ua/client/client.hpp"
#include "ua/server/server.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "value_text.hpp"
#include "world/cell_file.hpp"

namespace pnp::cli {

namespace {

struct SimOptions {
    std::string cell;
    double rate = 500.0;
    std::string deviceHost = "127.0.0.1";
    bool ephemeral = false;
    double truthRate = 125.0;
    ServeOptions serve;  // the ground truth's OPC UA server
    bool statsOnExit = false;
};

int runSim(SimOptions& o) {
    const std::filesystem::path file =
        o.cell.empty() ? sim::cell::defaultCellFile() : std::filesystem::path(o.cell);
    auto cell = world::loadCellFile(file);
    if (!cell) {
        std::cerr << "error: " << cell.error().message << "\n";
        return kExitUsage;
    }
    const sigset_t stopSignals = blockStopSignals();

    sim::cell::SimulatorConfig sc;
    sc.rate = o.rate;
    sc.bindAddress = o.deviceHost;
    sc.ephemeralPorts = o.ephemeral;
    sc.snapshotRate = std::min(o.truthRate, o.rate);
    sc.log = [](const std::string& line) { std::cerr << "pnp sim: " + line + "\n" << std::flush; };
    sim::cell::Simulator simulator(std::move(cell).value(), sc);

    ua::server::ServerConfig config;
    config.host = o.serve.host;
    config.port = o.serve.port;
    if (o.serve.discovery.name.empty())
        o.serve.discovery.name = "pnp sim " + simulator.description().name;
    applyDiscoveryConfig(config, o.serve.discovery, false);
    applyUsers(config, o.serve.discovery.security, true);
    ua::server::Server server(config);
    sim::cell::GroundTruth truth(server, simulator, {.rate = o.truthRate});
    finishServerSecurity(server, o.serve.discovery.security);

    try {
        simulator.start();
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        return kExitUaError;
    }
    try {
        server.start();
    } catch (const std::exception& e) {
        std::cerr << "error: ground truth server: cannot listen on " << o.serve.host << ":"
                  << o.serve.port << ": " << e.what() << "\n";
        return kExitUaError;
    }
    truth.start();
    std::unique_ptr<DiscoveryRuntime> discovery;
    try {
        discovery = std::make_unique<DiscoveryRuntime>(server, o.serve.discovery);
    } catch (const std::exception& e) {
        std::cerr << "error: discovery: " << e.what() << "\n";
        return kExitUaError;
    }

    Json devices = Json::array();
    for (const auto& d : simulator.endpoints()) {
        Json device = {{"name", d.name},
                       {"device", d.device},
                       {"protocol", d.protocol},
                       {"address", d.address()}};
        if (d.slave != 0) device["slave"] = d.slave;
        if (d.ioLinkPort != 0) device["iolink-port"] = d.ioLinkPort;
        devices.push_back(std::move(device));
    }
    Json line = {{"cell", simulator.description().name},
                 {"file", file.string()},
                 {"rate", simulator.rate()},
                 {"world", server.endpointUrl()},
                 {"devices", devices}};
    std::cout << line.dump() << std::endl;  // one line, flushed: adapters and tests read it
    std::cerr << "pnp sim: cell " << simulator.description().name << " from " << file.string()
              << " at " << simulator.rate() << " Hz; ground truth " << server.endpointUrl()
              << " (namespace " << sim::cell::kWorldNamespaceUri << "); " << discovery->status()
              << "; stop with Ctrl-C or SIGTERM" << std::endl;

    int sig = 0;
    while (sigwait(&stopSignals, &sig) != 0) {
    }
    const auto stats = simulator.stats();
    std::cerr << "pnp sim: " << (sig == SIGINT ? "SIGINT" : "SIGTERM") << ", stopping after "
              << stats.steps << " steps (" << stats.overruns << " late; step cost median "
              << stats.stepCostMedian * 1e6 << " us, p99 " << stats.stepCostP99 * 1e6 << " us; "
              << (stats.realtime ? "real-time" : "normal") << " scheduling)" << std::endl;
    discovery.reset();
    truth.stop();
    server.stop();
    simulator.stop();
    return kExitOk;
}

// `pnp sim tool|object ...`: the operator's hands, through the ground truth's methods.
struct OperatorOptions {
    std::string world = "opc.tcp://127.0.0.1:4850";
    int timeoutMs = 5000;
    std::string method;              // PutToolInDock, TakeToolOut, PlaceObject, RemoveObject
    std::vector<std::string> names;  // tool [dock] / object
    std::vector<double> xyz;         // PlaceObject
    std::vector<double> rpy{0.0, 0.0, 0.0};
    std::string object;
    std::string robot = "ur5";
    SecurityOptions security;
};

int runOperator(const OperatorOptions& o) {
    using namespace std::chrono;
    const auto deadline = steady_clock::now() + milliseconds(o.timeoutMs);
    std::vector<ua::Variant> inputs;
    for (const auto& n : o.names) inputs.emplace_back(ua::String(n));
    if (o.method == "PlaceObject") {
        Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
        pose.translation() = Eigen::Vector3d(o.xyz[0], o.xyz[1], o.xyz[2]);
        pose.linear() = (Eigen::AngleAxisd(o.rpy[2], Eigen::Vector3d::UnitZ()) *
                         Eigen::AngleAxisd(o.rpy[1], Eigen::Vector3d::UnitY()) *
                         Eigen::AngleAxisd(o.rpy[0], Eigen::Vector3d::UnitX()))
                            .toRotationMatrix();
        inputs.emplace_back(ua::toExtensionObject(ua::spatial::toFrame(pose)));
    }
    try {
        secureClients(o.security);
        ua::client::Client client;
        client.connect(o.world, ua::client::Anonymous{}, deadline);
        const ua::UInt16 ns = client.namespaceIndex(sim::cell::kWorldNamespaceUri, deadline);
        const auto r = client.call(ua::NodeId(ns, "World"), ua::NodeId(ns, "World." + o.method),
                                   std::move(inputs), deadline);
        client.disconnect();
        if (!r.ok()) {
            std::cerr << "error: " << o.method << ": " << statusText(r.status) << "\n";
            return kExitUaError;
        }
        const auto* error = r.outputs.empty() ? nullptr : r.outputs[0].scalar<ua::String>();
        if (error != nullptr && !error->empty()) {
            std::cerr << "error: " << *error << "\n";
            return kExitUsage;
        }
    } catch (const std::exception& e) {
        std::cerr << "error: " << o.world << ": " << e.what() << "\n";
        return kExitUaError;
    }
    return kExitOk;
}

}  // namespace

std::function<int()> addSimCommands(CLI::App& app) {
    auto o = std::make_shared<SimOptions>();
    o->serve.port = 4850;
    CLI::App* cmd = app.add_subcommand(
        "sim",
        "run the simulated cell: the physical world, every device on its own protocol (UR over "
        "RTDE, Robotiq over Modbus RTU, ECBPi over IO-Link/Modbus TCP, WSG 50 over TCP, the "
        "tool changer's ADC), the ground truth as an OPC UA server; `tool` / `object`: the "
        "operator's hands");
    cmd->add_option("--cell", o->cell,
                    "cell file (docs/cell-file.md; default: the thesis cell, "
                    "models/cells/thesis.yaml)");
    cmd->add_option("--rate", o->rate, "world steps per second")
        ->capture_default_str()
        ->check(CLI::Range(1.0, 10000.0));
    cmd->add_option("--device-host", o->deviceHost,
                    "address the device endpoints listen on (RTDE ...)")
        ->capture_default_str();
    cmd->add_flag("--ephemeral-ports", o->ephemeral,
                  "every device on a free port instead of the cell file's (see the JSON line)");
    cmd->add_option("--truth-rate", o->truthRate, "ground truth updates per second")
        ->capture_default_str()
        ->check(CLI::Range(1.0, 1000.0));
    cmd->add_option("--port", o->serve.port, "ground truth OPC UA port (0: any free port)")
        ->capture_default_str();
    cmd->add_option("--host", o->serve.host, "ground truth OPC UA listen address")
        ->capture_default_str();
    addDiscoveryOptions(cmd, o->serve.discovery, false);
    cmd->footer(
        "Prints one JSON line: {\"cell\", \"file\", \"rate\", \"world\": ground truth URL, "
        "\"devices\": [{\"name\", \"device\", \"protocol\", \"address\"}]}.\n"
        "Then: pnp device ur --controller 127.0.0.1:30004; pnp robot square auto");

    // The operator's hands in a running simulation.
    auto op = std::make_shared<OperatorOptions>();
    auto worldOption = [op](CLI::App* c) {
        c->add_option("--world", op->world, "the ground truth server of `pnp sim`")
            ->capture_default_str();
        c->add_option("--timeout", op->timeoutMs, "ms")->capture_default_str();
        addConnectionSecurityOptions(c, op->security);
    };
    CLI::App* tool = cmd->add_subcommand("tool", "an operator's hands on the tools");
    tool->require_subcommand(1);
    CLI::App* put =
        tool->add_subcommand("put", "put a tool (from the shelf or a dock) into an empty dock");
    put->add_option("tool", op->names, "TOOL DOCK")->expected(2)->required();
    worldOption(put);
    put->callback([op] { op->method = "PutToolInDock"; });
    CLI::App* take = tool->add_subcommand("take", "take a tool out of its dock (onto the shelf)");
    take->add_option("tool", op->object, "TOOL")->required();
    worldOption(take);
    take->callback([op] {
        op->method = "TakeToolOut";
        op->names = {op->object};
    });
    CLI::App* attach = tool->add_subcommand(
        "attach", "lock a tool on a robot's changer by hand (it is then powered)");
    attach->add_option("tool", op->object, "TOOL")->required();
    attach->add_option("--robot", op->robot, "the robot")->capture_default_str();
    worldOption(attach);
    attach->callback([op] {
        op->method = "AttachToolByHand";
        op->names = {op->robot, op->object};
    });
    CLI::App* detach =
        tool->add_subcommand("detach", "unlock a robot's tool by hand (onto the shelf)");
    detach->add_option("--robot", op->robot, "the robot")->capture_default_str();
    worldOption(detach);
    detach->callback([op] {
        op->method = "DetachToolByHand";
        op->names = {op->robot};
    });
    CLI::App* object = cmd->add_subcommand("object", "an operator's hands on the objects");
    object->require_subcommand(1);
    CLI::App* place = object->add_subcommand(
        "place",
        "place an object at X Y Z (its centre, world frame, m); it rests on what is below");
    place->add_option("object", op->object, "OBJECT")->required();
    place->add_option("xyz", op->xyz, "X Y Z")->expected(3)->required();
    place->add_option("--rpy", op->rpy, "roll pitch yaw (rad, fixed axes X Y Z)")->expected(3);
    worldOption(place);
    place->callback([op] {
        op->method = "PlaceObject";
        op->names = {op->object};
    });
    CLI::App* remove = object->add_subcommand("remove", "take an object out of the cell");
    remove->add_option("object", op->object, "OBJECT")->required();
    worldOption(remove);
    remove->callback([op] {
        op->method = "RemoveObject";
        op->names = {op->object};
    });

    return [cmd, o, op]() -> int {
        if (!*cmd) return -1;
        if (!op->method.empty()) return runOperator(*op);
        return runSim(*o);
    };
}

}  // namespace pnp::cli
