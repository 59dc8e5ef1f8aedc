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
#include "ua/server/server.hpp"
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
    sim::cell::Simulator simulator(std::move(cell).value(), sc);

    ua::server::ServerConfig config;
    config.host = o.serve.host;
    config.port = o.serve.port;
    if (o.serve.discovery.name.empty())
        o.serve.discovery.name = "pnp sim " + simulator.description().name;
    applyDiscoveryConfig(config, o.serve.discovery, false);
    ua::server::Server server(config);
    sim::cell::GroundTruth truth(server, simulator, {.rate = o.truthRate});

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
    for (const auto& d : simulator.endpoints())
        devices.push_back({{"name", d.name},
                           {"device", d.device},
                           {"protocol", d.protocol},
                           {"address", d.host + ":" + std::to_string(d.port)}});
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

}  // namespace

std::function<int()> addSimCommands(CLI::App& app) {
    auto o = std::make_shared<SimOptions>();
    o->serve.port = 4850;
    CLI::App* cmd = app.add_subcommand(
        "sim",
        "run the simulated cell: the physical world, every device's controller on its own "
        "protocol (a UR controller over RTDE), the ground truth as an OPC UA server");
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
    return [cmd, o]() -> int {
        if (!*cmd) return -1;
        return runSim(*o);
    };
}

}  // namespace pnp::cli
