// STUB: a one-line report.md, so that the runner builds before the real module lands.
#include "bench/report/report.hpp"

#include <fstream>
#include <stdexcept>

namespace pnp::bench::report {

std::filesystem::path writeReport(const std::filesystem::path& dir, const Options&) {
    if (!std::filesystem::exists(dir / "summary.json"))
        throw std::runtime_error("no summary.json in " + dir.string());
    const auto path = dir / "report.md";
    std::ofstream out(path);
    out << "# Middleware evaluation (stub report: see summary.json)\n";
    if (!out) throw std::runtime_error("cannot write " + path.string());
    return path;
}

}  // namespace pnp::bench::report
