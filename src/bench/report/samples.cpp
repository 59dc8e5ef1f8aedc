#include "bench/report/samples.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <stdexcept>
#include <string_view>

#include "bench/driver/driver.hpp"

namespace pnp::bench::report {

namespace {

constexpr std::size_t kMaxProblems = 5;
constexpr std::size_t kMaxLine = 4096;
// Bounds of a plausible row: payloads up to 1 GiB, RTTs up to one hour.
constexpr std::uint64_t kMaxPayload = 1ull << 30;
constexpr std::int64_t kMaxRttNs = 3'600'000'000'000;

template <typename T>
bool parseInt(std::string_view s, T& out) {
    if (s.empty()) return false;
    auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
    return ec == std::errc() && p == s.data() + s.size();
}

std::vector<std::string_view> split(std::string_view line) {
    std::vector<std::string_view> f;
    std::size_t start = 0;
    for (;;) {
        const auto comma = line.find(',', start);
        f.push_back(line.substr(start, comma == std::string_view::npos ? comma : comma - start));
        if (comma == std::string_view::npos) break;
        start = comma + 1;
    }
    return f;
}

}  // namespace

Box boxOf(std::vector<std::int64_t> ns) {
    Box b;
    const driver::Summary s = driver::summarize(ns);  // same quantiles as the driver prints
    b.n = s.n;
    if (ns.empty()) return b;
    b.min = s.min;
    b.q1 = s.q1;
    b.median = s.median;
    b.q3 = s.q3;
    b.mean = s.mean;
    b.p99 = s.p99;
    b.max = s.max;
    std::sort(ns.begin(), ns.end());
    const double iqr = b.q3 - b.q1;
    const double lo = b.q1 - 1.5 * iqr, hi = b.q3 + 1.5 * iqr;
    b.whiskerLo = b.q1;
    b.whiskerHi = b.q3;
    for (auto v : ns) {
        const double us = static_cast<double>(v) / 1e3;
        if (us < lo || us > hi) {
            ++b.outliers;
            continue;
        }
        b.whiskerLo = std::min(b.whiskerLo, us);
        b.whiskerHi = std::max(b.whiskerHi, us);
    }
    return b;
}

CsvSamples readCsv(const std::filesystem::path& file, const std::string& adapter,
                   const std::string& variant, const std::string& mode) {
    std::ifstream in(file, std::ios::binary);
    if (!in) throw std::runtime_error(file.string() + ": cannot open");
    CsvSamples out;
    auto problem = [&](std::size_t lineNo, const std::string& why) {
        ++out.skipped;
        if (out.problems.size() < kMaxProblems)
            out.problems.push_back("line " + std::to_string(lineNo) + ": " + why);
    };
    std::string line;
    std::size_t lineNo = 0;
    bool header = false;
    while (std::getline(in, line)) {
        ++lineNo;
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (!header) {
            if (line.rfind("adapter,variant,mode,payload,seq,rtt_ns", 0) != 0)
                throw std::runtime_error(file.string() +
                                         ": no driver CSV header "
                                         "(adapter,variant,mode,payload,seq,rtt_ns) on line 1");
            header = true;
            continue;
        }
        if (line.empty()) continue;
        if (line.size() > kMaxLine) {
            problem(lineNo, "longer than " + std::to_string(kMaxLine) + " characters");
            continue;
        }
        const auto f = split(line);
        if (f.size() != 6) {
            problem(lineNo, std::to_string(f.size()) + " fields instead of 6");
            continue;
        }
        if ((!adapter.empty() && f[0] != adapter) || (!variant.empty() && f[1] != variant) ||
            (!mode.empty() && f[2] != mode)) {
            problem(lineNo, "row of " + std::string(f[0]) + "/" + std::string(f[1]) + "/" +
                                std::string(f[2]) + ", expected " + adapter + "/" + variant + "/" +
                                mode);
            continue;
        }
        std::uint64_t payload = 0, seq = 0;
        std::int64_t rtt = 0;
        if (!parseInt(f[3], payload) || payload > kMaxPayload) {
            problem(lineNo, "payload \"" + std::string(f[3]) + "\" is not a size");
            continue;
        }
        if (!parseInt(f[4], seq)) {
            problem(lineNo, "seq \"" + std::string(f[4]) + "\" is not a number");
            continue;
        }
        if (!parseInt(f[5], rtt) || rtt < 0 || rtt > kMaxRttNs) {
            problem(lineNo, "rtt_ns \"" + std::string(f[5]) + "\" is not a duration in ns");
            continue;
        }
        out.byPayload[payload].push_back(rtt);
        ++out.rows;
    }
    if (!header) throw std::runtime_error(file.string() + ": empty (no CSV header)");
    return out;
}

}  // namespace pnp::bench::report
