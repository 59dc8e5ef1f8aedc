// pnp: the command line entry point (CLI11). Exit codes: 0 ok, 1 OPC UA error (the status
// name is printed), 2 usage error.
#include <signal.h>

#include <CLI/CLI.hpp>
#include <functional>
#include <iostream>

#include "commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"
#include "ua/client/error.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "value_text.hpp"

namespace pnp::cli {
// bench_commands.cpp: adds `pnp bench ...`; the function runs the parsed one (-1: none).
std::function<int()> addBenchCommands(CLI::App& app);
// The cell's devices, same pattern: sim_commands.cpp (`pnp sim`), device_commands.cpp
// (`pnp device ...`), robot_commands.cpp (`pnp robot ...`).
std::function<int()> addSimCommands(CLI::App& app);
std::function<int()> addDeviceCommands(CLI::App& app);
std::function<int()> addRobotCommands(CLI::App& app);
std::function<int()> addComponentCommands(CLI::App& app);  // toolchanger_commands.cpp
std::function<int()> addPickPlaceCommand(CLI::App& app);   // pickplace_commands.cpp
std::function<int()> addCellCommands(CLI::App& app);       // cell_commands.cpp
std::function<int()> addMesCommands(CLI::App& app);        // mes_commands.cpp
std::function<int()> addPkiCommands(CLI::App& app);        // pki_commands.cpp
std::function<int()> addUserCommands(CLI::App& app);       // user_commands.cpp
std::function<int()> addDashboardCommand(CLI::App& app);   // dashboard_commands.cpp
}  // namespace pnp::cli

namespace {

using namespace pnp::cli;

constexpr const char* kNodeHelp =
    "node: i=85 | ns=2;s=Name | nsu=urn:pnp:demo;s=Demo | /Objects/Server/ServerStatus";

void addClientOptions(CLI::App* cmd, ClientOptions& o) {
    cmd->add_option("URL", o.url, "server endpoint, e.g. opc.tcp://127.0.0.1:4840")
        ->required()
        ->check([](const std::string& s) {
            return s.starts_with("opc.tcp://") ? std::string()
                                               : "URL must start with opc.tcp:// (got " + s + ")";
        });
    cmd->add_flag("--json", o.json, "print JSON (documented in apps/pnp/README.md)");
    cmd->add_option("--timeout", o.timeoutMs, "timeout of connect and of each request, in ms")
        ->capture_default_str()
        ->check(CLI::Range(1, 3600000));
    cmd->add_option("--user", o.user, "user name identity NAME:PASSWORD (default: anonymous)");
    addClientSecurityOptions(cmd, o.security);
}

int uaError(const pnp::ua::client::Error& e, bool json) {
    std::cerr << "error: " << e.what() << "\n";
    if (json) {
        Json j = {{"error",
                   {{"status", statusText(e.status())},
                    {"statusCode", e.status().value},
                    {"message", e.what()}}}};
        std::cout << j.dump(2) << '\n';
    }
    return kExitUaError;
}

}  // namespace

int main(int argc, char** argv) {
    signal(SIGPIPE, SIG_IGN);  // a closed pipe or socket is an error return, not a signal

    CLI::App app{"pnp — Plug & Produce robot cells on OPC UA", "pnp"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "pnp 0.1.0");
    app.footer(
        "Run `pnp ua --help` for the OPC UA tools, `pnp lds --help` and `pnp discover --help` "
        "for discovery (docs/discovery.md), `pnp skills --help` and `pnp skill run --help` for "
        "skills (docs/skills.md), `pnp bench middleware --help` for the middleware evaluation "
        "(docs/middleware_bench.md), `pnp sim --help`, `pnp device ur --help` and `pnp robot "
        "square --help` for the simulated robot cell (README, docs/ur-real-robot.md), `pnp "
        "device robotiq|ecbpi|wsg|kelvin-adc --help` and `pnp component toolchanger --help` "
        "for its tools (README \"Tools that plug in\"), `pnp cell run --help` for the main job, "
        "`pnp mes --help` and `pnp component pick-place --help` for the process and its skills "
        "(docs/kb-vocabulary.md), `pnp dashboard --help` to watch the cell (docs/dashboard.md), "
        "`pnp pki --help` and `pnp user --help` for certificates, trust and users "
        "(docs/security.md).");

    std::uint16_t ldsPort = 4840;
    std::string ldsHost = "0.0.0.0";
    DiscoveryOptions ldsOpts;
    CLI::App* lds =
        app.add_subcommand("lds", "run a Local Discovery Server with multicast extension (LDS-ME)");
    lds->add_option("--port", ldsPort, "TCP port (0: any free port)")->capture_default_str();
    lds->add_option("--host", ldsHost, "address to listen on")->capture_default_str();
    addDiscoveryOptions(lds, ldsOpts, true);
    lds->footer(
        "Prints `listening on opc.tcp://HOST:PORT` once ready; stops on SIGINT/SIGTERM.\n"
        "Servers register with RegisterServer2 and are announced by mDNS until they "
        "unregister or their registration expires.");

    DiscoverOptions discoverOpts;
    CLI::App* discover = app.add_subcommand(
        "discover", "list OPC UA servers on the network as they come and go (mDNS + LDS-MEs)");
    discover->add_flag("--json", discoverOpts.json, "one JSON object per line (--once: a list)");
    discover->add_option("--duration", discoverOpts.durationMs, "stop after MS ms (0: Ctrl-C)");
    discover->add_flag("--once", discoverOpts.once,
                       "print the servers found within --duration (default 2000) and exit");
    discover->add_option("--lds", discoverOpts.lds, "also poll this LDS-ME (repeatable)");
    discover->add_flag("--no-details", discoverOpts.noDetails,
                       "do not ask each server for its description and endpoints");
    discover->add_flag("--no-mdns", discoverOpts.noMdns,
                       "no multicast: only poll the --lds LDS-MEs (and those they list)");
    discover->add_option("--mdns-interface", discoverOpts.mdnsInterfaces,
                         "mDNS on this interface (repeatable; default all)");
    discover->add_option("--mdns-port", discoverOpts.mdnsPort, "mDNS UDP port")
        ->capture_default_str()
        ->check(CLI::Range(1, 65535));
    discover->add_option("--poll", discoverOpts.pollMs, "LDS-ME polling period, ms")
        ->capture_default_str()
        ->check(CLI::Range(10, 600000));

    ServeOptions skillsOpts;
    skillsOpts.skillController = "DemoGripper";
    CLI::App* demoSkills = app.add_subcommand(
        "demo-skills",
        "run a skill server: a demo gripper with the skills Delay, Grasp, Release, "
        "MoveGripper (docs/skills.md)");
    demoSkills->add_option("--port", skillsOpts.port, "TCP port (0: any free port)")
        ->capture_default_str();
    demoSkills->add_option("--host", skillsOpts.host, "address to listen on")
        ->capture_default_str();
    demoSkills
        ->add_option("--controller", skillsOpts.skillController,
                     "name of the skill controller (the device node)")
        ->capture_default_str();
    addDiscoveryOptions(demoSkills, skillsOpts.discovery, false);
    demoSkills->footer(
        "Prints `listening on opc.tcp://HOST:PORT` once ready; stops on SIGINT/SIGTERM.\n"
        "Try: pnp skills --once; pnp skill run opc.tcp://127.0.0.1:4840 Delay DurationMs=500");

    SkillsOptions skillsListOpts;
    CLI::App* skillsCmd = app.add_subcommand(
        "skills", "list the skills on the network as they come and go (skill detector)");
    skillsCmd->add_flag("--json", skillsListOpts.json, "one JSON object per line (--once: a list)");
    addConnectionSecurityOptions(skillsCmd, skillsListOpts.security);
    skillsCmd->add_flag("--once", skillsListOpts.once,
                        "print the skills found and exit: after --duration MS, or (default) once "
                        "every server discovered within 2 s has been examined (15 s at most)");
    skillsCmd->add_option("--duration", skillsListOpts.durationMs, "stop after MS ms (0: Ctrl-C)");
    skillsCmd->add_option("--type", skillsListOpts.type,
                          "only skills of this type or a subtype (e.g. GripperSkillType)");
    skillsCmd->add_option("--lds", skillsListOpts.lds, "also poll this LDS-ME (repeatable)");
    skillsCmd->add_option("--url", skillsListOpts.urls,
                          "also examine this server directly (repeatable)");
    skillsCmd->add_flag("--no-mdns", skillsListOpts.noMdns, "no multicast: --lds / --url only");
    skillsCmd->add_option("--mdns-interface", skillsListOpts.mdnsInterfaces,
                          "mDNS on this interface (repeatable; default all)");
    skillsCmd->add_option("--mdns-port", skillsListOpts.mdnsPort, "mDNS UDP port")
        ->capture_default_str()
        ->check(CLI::Range(1, 65535));

    SkillRunOptions skillRunOpts;
    CLI::App* skillCmd = app.add_subcommand("skill", "use one skill (docs/skills.md)");
    skillCmd->require_subcommand(1);
    CLI::App* skillRun = skillCmd->add_subcommand(
        "run",
        "run a skill: lock it, write the parameters, start it, print its transitions "
        "and its result, unlock it");
    skillRun
        ->add_option("TARGET", skillRunOpts.target,
                     "the server (opc.tcp://HOST:PORT) or a skill type (e.g. MoveGripperSkillType, "
                     "found by discovery)")
        ->required();
    skillRun->add_option("PARAMETERS", skillRunOpts.assignments,
                         "Name=value (typed by the parameter's DataType: 0.05, [1,2,3], "
                         "x,y,z,a,b,c for a ThreeDFrame)");
    skillRun->add_option("--skill", skillRunOpts.skill,
                         "the skill's name on its component (when there are several)");
    skillRun->add_flag("--json", skillRunOpts.json, "print one JSON object");
    skillRun
        ->add_option("--timeout", skillRunOpts.timeoutMs,
                     "deadline of the whole run (of each run with --repeat), ms")
        ->capture_default_str()
        ->check(CLI::Range(1, 86400000));
    skillRun
        ->add_option("--repeat", skillRunOpts.repeat,
                     "run it this many times in a row on one connection and print a summary "
                     "(results, median / p99 / max duration): a soak test")
        ->capture_default_str()
        ->check(CLI::Range(1, 1000000));
    skillRun->add_option("--lds", skillRunOpts.lds, "look for TYPE at this LDS-ME too");
    addConnectionSecurityOptions(skillRun, skillRunOpts.security);
    skillRun->add_flag("--no-mdns", skillRunOpts.noMdns, "no multicast (with --lds)");
    skillRun->add_option("--mdns-port", skillRunOpts.mdnsPort, "mDNS UDP port")
        ->capture_default_str()
        ->check(CLI::Range(1, 65535));
    skillRun
        ->add_option("--discover", skillRunOpts.discoverMs,
                     "how long to look for a skill of TYPE, ms")
        ->capture_default_str();
    skillRun->footer(
        "Ctrl-C (SIGINT) or SIGTERM during the run halts the skill and unlocks it.\n"
        "Exit codes: 0 Completed, 1 OPC UA error, 2 usage error, 3 Failed / Aborted / timed "
        "out / interrupted (halted).\n"
        "Example: pnp skill run opc.tcp://127.0.0.1:4840 --skill MoveGripper Width=0.02");

    CLI::App* ua =
        app.add_subcommand("ua", "OPC UA tools: a demo server and a command-line client");
    ua->require_subcommand(1);
    ua->footer(
        "Exit codes: 0 ok, 1 OPC UA error (status name printed), 2 usage error.\n"
        "Examples:\n"
        "  pnp ua serve --port 4840 --user operator:secret\n"
        "  pnp ua browse opc.tcp://127.0.0.1:4840 i=85 --depth 2\n"
        "  pnp ua read  opc.tcp://127.0.0.1:4840 /Objects/Server/ServerStatus/State\n"
        "  pnp ua write opc.tcp://127.0.0.1:4840 \"nsu=urn:pnp:demo;s=Array.Int32\" [1,2,3]\n"
        "  pnp ua call  opc.tcp://127.0.0.1:4840 \"nsu=urn:pnp:demo;s=Demo\" "
        "\"nsu=urn:pnp:demo;s=Demo.Add\" 2 3");

    ServeOptions serveOpts;
    CLI::App* serve = ua->add_subcommand(
        "serve", "run an OPC UA server: namespace 0 + demo namespace urn:pnp:demo");
    serve->add_option("--port", serveOpts.port, "TCP port (0: any free port)")
        ->capture_default_str();
    serve->add_option("--host", serveOpts.host, "address to listen on")->capture_default_str();
    serve->add_option("--user", serveOpts.users, "accept user NAME:PASSWORD (repeatable)");
    serve->add_flag("--no-anonymous", serveOpts.noAnonymous, "refuse anonymous sessions");
    serve->add_option("--nodeset", serveOpts.nodesets,
                      "load a NodeSet2 XML file and the models it requires (repeatable)");
    serve->add_option("--instance", serveOpts.instances,
                      "TYPE=NAME: instantiate ObjectType/VariableType TYPE (e.g. "
                      "\"nsu=http://opcfoundation.org/UA/Robotics/;i=1002\") as NAME below "
                      "Objects, node id ns=1;s=NAME (repeatable)");
    addDiscoveryOptions(serve, serveOpts.discovery, false);
    serve->footer(
        "Prints `listening on opc.tcp://HOST:PORT` once ready; stops on SIGINT/SIGTERM.\n"
        "Registers with an LDS-ME (found by mDNS, or --lds URL) unless --no-register; "
        "see docs/discovery.md.");

    ClientOptions epOpts;
    CLI::App* endpoints =
        ua->add_subcommand("endpoints", "list the server's endpoints (GetEndpoints)");
    addClientOptions(endpoints, epOpts);

    ClientOptions brOpts;
    BrowseOptions browseOpts;
    CLI::App* browse = ua->add_subcommand("browse", "list the hierarchical references of a node");
    addClientOptions(browse, brOpts);
    browse->add_option("NODE", browseOpts.node, std::string("start ") + kNodeHelp)
        ->capture_default_str();
    browse->add_option("--depth", browseOpts.depth, "levels to descend")
        ->capture_default_str()
        ->check(CLI::Range(1, 64));

    ClientOptions rdOpts;
    ReadOptions readOpts;
    CLI::App* read = ua->add_subcommand("read", "read an attribute (default Value) of nodes");
    addClientOptions(read, rdOpts);
    read->add_option("NODE", readOpts.nodes, kNodeHelp)->required();
    read->add_option("--attribute", readOpts.attribute,
                     "attribute name (Value, DataType, BrowseName, ...) or id")
        ->capture_default_str();

    ClientOptions wrOpts;
    WriteOptions writeOpts;
    CLI::App* write = ua->add_subcommand("write", "write the Value of a variable");
    addClientOptions(write, wrOpts);
    write->add_option("NODE", writeOpts.node, kNodeHelp)->required();
    write
        ->add_option("VALUE", writeOpts.value,
                     "the value as text; arrays as JSON arrays [1,2,3] (see apps/pnp/README.md)")
        ->required();
    write->add_option("--type", writeOpts.type,
                      "built-in type, e.g. Int32, Double[], LocalizedText (default: the node's "
                      "DataType and ValueRank)");

    ClientOptions clOpts;
    CallOptions callOpts;
    CLI::App* call = ua->add_subcommand("call", "call a method");
    addClientOptions(call, clOpts);
    call->add_option("OBJECT", callOpts.object, "the object (or type) owning the method")
        ->required();
    call->add_option("METHOD", callOpts.method, "the method")->required();
    call->add_option("ARG", callOpts.args,
                     "input arguments as text, typed by the method's InputArguments (use -- "
                     "before arguments that start with '-' and are not numbers)");
    call->add_option("--types", callOpts.types,
                     "comma-separated argument types, overriding InputArguments (Int32,Int32)");

    ClientOptions moOpts;
    MonitorOptions monitorOpts;
    CLI::App* monitor = ua->add_subcommand("monitor", "subscribe to data changes and print them");
    addClientOptions(monitor, moOpts);
    monitor->add_option("NODE", monitorOpts.nodes, kNodeHelp)->required();
    monitor->add_option("--interval", monitorOpts.interval, "publishing/sampling interval, ms")
        ->capture_default_str();
    monitor->add_option("--count", monitorOpts.count, "stop after N notifications (0: never)");
    monitor->add_option("--duration", monitorOpts.durationMs, "stop after MS ms (0: never)");
    monitor->footer("Runs until Ctrl-C, --count or --duration.");

    ClientOptions evOpts;
    EventsOptions eventsOpts;
    CLI::App* events = ua->add_subcommand("events", "subscribe to events and print them");
    addClientOptions(events, evOpts);
    events->add_option("NODE", eventsOpts.node, "event notifier (default: the Server object)")
        ->capture_default_str();
    events
        ->add_option("--select", eventsOpts.select,
                     "comma-separated fields (browse paths like 2:CustomField or A/B)")
        ->capture_default_str();
    events->add_option("--interval", eventsOpts.interval, "publishing interval, ms")
        ->capture_default_str();
    events->add_option("--count", eventsOpts.count, "stop after N events (0: never)");
    events->add_option("--duration", eventsOpts.durationMs, "stop after MS ms (0: never)");
    events->footer("Runs until Ctrl-C, --count or --duration.");

    const auto runBench = addBenchCommands(app);
    const auto runSim = addSimCommands(app);
    const auto runDevice = addDeviceCommands(app);
    const auto runRobot = addRobotCommands(app);
    const auto runComponent = addComponentCommands(app);
    const auto runPickPlace = addPickPlaceCommand(app);
    const auto runCell = addCellCommands(app);
    const auto runMes = addMesCommands(app);
    const auto runPki = addPkiCommands(app);
    const auto runUser = addUserCommands(app);
    const auto runDashboard = addDashboardCommand(app);

    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        int rc = app.exit(e);  // help / version to stdout (0), errors to stderr
        return rc == 0 ? kExitOk : kExitUsage;
    }

    const bool json = (*discover && discoverOpts.json) || (*endpoints && epOpts.json) ||
                      (*browse && brOpts.json) || (*read && rdOpts.json) ||
                      (*write && wrOpts.json) || (*call && clOpts.json) ||
                      (*monitor && moOpts.json) || (*events && evOpts.json);
    try {
        if (const int rc = runBench(); rc >= 0) return rc;
        if (const int rc = runSim(); rc >= 0) return rc;
        if (const int rc = runDevice(); rc >= 0) return rc;
        if (const int rc = runRobot(); rc >= 0) return rc;
        if (const int rc = runComponent(); rc >= 0) return rc;
        if (const int rc = runPickPlace(); rc >= 0) return rc;
        if (const int rc = runCell(); rc >= 0) return rc;
        if (const int rc = runMes(); rc >= 0) return rc;
        if (const int rc = runPki(); rc >= 0) return rc;
        if (const int rc = runUser(); rc >= 0) return rc;
        if (const int rc = runDashboard(); rc >= 0) return rc;
        if (*serve) return runServe(serveOpts);
        if (*demoSkills) return runServe(skillsOpts);
        if (*skillsCmd) return runSkills(skillsListOpts);
        if (*skillRun) return runSkillRun(skillRunOpts);
        if (*lds) return runLds(ldsPort, ldsHost, ldsOpts);
        if (*discover) return runDiscover(discoverOpts);
        if (*endpoints) return runEndpoints(epOpts);
        if (*browse) return runBrowse(brOpts, browseOpts);
        if (*read) return runRead(rdOpts, readOpts);
        if (*write) return runWrite(wrOpts, writeOpts);
        if (*call) return runCall(clOpts, callOpts);
        if (*monitor) return runMonitor(moOpts, monitorOpts);
        if (*events) return runEvents(evOpts, eventsOpts);
    } catch (const UsageError& e) {
        std::cerr << "error: " << e.what() << "\n";
        return kExitUsage;
    } catch (const ValueError& e) {
        std::cerr << "error: " << e.what() << "\n";
        return kExitUsage;
    } catch (const pnp::ua::client::Error& e) {
        return uaError(e, json);
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        return kExitUaError;
    }
    return kExitUsage;
}
