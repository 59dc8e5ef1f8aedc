// Per-request CSVs of the driver (adapter,variant,mode,payload,seq,rtt_ns) and the box
// statistics computed from them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace pnp::bench::report {

// One box of a box plot, in µs. Quartiles: type-7 quantiles (as the driver's summaries);
// whiskers: the furthest samples within 1.5 IQR of the box (Tukey).
struct Box {
    std::size_t n = 0;
    double min = 0, whiskerLo = 0, q1 = 0, median = 0, q3 = 0, whiskerHi = 0, max = 0;
    double mean = 0, p99 = 0;
    std::size_t outliers = 0;  // samples beyond the whiskers
    bool fromSummary = false;  // no CSV: numbers of summary.json, whiskers = min / max
};

Box boxOf(std::vector<std::int64_t> samplesNs);

// What a CSV held: samples per payload size, and the rows that could not be used.
struct CsvSamples {
    std::map<std::size_t, std::vector<std::int64_t>> byPayload;  // rtt in ns
    std::size_t rows = 0;                                        // data rows read
    std::size_t skipped = 0;                                     // malformed / foreign rows
    std::vector<std::string> problems;                           // first few, "line N: why"
};

// Reads a driver CSV. Rows that are malformed, or whose adapter / variant / mode are not the
// expected ones (an empty expectation matches all), are skipped and noted. Throws
// std::runtime_error when the file cannot be read or has no header.
CsvSamples readCsv(const std::filesystem::path& file, const std::string& adapter,
                   const std::string& variant, const std::string& mode);

}  // namespace pnp::bench::report
