// The middleware evaluation's report (thesis chapter 4.4–4.5): turns the results directory of
// `pnp bench middleware --out DIR` (docs: /work/notes/mw_results.md contract, summary.json +
// per-request CSVs) into box plots (gnuplot, PNG) and a markdown report with the Table 4.2 /
// 4.3 equivalents next to the thesis's published values.
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
