// `pnp cell run` (the main job: the simulated cell end to end, with a report) and `pnp cell
// up` (the same cell, left running until Ctrl-C). The runner is src/cell (README.md there).
#include <signal.h>
#include <time.h>

#include <CLI/CLI.hpp>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <memory>
#include <stop_token>
#include <thread>

#include "cell/cell.hpp"
#include "commands.hpp"
#include "output.hpp"

namespace pnp::cli {

namespace {

struct CellCliOptions {
    cell::CellOptions cell;
    std::string pnp, cellFile, logDir, reportFile = "cell-report.json";
    std::vector<std::string> kbFiles, extraKbFiles;
    int ldsPollMs = 5;
    int startTimeoutMs = 30000;
    int processTimeoutMs = 150000;
    SecurityOptions security;
};

// Runs `body` with a stop token requested on SIGINT / SIGTERM (blocked in every thread; a
// thread of ours waits for them). A second signal is not needed: the runner stops its
// children within their grace time.
int withStopSignals(const std::function<int(std::stop_token)>& body) {
    StopOnSignal stop([](int sig) {
        std::cerr << "pnp cell: " << (sig == SIGINT ? "SIGINT" : "SIGTERM")
                  << ", stopping everything it started" << std::endl;
    });
    return body(stop.token());
}

int runCellCommand(CellCliOptions& o, bool up) {
    auto& c = o.cell;
    c.pnp = o.pnp;
    c.cellFile = o.cellFile;
    c.logDir = o.logDir;
    c.reportFile = o.reportFile;
    for (const auto& f : o.kbFiles) c.kbFiles.emplace_back(f);
    for (const auto& f : o.extraKbFiles) c.extraKbFiles.emplace_back(f);
    c.ldsPoll = std::chrono::milliseconds(o.ldsPollMs);
    c.startTimeout = std::chrono::milliseconds(o.startTimeoutMs);
    c.processTimeout = std::chrono::milliseconds(o.processTimeoutMs);
    // The cell provisions its security: every child gets its certificate from one folder and
    // trusts the others through it (docs/security.md); the runner's own clients too.
    const std::filesystem::path pki = std::filesystem::absolute(pkiFolder(o.security));
    ::setenv("PNP_PKI", pki.c_str(), 1);
    secureClients(o.security);
    return withStopSignals(
        [&](std::stop_token stop) { return up ? cell::upCell(c, stop) : cell::runCell(c, stop); });
}

void addCommonOptions(CLI::App* cmd, CellCliOptions& o) {
    cmd->add_option("--cell", o.cellFile,
                    "cell file for `pnp sim` (default: models/cells/thesis.yaml)");
    cmd->add_option("--kb-file", o.kbFiles,
                    "Turtle file for the MES and Pick-and-Place (repeatable; default: every "
                    "models/kb/*.ttl)");
    cmd->add_option("--add-kb-file", o.extraKbFiles,
                    "a Turtle file loaded after those (repeatable): e.g. a process of your own "
                    "next to the default files");
    cmd->add_option("--kb", o.cell.kb,
                    "their knowledge base: a SPARQL 1.1 endpoint URL (default: embedded)");
    cmd->add_option("--log-dir", o.logDir, "every child's log here (default /tmp/pnp-cell-<pid>)");
    cmd->add_flag("--netns", o.cell.netns,
                  "each device in a network namespace of its own, the cell bus in another "
                  "(root; mDNS between them)");
    cmd->add_option("--lds-poll", o.ldsPollMs, "the runner's detector polls the LDS-ME every MS ms")
        ->capture_default_str()
        ->check(CLI::Range(1, 10000));
    cmd->add_option("--start-timeout", o.startTimeoutMs,
                    "each process must be up and detected within MS ms")
        ->capture_default_str()
        ->check(CLI::Range(100, 600000));
    cmd->add_option("--pnp", o.pnp, "the pnp executable of the children (default: this one)");
    cmd->add_option("--mes-arg", o.cell.mesArgs, "an extra argument of `pnp mes` (repeatable)")
        ->allow_extra_args(false);
    cmd->add_option("--pick-place-arg", o.cell.pickPlaceArgs,
                    "an extra argument of `pnp component pick-place` (repeatable)")
        ->allow_extra_args(false);
    cmd->add_flag("--quiet", o.cell.quiet, "no progress lines");
    cmd->add_flag("!--no-dashboard", o.cell.dashboard, "no live web dashboard (`pnp dashboard`)");
    cmd->add_option("--dashboard-port", o.cell.dashboardPort,
                    "the dashboard's HTTP port (a free one when it is taken)")
        ->capture_default_str();
    cmd->add_option("--pki", o.security.pki,
                    "the PKI folder of every process of the cell (default: the machine's, "
                    "$PNP_PKI or ~/.local/share/pnp/pki): they trust each other through it");
}

}  // namespace

std::function<int()> addCellCommands(CLI::App& app) {
    auto runOpts = std::make_shared<CellCliOptions>();
    auto upOpts = std::make_shared<CellCliOptions>();
    CLI::App* cell = app.add_subcommand(
        "cell", "the simulated Plug & Produce cell end to end (src/cell/README.md)");
    cell->require_subcommand(1);

    CLI::App* run = cell->add_subcommand(
        "run",
        "the main job: start the cell bus (LDS-ME, MES), the simulator and every device one at "
        "a time (plug-in -> skills detected), run the process through the MES, swap the tool "
        "in a dock as an operator would, run it again, report");
    addCommonOptions(run, *runOpts);
    run->add_option("--process", runOpts->cell.processIri, "the process's IRI in the KB")
        ->capture_default_str();
    run->add_option("--report", runOpts->reportFile, "the JSON report")->capture_default_str();
    run->add_option("--process-timeout", runOpts->processTimeoutMs,
                    "one run of the process must end within MS ms")
        ->capture_default_str()
        ->check(CLI::Range(1000, 3600000));
    run->add_flag("!--no-swap", runOpts->cell.swap, "one round only, no operator's swap");
    run->add_option("--swap-dock", runOpts->cell.swapDock, "the dock whose tool is swapped")
        ->capture_default_str();
    run->add_option("--swap-tool", runOpts->cell.swapTool, "the tool put in its place")
        ->capture_default_str();
    run->add_option("--tolerance", runOpts->cell.toleranceMm,
                    "a placed object further than this (mm) from its target fails the run")
        ->capture_default_str()
        ->check(CLI::Range(0.0, 1000.0));
    run->footer(
        "Exit codes: 0 every step completed and every placed object within the tolerance; 1 "
        "a step failed, an object is off or a process did not come up (the report says "
        "which); 2 usage; 130 stopped by SIGINT / SIGTERM.\n"
        "Every child's log is in the log directory, named in the report.");

    CLI::App* up = cell->add_subcommand(
        "up",
        "start the same cell and leave it running: prints every server's URL; Ctrl-C stops "
        "everything it started");
    addCommonOptions(up, *upOpts);
    up->footer(
        "Once everything is up it prints ONE JSON line on stdout (then the URLs as text):\n"
        "  {\"pid\": runner, \"logDir\": DIR, \"lds\": URL, \"mes\": URL, \"world\": URL (the "
        "simulator's ground truth), \"sim\": {the simulator's own line}, \"problems\": [...],\n"
        "   \"children\": [{\"name\": \"pick-place\", \"pid\": N, \"url\": URL, \"log\": FILE, "
        "\"argv\": [...]}, ...]}\n"
        "in start order (lds, mes, sim, ur, kelvin-adc, robotiq, ecbpi, wsg, toolchanger, "
        "pick-place); a tool adapter's url (\"servedWhilePowered\": true) is served only while "
        "its tool is locked on the flange. A child may be killed by its PID and started again "
        "with its argv (the same ports for the tools' adapters; a server with --port 0 gets a "
        "new one and registers with the LDS-ME again): a child that exits is a warning on "
        "stderr, the rest keeps running. A process of your own: --add-kb-file "
        "F.ttl (next to models/kb/*.ttl), then `pnp mes run IRI --mes URL`.\n"
        "Exit codes: 0 stopped by SIGINT / SIGTERM once up; 1 the cell did not come up; 130 "
        "stopped while starting.");

    return [run, up, runOpts, upOpts]() -> int {
        if (*run) return runCellCommand(*runOpts, false);
        if (*up) return runCellCommand(*upOpts, true);
        return -1;
    };
}

}  // namespace pnp::cli
