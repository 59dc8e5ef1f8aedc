// `pnp component pick-place [--kb LOCATION] [--kb-file FILE.ttl]...`: the Pick-and-Place
// component (src/component/pickplace/README.md) on its own server, with the world model in a
// knowledge base (embedded by default, loaded from models/kb/*.ttl; or a SPARQL 1.1
// endpoint). Registers with discovery like every pnp server; runs until SIGINT / SIGTERM.
#include <signal.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <functional>
#include <iostream>
#include <memory>

#include "commands.hpp"
#include "component/pickplace/knowledge.hpp"
#include "component/pickplace/pick_place.hpp"
#include "device_commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"

namespace pnp::cli {

namespace {

struct PickPlaceCliOptions {
    std::string kb = "embedded";
    std::vector<std::string> kbFiles;  // empty: every models/kb/*.ttl
    std::string componentName = "PickAndPlace";
    bool noMdns = false;
    int findTimeoutMs = 5000;
    int moveTimeoutMs = 30000;
    double approachHeight = 0.05;
    ServeOptions serve;
};

// The knowledge base with the files loaded (each into the graph named by its file URL).
std::shared_ptr<kb::KnowledgeBase> openKnowledge(const PickPlaceCliOptions& o) {
#ifdef PNP_HAVE_KB
    std::shared_ptr<kb::KnowledgeBase> knowledge = kb::open(o.kb == "embedded" ? "" : o.kb);
    std::vector<std::filesystem::path> files(o.kbFiles.begin(), o.kbFiles.end());
    if (files.empty()) files = component::pickplace::defaultKnowledgeFiles();
    for (const auto& f : files) {
        const auto n =
            knowledge->loadTurtle(f, "file://" + std::filesystem::absolute(f).string(),
                                  std::chrono::steady_clock::now() + std::chrono::seconds(30));
        std::cerr << "pnp component pick-place: " << f.string() << ": " << n << " triples"
                  << std::endl;
    }
    return knowledge;
#else
    (void)o;
    throw UsageError("this pnp was built without the knowledge base (src/kb)");
#endif
}

int runPickPlace(PickPlaceCliOptions& o) {
    if (o.serve.discovery.name.empty()) o.serve.discovery.name = "Pick and place";
    std::shared_ptr<kb::KnowledgeBase> knowledge;
    try {
        knowledge = openKnowledge(o);
    } catch (const UsageError&) {
        throw;
    } catch (const std::exception& e) {
        std::cerr << "error: the knowledge base: " << e.what() << "\n";
        return kExitUsage;
    }
    const sigset_t stopSignals = blockStopSignals();
    std::unique_ptr<mdns::Mdns> mdns = componentMdns(o.noMdns, o.serve, "pnp component pick-place");
    component::pickplace::PickPlaceOptions popt;
    popt.name = o.componentName;
    popt.knowledge = knowledge;
    if (!o.serve.discovery.lds.empty()) popt.detector.watcher.ldsUrls = {o.serve.discovery.lds};
    popt.detector.useDiscovery = mdns != nullptr || !o.serve.discovery.lds.empty();
    popt.findTimeout = std::chrono::milliseconds(o.findTimeoutMs);
    popt.moveTimeout = std::chrono::milliseconds(o.moveTimeoutMs);
    popt.plan.approachHeight = o.approachHeight;

    return serveUntilStopped(
        o.serve, stopSignals, "pnp component pick-place",
        [&](ua::server::Server& server) {
            return std::make_unique<component::pickplace::PickPlaceComponent>(server, popt,
                                                                              mdns.get());
        },
        [&](component::pickplace::PickPlaceComponent&, const std::string& discoveryStatus) {
            std::cerr << "pnp component pick-place: DeviceSet/" << o.componentName
                      << "/Skills/PickAndPlace; knowledge base " << knowledge->describe() << "; "
                      << discoveryStatus << "; stop with Ctrl-C or SIGTERM" << std::endl;
        });
}

}  // namespace

// Adds `pick-place` below the `component` subcommand (created by addComponentCommands).
std::function<int()> addPickPlaceCommand(CLI::App& app) {
    auto o = std::make_shared<PickPlaceCliOptions>();
    o->serve.port = 4856;
    CLI::App* component = app.get_subcommand("component");
    CLI::App* cmd = component->add_subcommand(
        "pick-place",
        "the Pick-and-Place component: PickAndPlace with the robot's CartesianLinearMove and "
        "the tool's Grasp / Release, objects from the knowledge base "
        "(src/component/pickplace/README.md)");
    cmd->add_option("--kb", o->kb,
                    "the knowledge base: embedded, or a SPARQL 1.1 endpoint http://HOST:PORT/PATH")
        ->capture_default_str();
    cmd->add_option("--kb-file", o->kbFiles,
                    "load this Turtle file (repeatable; default: every models/kb/*.ttl)");
    cmd->add_option("--component-name", o->componentName, "BrowseName below DeviceSet")
        ->capture_default_str();
    cmd->add_flag("--no-mdns", o->noMdns, "find the robot and tools only through --lds");
    cmd->add_option("--find-timeout", o->findTimeoutMs,
                    "a run waits this long (ms) for the robot / tool to be detected")
        ->capture_default_str()
        ->check(CLI::Range(1, 600000));
    cmd->add_option("--move-timeout", o->moveTimeoutMs, "deadline of each robot move, ms")
        ->capture_default_str()
        ->check(CLI::Range(1, 600000));
    cmd->add_option("--approach-height", o->approachHeight,
                    "m above the pick and place poses the approaches start and end")
        ->capture_default_str()
        ->check(CLI::Range(0.0, 0.5));
    addServerOptions(cmd, o->serve);
    cmd->get_option("--lds")->description(
        "register with this LDS-ME, and find the robot and the tools there too");
    cmd->footer(
        "Prints `listening on opc.tcp://HOST:PORT` once ready.\n"
        "Example: pnp component pick-place --lds opc.tcp://127.0.0.1:4840 --no-mdns; then\n"
        "  pnp skill run PickAndPlaceSkillType ObjectId=cube-green "
        "PlacePosition=-0.05,-0.10,0,0,0,0");
    return [o, cmd]() -> int {
        if (!*cmd) return -1;
        return runPickPlace(*o);
    };
}

}  // namespace pnp::cli
