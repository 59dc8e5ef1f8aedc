// Box plots drawn by gnuplot (a child process with a script file and bounded time). gnuplot
// gets the few numbers per box (candlesticks), never the samples.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "bench/report/samples.hpp"

namespace pnp::bench::report {

// Boxes grouped along x (e.g. payload sizes); within a group one box per series (e.g. load),
// each series one colour with a legend entry.
struct BoxPlot {
    std::string name;  // file stem: plots/<name>.png
    std::string title;
    std::string xlabel;
    std::string ylabel;
    std::vector<std::string> groups;
    std::vector<std::string> series;
    // boxes[series][group]; empty optional: no data, the slot stays empty.
    std::vector<std::vector<std::optional<Box>>> boxes;
};

// The gnuplot executable on PATH, or nullopt.
std::optional<std::filesystem::path> findGnuplot();

// Writes plotsDir/<name>.dat and .gp and runs gnuplot on them (stderr appended to log, at most
// timeoutSeconds). Returns an empty string on success, otherwise why the PNG is missing.
std::string renderBoxPlot(const std::filesystem::path& gnuplot,
                          const std::filesystem::path& plotsDir, const BoxPlot& plot,
                          const std::filesystem::path& log, int timeoutSeconds = 60);

}  // namespace pnp::bench::report
