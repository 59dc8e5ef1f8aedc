// `pnp bench middleware` (thesis chapter 4.5; docs/middleware_bench.md): runs the adapter
// executables <build>/mw/pnp-mw-* through the test matrix (load scenario x adapter x
// variant x mode), the chain test and the package-overhead capture, and writes the results
// directory (summary.json, samples/**.csv, logs/) that the report module reads.
#pragma once

#include <cstddef>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace pnp::bench::runner {

// The adapters in the order of the report.
const std::vector<std::string>& knownAdapters();

struct Options {
    std::filesystem::path out = "middleware-report";
    std::filesystem::path adapterDir;  // empty: the build's mw directory (defaultAdapterDir())
    bool quick = false;
    std::vector<std::string> only;        // adapters; empty: all
    std::vector<std::string> loads;       // idle, cpu, net; empty: all (quick: idle)
    std::vector<std::string> modes;       // ack, echo, resting; empty: all
    int reps = 0;                         // 0: 5000 (quick 50); also under load when given
    int repsUnderLoad = 0;                // 0: 500 (quick 50), or --reps when given
    int warmup = -1;                      // -1: 100 (quick 5)
    std::vector<std::size_t> sizes;       // empty: 2, 4, ..., 32768
    std::string placement = "different";  // different | same | none
    bool chain = true;
    bool overhead = true;
    double restingSeconds = 0;   // 0: 15 (quick 2)
    double restingMaxPause = 0;  // 0: 3 (quick 0.3)
    std::string netRate = "200mbit";
    std::function<void(const std::string&)> progress;  // one line each; default: stderr
};

std::filesystem::path defaultAdapterDir();

// Runs everything and writes OUT/summary.json (returned), OUT/samples, OUT/logs. Throws
// std::invalid_argument for bad options, Interrupted (after cleaning up and writing what was
// measured) when SIGINT / SIGTERM arrived (installStopHandlers()), std::runtime_error when
// the results directory cannot be written.
std::filesystem::path run(const Options& options);

// SIGINT / SIGTERM set stopRequested() (process.hpp): the run stops at the next wait and
// removes everything it created.
void installStopHandlers();

}  // namespace pnp::bench::runner
