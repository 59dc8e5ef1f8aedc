// STUB of the report module (written by another helper): the API the runner calls.
#pragma once

#include <filesystem>

namespace pnp::bench::report {

struct Options {
    bool plots = true;
};

// Reads DIR/summary.json and DIR/samples/**, writes DIR/report.md and DIR/plots/*.png.
// Returns the report's path; throws std::runtime_error with a reason.
std::filesystem::path writeReport(const std::filesystem::path& dir, const Options& options = {});

}  // namespace pnp::bench::report
