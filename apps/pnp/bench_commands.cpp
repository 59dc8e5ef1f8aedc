// `pnp bench middleware` (docs/middleware_bench.md): the middleware evaluation of thesis
// chapter 4.5 — runs the adapters through the test matrix (src/bench/runner), then writes the
// report (src/bench/report).
#include <CLI/CLI.hpp>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "bench/report/report.hpp"
#include "bench/runner/process.hpp"
#include "bench/runner/runner.hpp"
#include "output.hpp"

namespace pnp::cli {

namespace {

namespace runner = pnp::bench::runner;

struct BenchMiddleware {
    runner::Options options;
    std::string sizes;
    bool json = false;
    bool noChain = false;
    bool noOverhead = false;
    bool noPlots = false;
};

// Exit code of a run in which some measurement failed (the results directory says which).
constexpr int kExitSomeFailed = 3;
constexpr int kExitInterrupted = 130;

int runBenchMiddleware(BenchMiddleware& b) {
    runner::Options& o = b.options;
    o.chain = !b.noChain;
    o.overhead = !b.noOverhead;
    if (!b.sizes.empty()) {
        std::stringstream ss(b.sizes);
        std::string item;
        while (std::getline(ss, item, ',')) {
            if (item.empty()) continue;
            if (item.find_first_not_of("0123456789") != std::string::npos || item.size() > 9)
                throw UsageError("--sizes: not a size in bytes: " + item);
            const auto v = std::stoul(item);
            if (v > (64u << 20)) throw UsageError("--sizes: " + item + " is above 64 MiB");
            o.sizes.push_back(v);
        }
        if (o.sizes.empty()) throw UsageError("--sizes: no sizes");
    }
    runner::installStopHandlers();
    std::filesystem::path summaryPath;
    try {
        summaryPath = runner::run(o);
    } catch (const runner::Interrupted& e) {
        std::cerr << "pnp bench middleware: " << e.what()
                  << "; everything it started is stopped and removed; partial results in "
                  << o.out.string() << "\n";
        return kExitInterrupted;
    } catch (const std::invalid_argument& e) {
        throw UsageError(e.what());
    }
    std::ifstream in(summaryPath);
    const auto summary = nlohmann::json::parse(in);
    int failed = 0, ok = 0;
    for (const char* part : {"runs", "chain", "overhead"})
        for (const auto& r : summary.value(part, nlohmann::json::array())) {
            const std::string status = r.value("status", "");
            if (status == "failed") ++failed;
            if (status == "ok") ++ok;
        }
    int rc = failed > 0 ? kExitSomeFailed : kExitOk;
    try {
        bench::report::Options ro;
        ro.plots = !b.noPlots;
        const auto report = bench::report::writeReport(o.out, ro);
        std::cerr << "report: " << report.string() << "\n";
    } catch (const std::exception& e) {
        std::cerr << "pnp bench middleware: no report: " << e.what() << "\n";
        rc = kExitUaError;
    }
    std::cerr << ok << " measurements ok, " << failed << " failed; results in " << o.out.string()
              << " (" << summary.value("duration_s", 0.0) << " s)\n";
    if (b.json) std::cout << summary.dump(2) << std::endl;
    return rc;
}

}  // namespace

// Adds `pnp bench ...`; the returned function runs the parsed subcommand (-1: none parsed).
std::function<int()> addBenchCommands(CLI::App& app) {
    auto b = std::make_shared<BenchMiddleware>();
    CLI::App* bench = app.add_subcommand("bench", "benchmarks (docs/middleware_bench.md)");
    bench->require_subcommand(1);
    CLI::App* mw = bench->add_subcommand(
        "middleware",
        "the middleware evaluation (thesis 4.5): RTT (ACK, Echo, Resting, Chain), throughput, "
        "CPU, memory and package overhead of OPC UA, MQTT, DDS, ROS, raw TCP/UDP under idle, "
        "CPU and network load");
    runner::Options& o = b->options;
    mw->add_option("--out", o.out, "results directory")->capture_default_str();
    mw->add_flag("--quick", o.quick,
                 "a short run (< 2 min): 50 reps, idle only, short resting, a tiny chain, no "
                 "overhead capture");
    mw->add_option("--only", o.only, "only these adapters (tcp,udp,opcua,mqtt,dds,ros)")
        ->delimiter(',');
    mw->add_option("--loads", o.loads, "load scenarios (idle,cpu,net; default all, --quick idle)")
        ->delimiter(',');
    mw->add_option("--modes", o.modes, "modes (ack,echo,resting; default all)")->delimiter(',');
    mw->add_option("--reps", o.reps,
                   "timed requests per payload size (default 5000 idle / 500 under load; "
                   "--quick 50); given: also under load")
        ->check(CLI::Range(1, 1000000));
    mw->add_option("--reps-under-load", o.repsUnderLoad, "timed requests per size under load")
        ->check(CLI::Range(1, 1000000));
    mw->add_option("--warmup", o.warmup, "untimed requests before each size (default 100)")
        ->check(CLI::Range(0, 100000));
    mw->add_option("--sizes", b->sizes, "payload sizes, comma-separated (default 2,4,...,32768)");
    mw->add_option("--placement", o.placement,
                   "different: client on CPU 0, server (+ broker/master) on CPU 1; same: all on "
                   "CPU 0; none: no pinning")
        ->capture_default_str()
        ->check(CLI::IsMember({"different", "same", "none"}));
    mw->add_option("--resting-seconds", o.restingSeconds, "resting: duration (default 15)")
        ->check(CLI::Range(0.1, 3600.0));
    mw->add_option("--net-rate", o.netRate, "network load: tbf rate of both veth ends")
        ->capture_default_str();
    mw->add_flag("--no-chain", b->noChain, "skip the chain test");
    mw->add_flag("--no-overhead", b->noOverhead, "skip the package-overhead capture");
    mw->add_flag("--no-plots", b->noPlots, "report without PNG plots");
    mw->add_option("--adapters", o.adapterDir,
                   "directory of the pnp-mw-* executables (default: this build's mw/)");
    mw->add_flag("--json", b->json, "print summary.json on stdout at the end");
    mw->footer(
        "Progress on stderr. Writes OUT/summary.json, OUT/samples/<load>/*.csv, OUT/logs/, "
        "OUT/report.md and OUT/plots/*.png. Exit codes: 0 all ok, 1 no report, 2 usage, 3 "
        "some measurement failed (see summary.json), 130 interrupted (everything started is "
        "stopped and removed).\n"
        "Examples: pnp bench middleware --quick --out /tmp/mw\n"
        "          pnp bench middleware --only tcp,mqtt --loads idle,net --no-chain");
    // Re-renders report.md and the plots from a results directory's summary.json and CSVs
    // (e.g. after an interrupted run, or with a newer report layout).
    auto reportDir = std::make_shared<std::string>();
    auto reportNoPlots = std::make_shared<bool>(false);
    CLI::App* rep = bench->add_subcommand(
        "report",
        "writes report.md (and plots) again from a `pnp bench middleware` results directory");
    rep->add_option("dir", *reportDir, "results directory (with summary.json)")->required();
    rep->add_flag("--no-plots", *reportNoPlots, "report without PNG plots");
    return [b, mw, rep, reportDir, reportNoPlots]() -> int {
        if (*rep) {
            bench::report::Options ro;
            ro.plots = !*reportNoPlots;
            try {
                std::cerr << "report: " << bench::report::writeReport(*reportDir, ro).string()
                          << "\n";
                return kExitOk;
            } catch (const std::exception& e) {
                std::cerr << "pnp bench report: " << e.what() << "\n";
                return kExitUaError;
            }
        }
        if (!*mw) return -1;
        return runBenchMiddleware(*b);
    };
}

}  // namespace pnp::cli
