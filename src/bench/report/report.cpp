#include "bench/report/report.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "bench/report/plot.hpp"
#include "bench/report/samples.hpp"
#include "bench/report/thesis.hpp"

namespace pnp::bench::report {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kTcpTarget = 1.2;  // the target: OPC UA echo ≤ 1.2 × raw TCP

// ---- summary.json access: missing or null fields fall back, wrong types are errors --------

std::string str(const json& j, const char* key, const std::string& fallback = "") {
    if (!j.is_object()) return fallback;
    const auto it = j.find(key);
    if (it == j.end() || it->is_null()) return fallback;
    if (it->is_string()) return it->get<std::string>();
    if (it->is_number() || it->is_boolean()) return it->dump();
    throw std::runtime_error(std::string("field \"") + key + "\" is not a string");
}

double num(const json& j, const char* key, double fallback = kNaN) {
    if (!j.is_object()) return fallback;
    const auto it = j.find(key);
    if (it == j.end() || it->is_null()) return fallback;
    if (it->is_number()) return it->get<double>();
    throw std::runtime_error(std::string("field \"") + key + "\" is not a number");
}

const json& arr(const json& j, const char* key) {
    static const json empty = json::array();
    if (!j.is_object()) return empty;
    const auto it = j.find(key);
    if (it == j.end() || it->is_null()) return empty;
    if (!it->is_array())
        throw std::runtime_error(std::string("field \"") + key + "\" is not an array");
    return *it;
}

const json& obj(const json& j, const char* key) {
    static const json empty = json::object();
    if (!j.is_object()) return empty;
    const auto it = j.find(key);
    if (it == j.end() || it->is_null()) return empty;
    if (!it->is_object())
        throw std::runtime_error(std::string("field \"") + key + "\" is not an object");
    return *it;
}

// ---- formatting ---------------------------------------------------------------------------

std::string fmt(const char* f, double v) {
    char buf[64];
    std::snprintf(buf, sizeof buf, f, v);
    return buf;
}

// µs with the precision that matters at that magnitude.
std::string us(double v) {
    if (std::isnan(v)) return "–";
    const double a = std::fabs(v);
    return fmt(a < 10 ? "%.2f" : a < 100 ? "%.1f" : "%.0f", v);
}

std::string ratio(double v) { return std::isnan(v) ? "–" : fmt("%.2f", v) + "×"; }

std::string plain(double v, const char* f = "%.1f") { return std::isnan(v) ? "–" : fmt(f, v); }

std::string mib(double kib) { return std::isnan(kib) ? "–" : fmt("%.1f", kib / 1024.0); }

// Markdown table cells: no pipes or line breaks from the data.
std::string cell(std::string s) {
    for (auto& c : s)
        if (c == '\n' || c == '\r') c = ' ';
    std::string out;
    for (char c : s) {
        if (c == '|')
            out += "\\|";
        else
            out += c;
    }
    return out.empty() ? "–" : out;
}

std::string nowUtc() {
    const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    std::tm tm{};
    gmtime_r(&t, &tm);
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
    return buf;
}

std::string duration(double s) {
    if (std::isnan(s)) return "–";
    const long total = std::lround(s);
    std::string out = fmt("%.1f s", s);
    if (total >= 60)
        out += " (" + std::to_string(total / 3600) + " h " + std::to_string(total / 60 % 60) +
               " min " + std::to_string(total % 60) + " s)";
    return out;
}

// ---- names and order ----------------------------------------------------------------------

struct Mw {
    std::string adapter, variant;
    auto operator<=>(const Mw&) const = default;
};

std::string pretty(const std::string& adapter) {
    static const std::map<std::string, std::string> names = {{"opcua", "OPC UA"}, {"mqtt", "MQTT"},
                                                             {"dds", "DDS"},      {"ros", "ROS"},
                                                             {"tcp", "TCP"},      {"udp", "UDP"}};
    const auto it = names.find(adapter);
    return it == names.end() ? adapter : it->second;
}

std::string label(const Mw& m) {
    return m.variant.empty() || m.variant == m.adapter ? pretty(m.adapter)
                                                       : pretty(m.adapter) + " " + m.variant;
}

std::string loadLabel(const std::string& load) {
    if (load == "idle") return "idle";
    if (load == "cpu") return "CPU load";
    if (load == "net") return "network load";
    return load;
}

int rankOf(const std::vector<std::string>& order, const std::string& s) {
    const auto it = std::find(order.begin(), order.end(), s);
    return it == order.end() ? static_cast<int>(order.size())
                             : static_cast<int>(it - order.begin());
}

// ---- what the results directory holds -----------------------------------------------------

struct Run {
    Mw mw;
    std::string mode, load, status, reason, csv;
    std::map<std::size_t, Box> boxes;        // per payload
    std::map<std::size_t, double> msgsPerS;  // from summary.json
    json resources;
};

struct Chain {
    Mw mw;
    json j;
    std::optional<Box> box;
};

struct Data {
    json summary;
    std::vector<std::string> adapterOrder;  // thesis order first
    std::map<std::string, std::vector<std::string>> variantOrder;
    std::vector<Run> runs;  // status ok
    std::vector<std::string> failedRuns;
    std::vector<std::string> problems;  // data problems (CSV rows, files)
    std::vector<Chain> chain;
    std::size_t skippedRows = 0;

    bool mwLess(const Mw& a, const Mw& b) const {
        const int ra = rankOf(adapterOrder, a.adapter), rb = rankOf(adapterOrder, b.adapter);
        if (ra != rb) return ra < rb;
        if (a.adapter != b.adapter) return a.adapter < b.adapter;
        const auto it = variantOrder.find(a.adapter);
        if (it != variantOrder.end()) {
            const int va = rankOf(it->second, a.variant), vb = rankOf(it->second, b.variant);
            if (va != vb) return va < vb;
        }
        return a.variant < b.variant;
    }

    const Run* find(const Mw& m, const std::string& mode, const std::string& load) const {
        for (const auto& r : runs)
            if (r.mw == m && r.mode == mode && r.load == load) return &r;
        return nullptr;
    }

    std::vector<Mw> middlewares(const std::string& mode, const std::string& load = "") const {
        std::set<Mw> s;
        for (const auto& r : runs)
            if (r.mode == mode && (load.empty() || r.load == load) && !r.boxes.empty())
                s.insert(r.mw);
        std::vector<Mw> v(s.begin(), s.end());
        std::sort(v.begin(), v.end(), [this](const Mw& a, const Mw& b) { return mwLess(a, b); });
        return v;
    }

    std::vector<std::string> loads(const std::string& mode) const {
        std::set<std::string> s;
        for (const auto& r : runs)
            if (r.mode == mode && !r.boxes.empty()) s.insert(r.load);
        std::vector<std::string> v(s.begin(), s.end());
        const std::vector<std::string> order = {"idle", "cpu", "net"};
        std::stable_sort(v.begin(), v.end(), [&](const std::string& a, const std::string& b) {
            return rankOf(order, a) < rankOf(order, b);
        });
        return v;
    }

    std::vector<std::size_t> sizes(const std::vector<std::string>& modes) const {
        std::set<std::size_t> s;
        for (const auto& r : runs)
            if (std::find(modes.begin(), modes.end(), r.mode) != modes.end())
                for (const auto& [p, b] : r.boxes) s.insert(p);
        return {s.begin(), s.end()};
    }
};

Box boxFromSummary(const json& s) {
    Box b;
    b.n = static_cast<std::size_t>(std::max(0.0, num(s, "n", 0)));
    b.min = b.whiskerLo = num(s, "min_us", 0);
    b.q1 = num(s, "q1_us", 0);
    b.median = num(s, "median_us", 0);
    b.q3 = num(s, "q3_us", 0);
    b.mean = num(s, "mean_us", 0);
    b.p99 = num(s, "p99_us", 0);
    b.max = b.whiskerHi = num(s, "max_us", 0);
    b.fromSummary = true;
    return b;
}

// A CSV path from summary.json, inside the results directory.
std::optional<fs::path> csvPath(const fs::path& dir, const std::string& rel, std::string& why) {
    if (rel.empty()) {
        why = "no CSV named";
        return std::nullopt;
    }
    const fs::path p(rel);
    if (p.is_absolute() ||
        std::any_of(p.begin(), p.end(), [](const fs::path& c) { return c == ".."; })) {
        why = "CSV path \"" + rel + "\" is not inside the results directory";
        return std::nullopt;
    }
    if (!fs::is_regular_file(dir / p)) {
        why = rel + " not found";
        return std::nullopt;
    }
    return dir / p;
}

std::string runName(const Mw& m, const std::string& mode, const std::string& load) {
    return m.adapter + "/" + m.variant + " " + mode + " " + load;
}

void noteCsv(Data& d, const std::string& what, const std::string& rel, const CsvSamples& s) {
    if (s.skipped == 0) return;
    d.skippedRows += s.skipped;
    std::string line = what + ": " + std::to_string(s.skipped) + " row(s) of " + rel +
                       " skipped (" + std::to_string(s.rows) + " used)";
    for (const auto& p : s.problems) line += "; " + p;
    if (s.skipped > s.problems.size()) line += "; …";
    d.problems.push_back(line);
}

Data load(const fs::path& dir) {
    Data d;
    const fs::path summaryPath = dir / "summary.json";
    if (!fs::exists(dir)) throw std::runtime_error(dir.string() + ": results directory not found");
    if (!fs::is_regular_file(summaryPath))
        throw std::runtime_error(summaryPath.string() + ": not found (no summary.json)");
    {
        std::ifstream in(summaryPath);
        if (!in) throw std::runtime_error(summaryPath.string() + ": cannot open");
        try {
            d.summary = json::parse(in);
        } catch (const json::exception& e) {
            throw std::runtime_error(summaryPath.string() + ": not valid JSON: " + e.what());
        }
    }
    if (!d.summary.is_object())
        throw std::runtime_error(summaryPath.string() + ": not a JSON object");

    try {
        d.adapterOrder = {"opcua", "mqtt", "ros", "dds", "tcp", "udp"};
        for (const auto& a : arr(d.summary, "adapters")) {
            auto& order = d.variantOrder[str(a, "name")];
            for (const auto& v : arr(a, "variants"))
                if (v.is_string()) order.push_back(v.get<std::string>());
        }

        for (const auto& r : arr(d.summary, "runs")) {
            Run run;
            run.mw = {str(r, "adapter", "?"), str(r, "variant", "")};
            run.mode = str(r, "mode", "?");
            run.load = str(r, "load", "idle");
            run.status = str(r, "status", "ok");
            run.reason = str(r, "reason");
            run.csv = str(r, "csv");
            run.resources = obj(r, "resources");
            const std::string name = runName(run.mw, run.mode, run.load);
            if (run.status != "ok") {
                d.failedRuns.push_back(name + " (" + run.status + "): " +
                                       (run.reason.empty() ? "no reason given" : run.reason));
                continue;
            }
            std::map<std::size_t, Box> fallback;
            for (const auto& s : arr(r, "sizes")) {
                const double p = num(s, "payload", -1);
                if (p < 0) continue;
                const auto payload = static_cast<std::size_t>(p);
                fallback[payload] = boxFromSummary(s);
                const double mps = num(s, "msgs_per_s");
                if (!std::isnan(mps)) run.msgsPerS[payload] = mps;
            }
            std::string why;
            if (auto path = csvPath(dir, run.csv, why)) {
                try {
                    auto samples = readCsv(*path, run.mw.adapter, run.mw.variant, run.mode);
                    noteCsv(d, name, run.csv, samples);
                    for (auto& [p, v] : samples.byPayload) run.boxes[p] = boxOf(std::move(v));
                } catch (const std::runtime_error& e) {
                    why = e.what();
                }
            }
            if (run.boxes.empty() && !fallback.empty()) {
                d.problems.push_back(name + ": " + (why.empty() ? "CSV has no rows" : why) +
                                     "; the numbers of summary.json are used (whiskers = min / "
                                     "max)");
                run.boxes = std::move(fallback);
            } else if (run.boxes.empty()) {
                d.problems.push_back(name + ": " + (why.empty() ? "CSV has no rows" : why) +
                                     "; no data for this run");
            }
            d.runs.push_back(std::move(run));
        }

        for (const auto& c : arr(d.summary, "chain")) {
            Chain ch{{str(c, "adapter", "?"), str(c, "variant", "")}, c, std::nullopt};
            if (str(c, "status", "ok") == "ok") {
                const std::string name = ch.mw.adapter + "/" + ch.mw.variant + " chain";
                std::string why;
                if (auto path = csvPath(dir, str(c, "csv"), why)) {
                    try {
                        auto samples = readCsv(*path, ch.mw.adapter, ch.mw.variant, "chain");
                        noteCsv(d, name, str(c, "csv"), samples);
                        std::vector<std::int64_t> all;
                        for (auto& [p, v] : samples.byPayload)
                            all.insert(all.end(), v.begin(), v.end());
                        if (!all.empty()) ch.box = boxOf(std::move(all));
                    } catch (const std::runtime_error& e) {
                        why = e.what();
                    }
                }
                if (!ch.box && obj(c, "summary").contains("median_us")) {
                    ch.box = boxFromSummary(obj(c, "summary"));
                    d.problems.push_back(name + ": " + (why.empty() ? "CSV has no rows" : why) +
                                         "; the numbers of summary.json are used");
                }
            }
            d.chain.push_back(std::move(ch));
        }
    } catch (const json::exception& e) {
        throw std::runtime_error(summaryPath.string() + ": " + e.what());
    } catch (const std::runtime_error& e) {
        // Field type errors from str()/num()/arr() name the field; say which file.
        const std::string what = e.what();
        if (what.rfind("field ", 0) == 0)
            throw std::runtime_error(summaryPath.string() + ": " + what);
        throw;
    }
    return d;
}

// ---- plots --------------------------------------------------------------------------------

struct PlotResult {
    BoxPlot plot;
    std::string error;  // empty: plots/<name>.png written
    std::size_t samples = 0, outliers = 0;
    bool fromSummary = false;
    double max = 0;  // the largest sample of all boxes, and where
    std::string maxWhere;
};

std::string sizeLabel(std::size_t p) { return std::to_string(p); }

std::vector<BoxPlot> buildPlots(const Data& d) {
    std::vector<BoxPlot> plots;
    const std::string rtt = "RTT (µs)";
    // Figs 4.4–4.5: per middleware, echo RTT per payload size, idle / CPU / net side by side.
    const auto echoLoads = d.loads("echo");
    for (const auto& m : d.middlewares("echo")) {
        BoxPlot p;
        p.name = "echo-" + m.adapter + "-" + m.variant;
        p.title = "Echo RTT, " + label(m) + ", per load";
        p.xlabel = "payload size (bytes)";
        p.ylabel = rtt;
        std::set<std::size_t> sizes;
        for (const auto& l : echoLoads)
            if (const Run* r = d.find(m, "echo", l))
                for (const auto& [s, b] : r->boxes) sizes.insert(s);
        for (auto s : sizes) p.groups.push_back(sizeLabel(s));
        for (const auto& l : echoLoads) {
            const Run* r = d.find(m, "echo", l);
            if (!r || r->boxes.empty()) continue;
            p.series.push_back(loadLabel(l));
            std::vector<std::optional<Box>> row;
            for (auto s : sizes) {
                const auto it = r->boxes.find(s);
                row.push_back(it == r->boxes.end() ? std::nullopt : std::optional<Box>(it->second));
            }
            p.boxes.push_back(std::move(row));
        }
        plots.push_back(std::move(p));
    }
    // Fig 4.6a/b: all middlewares side by side per payload size, idle.
    for (const std::string mode : {"echo", "ack"}) {
        const auto mws = d.middlewares(mode, "idle");
        if (mws.empty()) continue;
        BoxPlot p;
        p.name = "compare-" + mode + "-idle";
        p.title = (mode == "echo" ? "Echo" : "ACK") + std::string(" RTT, all middlewares, idle");
        p.xlabel = "payload size (bytes)";
        p.ylabel = rtt;
        std::set<std::size_t> sizes;
        for (const auto& m : mws)
            for (const auto& [s, b] : d.find(m, mode, "idle")->boxes) sizes.insert(s);
        for (auto s : sizes) p.groups.push_back(sizeLabel(s));
        for (const auto& m : mws) {
            const Run* r = d.find(m, mode, "idle");
            p.series.push_back(label(m));
            std::vector<std::optional<Box>> row;
            for (auto s : sizes) {
                const auto it = r->boxes.find(s);
                row.push_back(it == r->boxes.end() ? std::nullopt : std::optional<Box>(it->second));
            }
            p.boxes.push_back(std::move(row));
        }
        plots.push_back(std::move(p));
    }
    // Fig 4.7a: resting RTT per middleware (the smallest payload of the run, normally 4 bytes).
    if (const auto mws = d.middlewares("resting"); !mws.empty()) {
        BoxPlot p;
        p.name = "resting";
        p.title = "Resting RTT (ACK after a random pause), per middleware";
        p.xlabel = "middleware";
        p.ylabel = rtt;
        for (const auto& m : mws) p.groups.push_back(label(m));
        for (const auto& l : d.loads("resting")) {
            p.series.push_back(loadLabel(l));
            std::vector<std::optional<Box>> row;
            for (const auto& m : mws) {
                const Run* r = d.find(m, "resting", l);
                row.push_back(r && !r->boxes.empty() ? std::optional<Box>(r->boxes.begin()->second)
                                                     : std::nullopt);
            }
            p.boxes.push_back(std::move(row));
        }
        plots.push_back(std::move(p));
    }
    // Fig 4.7b: chain RTT per middleware.
    std::vector<const Chain*> chains;
    for (const auto& c : d.chain)
        if (c.box) chains.push_back(&c);
    std::stable_sort(chains.begin(), chains.end(),
                     [&](const Chain* a, const Chain* b) { return d.mwLess(a->mw, b->mw); });
    if (!chains.empty()) {
        BoxPlot p;
        p.name = "chain";
        p.title = "Chain RTT (all streams through all hops), per middleware";
        p.xlabel = "middleware (N = chain nodes)";
        p.ylabel = rtt;
        p.series.push_back("chain");
        std::vector<std::optional<Box>> row;
        for (const auto* c : chains) {
            p.groups.push_back(label(c->mw) + " (N=" + plain(num(c->j, "nodes"), "%.0f") + ")");
            row.push_back(c->box);
        }
        p.boxes.push_back(std::move(row));
        plots.push_back(std::move(p));
    }
    return plots;
}

// ---- the markdown -------------------------------------------------------------------------

void keyValues(std::ostream& o, const json& j) {
    if (!j.is_object() || j.empty()) {
        o << "(not given)\n";
        return;
    }
    for (const auto& [k, v] : j.items()) {
        std::string s = v.is_string() ? v.get<std::string>() : v.dump();
        // The load descriptions are command lines: verbatim.
        const bool command = v.is_string() && k.size() > 5 && k.ends_with("_load");
        o << "- **" << k << "**: " << (command ? "`" + s + "`" : s) << "\n";
    }
}

void rttTable(std::ostream& o, const Data& d, const std::vector<std::size_t>& sizes, bool mean) {
    o << "| Mode | Middleware | Load |";
    for (auto s : sizes) o << ' ' << s << " |";
    o << "\n|---|---|---|";
    for (std::size_t i = 0; i < sizes.size(); ++i) o << "---:|";
    o << "\n";
    for (const std::string mode : {"echo", "ack"})
        for (const auto& m : d.middlewares(mode))
            for (const auto& l : d.loads(mode)) {
                const Run* r = d.find(m, mode, l);
                if (!r || r->boxes.empty()) continue;
                o << "| " << (mode == "echo" ? "Echo" : "ACK") << " | " << cell(label(m)) << " | "
                  << l << " |";
                for (auto s : sizes) {
                    const auto it = r->boxes.find(s);
                    o << ' '
                      << (it == r->boxes.end() ? "–"
                                               : us(mean ? it->second.mean : it->second.median))
                      << " |";
                }
                o << "\n";
            }
}

void thesisTable43(std::ostream& o) {
    o << "| Mode | Middleware | Load |";
    for (int s : thesis::table43Sizes()) o << ' ' << s << " |";
    o << "\n|---|---|---|";
    for (std::size_t i = 0; i < thesis::table43Sizes().size(); ++i) o << "---:|";
    o << "\n";
    for (const auto& r : thesis::table43()) {
        o << "| " << (r.mode == "echo" ? "Echo" : "ACK") << " | " << r.middleware << " | " << r.load
          << " |";
        for (double v : r.meanUs) o << ' ' << (v < 0 ? "?" : fmt("%.0f", v)) << " |";
        o << "\n";
    }
}

// Our run that stands for a thesis row: its MQTT QoS is not stated (QoS 0 assumed), its ROS
// used topics, its DDS Fast RTPS over UDP.
const Run* counterpart(const Data& d, const thesis::RttRow& row) {
    static const std::map<std::string, Mw> map = {
        {"OPC UA C/S", {"opcua", "cs"}}, {"MQTT", {"mqtt", "qos0"}}, {"ROS", {"ros", "topic"}},
        {"DDS", {"dds", "udp"}},         {"TCP", {"tcp", "tcp"}},    {"UDP", {"udp", "udp"}}};
    const auto it = map.find(row.middleware);
    if (it == map.end()) return nullptr;
    const Run* r = d.find(it->second, row.mode, row.load);
    return r && !r->boxes.empty() ? r : nullptr;
}

void sideBySide(std::ostream& o, const Data& d) {
    const auto& sizes = thesis::table43Sizes();
    std::ostringstream rows;
    for (const auto& row : thesis::table43()) {
        const Run* r = counterpart(d, row);
        if (!r) continue;
        rows << "| " << (row.mode == "echo" ? "Echo" : "ACK") << " | " << row.middleware << " = "
             << label(r->mw) << " | " << row.load << " |";
        for (std::size_t i = 0; i < sizes.size(); ++i) {
            const auto it = r->boxes.find(static_cast<std::size_t>(sizes[i]));
            const double t = row.meanUs[i];
            rows << ' ' << (it == r->boxes.end() ? "–" : us(it->second.mean)) << " / "
                 << (t < 0 ? "?" : fmt("%.0f", t)) << " |";
        }
        rows << "\n";
    }
    if (rows.str().empty()) {
        o << "No run of ours matches a row of the thesis's table.\n";
        return;
    }
    o << "| Mode | Middleware (thesis = ours) | Load |";
    for (int s : sizes) o << ' ' << s << " |";
    o << "\n|---|---|---|";
    for (std::size_t i = 0; i < sizes.size(); ++i) o << "---:|";
    o << "\n"
      << rows.str()
      << "\nThesis MQTT is compared with our QoS 0, ROS with topics, DDS with "
         "UDP (the thesis does not state its MQTT QoS).\n";
}

double medianAt(const Run* r, std::size_t s) {
    if (!r) return kNaN;
    const auto it = r->boxes.find(s);
    return it == r->boxes.end() ? kNaN : it->second.median;
}

void opcuaStanding(std::ostream& o, const Data& d) {
    std::vector<Mw> opcua;
    for (const auto& m : d.middlewares("echo", "idle"))
        if (m.adapter == "opcua") opcua.push_back(m);
    for (const auto& m : d.middlewares("ack", "idle"))
        if (m.adapter == "opcua" && std::find(opcua.begin(), opcua.end(), m) == opcua.end())
            opcua.push_back(m);
    if (opcua.empty()) {
        o << "No OPC UA echo / ACK run under idle load in this results directory.\n";
        return;
    }
    for (const std::string mode : {"echo", "ack"}) {
        const std::string Mode = mode == "echo" ? "Echo" : "ACK";
        for (const auto& ua : opcua) {
            const Run* ours = d.find(ua, mode, "idle");
            if (!ours || ours->boxes.empty()) continue;
            // vs raw TCP: the ratio per size and the target.
            const Run* tcp = nullptr;
            for (const auto& m : d.middlewares(mode, "idle"))
                if (m.adapter == "tcp") tcp = d.find(m, mode, "idle");
            if (tcp) {
                o << "- " << Mode << ", idle: " << label(ua)
                  << " median / raw TCP median per payload size:";
                std::vector<std::string> over;
                std::size_t compared = 0;
                for (const auto& [s, b] : ours->boxes) {
                    const double t = medianAt(tcp, s);
                    if (std::isnan(t) || t <= 0) continue;
                    const double q = b.median / t;
                    ++compared;
                    // Two decimals, three where two would hide the side of the target; bold
                    // when above it (echo).
                    std::string text = ratio(q);
                    if ((q > kTcpTarget) != (std::round(q * 100) / 100 > kTcpTarget))
                        text = fmt("%.3f", q) + "×";
                    const bool above = mode == "echo" && q > kTcpTarget;
                    o << (compared == 1 ? " " : ", ") << s << " B "
                      << (above ? "**" + text + "**" : text);
                    if (q > kTcpTarget) over.push_back(std::to_string(s) + " B");
                }
                if (compared == 0) o << " no common payload size";
                o << ".";
                if (mode == "echo" && compared > 0) {
                    if (over.empty())
                        o << " Within the target (≤ " << ratio(kTcpTarget)
                          << ") at every payload size.";
                    else {
                        o << " Within the target (≤ " << ratio(kTcpTarget) << ") at "
                          << compared - over.size() << " of " << compared
                          << " payload sizes; above it at";
                        for (std::size_t i = 0; i < over.size(); ++i)
                            o << (i ? ", " : " ") << over[i];
                        o << ".";
                    }
                }
                o << "\n";
            } else {
                o << "- " << Mode << ", idle: no raw TCP run to compare " << label(ua)
                  << " with.\n";
            }
            // vs the other middlewares.
            for (const auto& other : d.middlewares(mode, "idle")) {
                if (other.adapter == "opcua" || other.adapter == "tcp" || other.adapter == "udp")
                    continue;
                const Run* r = d.find(other, mode, "idle");
                std::vector<std::string> notBelow;
                std::size_t compared = 0;
                for (const auto& [s, b] : ours->boxes) {
                    const double m = medianAt(r, s);
                    if (std::isnan(m)) continue;
                    ++compared;
                    if (!(b.median < m))
                        notBelow.push_back(std::to_string(s) + " B (" + us(b.median) + " vs " +
                                           us(m) + " µs)");
                }
                o << "- " << Mode << ", idle: " << label(ua) << " vs " << label(other) << ": ";
                if (compared == 0)
                    o << "no common payload size.";
                else if (notBelow.empty())
                    o << "median below at every payload size (" << compared << " sizes).";
                else {
                    o << "median below at " << compared - notBelow.size() << " of " << compared
                      << " payload sizes; not below at";
                    for (std::size_t i = 0; i < notBelow.size(); ++i)
                        o << (i ? ", " : " ") << notBelow[i];
                    o << ".";
                }
                o << "\n";
            }
        }
    }
}

void resourcesTable(std::ostream& o, const Data& d) {
    o << "| Middleware | Mode | Load | Samples | msgs/s (smallest payload) | msgs/s (largest "
         "payload) | CPU % client | CPU % server | CPU % broker | RSS MiB client | RSS MiB server "
         "| RSS MiB broker |\n|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    std::vector<const Run*> runs;
    for (const auto& r : d.runs) runs.push_back(&r);
    const std::vector<std::string> modes = {"echo", "ack", "resting"},
                                   loads = {"idle", "cpu", "net"};
    std::stable_sort(runs.begin(), runs.end(), [&](const Run* a, const Run* b) {
        if (a->mw != b->mw) return d.mwLess(a->mw, b->mw);
        if (a->mode != b->mode) return rankOf(modes, a->mode) < rankOf(modes, b->mode);
        return rankOf(loads, a->load) < rankOf(loads, b->load);
    });
    bool estimated = false;
    for (const Run* r : runs) {
        std::size_t n = 0;
        for (const auto& [s, b] : r->boxes) n += b.n;
        auto mps = [&](bool first) -> std::string {
            if (r->boxes.empty()) return "–";
            const auto& [s, b] = first ? *r->boxes.begin() : *r->boxes.rbegin();
            const auto it = r->msgsPerS.find(s);
            const std::string size = " (" + std::to_string(s) + " B)";
            if (it != r->msgsPerS.end()) return fmt("%.0f", it->second) + size;
            if (b.mean <= 0) return "–";
            estimated = true;  // sequential requests: one per mean RTT
            return fmt("%.0f", 1e6 / b.mean) + "*" + size;
        };
        const json& res = r->resources;
        auto part = [&](const char* who, const char* key, bool kib) {
            const double v = num(obj(res, who), key);
            return kib ? mib(v) : plain(v);
        };
        o << "| " << cell(label(r->mw)) << " | " << r->mode << " | " << r->load << " | " << n
          << " | " << mps(true) << " | " << mps(false) << " | " << part("client", "cpu_pct", false)
          << " | " << part("server", "cpu_pct", false) << " | " << part("broker", "cpu_pct", false)
          << " | " << part("client", "rss_kib_max", true) << " | "
          << part("server", "rss_kib_max", true) << " | " << part("broker", "rss_kib_max", true)
          << " |\n";
    }
    if (estimated)
        o << "\n\\* not in summary.json; estimated as 1 / mean RTT (requests are sequential).\n";
}

void chainTable(std::ostream& o, const Data& d) {
    if (d.chain.empty()) {
        o << "No chain test in this results directory.\n";
        return;
    }
    o << "| Middleware | Status | N (nodes) | Streams × hops | Runs | Payload (B) | Processes | "
         "Median µs | Mean µs | p99 µs | RSS total MiB | Note / reason |\n"
         "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n";
    std::vector<const Chain*> chains;
    for (const auto& c : d.chain) chains.push_back(&c);
    std::stable_sort(chains.begin(), chains.end(),
                     [&](const Chain* a, const Chain* b) { return d.mwLess(a->mw, b->mw); });
    for (const Chain* c : chains) {
        const json& j = c->j;
        std::string note = str(j, "note");
        const std::string reason = str(j, "reason");
        if (!reason.empty()) note = note.empty() ? reason : note + "; " + reason;
        o << "| " << cell(label(c->mw)) << " | " << cell(str(j, "status", "ok")) << " | "
          << plain(num(j, "nodes"), "%.0f") << " | " << plain(num(j, "streams"), "%.0f") << " × "
          << plain(num(j, "hops"), "%.0f") << " | " << plain(num(j, "runs"), "%.0f") << " | "
          << plain(num(j, "payload"), "%.0f") << " | " << plain(num(j, "processes"), "%.0f")
          << " | " << (c->box ? us(c->box->median) : "–") << " | "
          << (c->box ? us(c->box->mean) : "–") << " | " << (c->box ? us(c->box->p99) : "–") << " | "
          << mib(num(j, "rss_kib_total")) << " | " << cell(note) << " |\n";
    }
}

void overheadTable(std::ostream& o, const Data& d) {
    const auto& rows = arr(d.summary, "overhead");
    const auto& payloads = thesis::table42Payloads();
    if (rows.empty()) {
        o << "No package overhead measurement in this results directory.\n\n";
    } else {
        // The method is the same for every row: said once, the column keeps what differs.
        std::string common;
        for (const auto& r : rows)
            if (common.empty()) common = str(r, "method");
        o << "Cells: request / response bytes of one message as TCP/UDP payload.";
        if (!common.empty()) o << " Method: " << common << ".";
        o << "\n\n| Middleware | Status |";
        for (int p : payloads) o << ' ' << p << " |";
        o << " Connection | Method / reason |\n|---|---|";
        for (std::size_t i = 0; i < payloads.size(); ++i) o << "---:|";
        o << "---:|---|\n";
        for (const auto& r : rows) {
            const Mw m{str(r, "adapter", "?"), str(r, "variant", "")};
            o << "| " << cell(label(m)) << " | " << cell(str(r, "status", "ok")) << " |";
            for (int p : payloads) {
                std::string c = "–";
                for (const auto& pm : arr(r, "per_message"))
                    if (num(pm, "payload", -1) == p)
                        c = plain(num(pm, "request_bytes"), "%.0f") + " / " +
                            plain(num(pm, "response_bytes"), "%.0f");
                o << ' ' << c << " |";
            }
            std::string how = str(r, "method");
            if (how == common) how.clear();
            const std::string reason = str(r, "reason");
            if (!reason.empty()) how = how.empty() ? reason : how + "; " + reason;
            o << ' ' << plain(num(r, "connection_bytes"), "%.0f") << " | "
              << (how.empty() ? std::string("–") : cell(how)) << " |\n";
        }
        o << "\n";
    }
    o << "Thesis Table 4.2 (bytes transmitted as TCP/UDP payload; connection = establishment + "
         "shutdown):\n\n| Middleware |";
    for (int p : payloads) o << ' ' << p << " |";
    o << " Connection |\n|---|";
    for (std::size_t i = 0; i < payloads.size(); ++i) o << "---:|";
    o << "---:|\n";
    for (const auto& r : thesis::table42()) {
        o << "| " << r.middleware << " |";
        for (int b : r.bytes) o << ' ' << b << " |";
        o << ' ' << r.connection << " |\n";
    }
}

}  // namespace

fs::path writeReport(const fs::path& dir, const Options& options) {
    Data d = load(dir);
    const json& s = d.summary;

    // Plots first: the report links what was actually drawn.
    std::vector<PlotResult> plots;
    std::string noPlots;
    if (!options.plots) {
        noPlots = "no plots: disabled (Options::plots = false)";
    } else if (const auto gnuplot = findGnuplot(); !gnuplot) {
        noPlots = "no plots: gnuplot not found";
    } else {
        std::error_code ec;
        fs::create_directories(dir / "plots", ec);
        if (ec) throw std::runtime_error((dir / "plots").string() + ": " + ec.message());
        fs::create_directories(dir / "logs", ec);
        if (ec) throw std::runtime_error((dir / "logs").string() + ": " + ec.message());
        for (auto& p : buildPlots(d)) {
            PlotResult r;
            for (std::size_t s = 0; s < p.boxes.size(); ++s)
                for (std::size_t g = 0; g < p.boxes[s].size(); ++g)
                    if (const auto& b = p.boxes[s][g]) {
                        r.samples += b->n;
                        r.outliers += b->outliers;
                        r.fromSummary = r.fromSummary || b->fromSummary;
                        if (b->max > r.max) {
                            r.max = b->max;
                            r.maxWhere = p.series[s] + ", " + p.groups[g];
                        }
                    }
            r.error = renderBoxPlot(*gnuplot, dir / "plots", p, dir / "logs" / "gnuplot.log");
            r.plot = std::move(p);
            plots.push_back(std::move(r));
        }
        if (plots.empty()) noPlots = "no plots: no RTT data in this results directory";
    }

    std::ostringstream o;
    o << "# Middleware evaluation (thesis chapter 4.4–4.5)\n\n"
      << "- Report written: " << nowUtc() << "\n"
      << "- Started: " << str(s, "started", "–") << ", finished: " << str(s, "finished", "–")
      << "\n- Duration: " << duration(num(s, "duration_s")) << "\n"
      << "- Quick run: " << str(s, "quick", "false") << "\n\n";

    o << "Our numbers come from one machine over loopback; the thesis used two machines (Intel "
         "i7-8700K, Preempt-RT kernel) connected over Gigabit Ethernet through a switch "
         "(ping RTT 0.35 ms). Absolute values therefore differ by a large factor; compare the "
         "order of the middlewares and the ratios, not the microseconds.\n\n";

    o << "## Machine\n\n";
    keyValues(o, obj(s, "machine"));
    o << "\n## Settings\n\n";
    keyValues(o, obj(s, "settings"));

    o << "\n## Adapters\n\n| Adapter | Variants | Status | Description / reason |\n"
         "|---|---|---|---|\n";
    std::vector<std::string> skipped;
    for (const auto& a : arr(s, "adapters")) {
        std::string variants;
        for (const auto& v : arr(a, "variants"))
            variants +=
                (variants.empty() ? "" : ", ") + (v.is_string() ? v.get<std::string>() : v.dump());
        const std::string status = str(a, "status", "ok");
        std::string text = str(a, "description");
        if (status != "ok") {
            text = str(a, "reason", "no reason given");
            skipped.push_back(str(a, "name", "?") + " (" + status + "): " + text);
        }
        o << "| " << cell(str(a, "name", "?")) << " | " << cell(variants) << " | " << cell(status)
          << " | " << cell(text) << " |\n";
    }
    o << "\n### Skipped adapters\n\n";
    if (skipped.empty()) o << "None.\n";
    for (const auto& x : skipped) o << "- " << x << "\n";
    o << "\n### Failed runs\n\n";
    if (d.failedRuns.empty()) o << "None.\n";
    for (const auto& x : d.failedRuns) o << "- " << x << "\n";
    o << "\n### Data problems\n\n";
    if (d.problems.empty()) o << "None: every CSV row was used.\n";
    for (const auto& x : d.problems) o << "- " << x << "\n";

    o << "\n## How to read this / where our OPC UA stands\n\n"
      << "RTT is the time from sending a request to receiving its answer, measured by the client "
         "with the steady clock, one sample per request (ACK: 1-byte answer; echo: the payload "
         "back). Box plots: the box spans the quartiles, the line and × mark the median, the "
         "whiskers reach the furthest sample within 1.5 IQR of the box, ○ marks the 99th "
         "percentile; samples beyond the whiskers are not drawn one by one (their number and "
         "the largest sample are given under each plot; the y range follows whiskers and 99th "
         "percentiles, so that one scheduler hiccup does not squash every box). Every statistic is "
         "computed from every CSV row; nothing is downsampled. "
         "The y axis is logarithmic where the values span more than a decade.\n\n"
      << "Medians, idle; the issue's target for echo is OPC UA ≤ " << ratio(kTcpTarget)
      << " raw TCP:\n\n";
    opcuaStanding(o, d);

    o << "\n## Plots\n\n";
    if (!noPlots.empty()) o << noPlots << "\n\n";
    for (const auto& p : plots) {
        if (!p.error.empty()) {
            o << "- " << p.plot.title << ": no plot (" << p.error << ")\n\n";
            continue;
        }
        o << "### " << p.plot.title << "\n\n![" << p.plot.title << "](plots/" << p.plot.name
          << ".png)\n\n"
          << p.samples << " samples; " << p.outliers
          << " beyond the whiskers (not drawn one by one); ○ = 99th percentile; largest sample "
          << us(p.max) << " µs (" << p.maxWhere << ").";
        if (p.fromSummary)
            o << " Some boxes come from summary.json (no CSV): their whiskers are min / max.";
        o << "\n\n";
    }

    const auto sizes = d.sizes({"echo", "ack"});
    o << "## Mean RTT in µs (Table 4.3 equivalent)\n\n";
    if (sizes.empty())
        o << "No echo / ACK data.\n";
    else
        rttTable(o, d, sizes, true);
    o << "\nThesis Table 4.3 (published; average RTT in µs, two machines over Gigabit "
         "Ethernet):\n\n";
    thesisTable43(o);
    o << "\n"
      << thesis::table43Note() << " The thesis does not say which MQTT QoS it used; its "
      << "OPC UA P/S rows have no counterpart here.\n";
    o << "\nOurs next to the thesis (mean µs, ours / thesis), for the rows both have:\n\n";
    sideBySide(o, d);
    o << "\n## Median RTT in µs\n\n";
    if (sizes.empty())
        o << "No echo / ACK data.\n";
    else
        rttTable(o, d, sizes, false);

    o << "\n## Throughput, CPU and memory per run\n\n";
    if (d.runs.empty())
        o << "No runs.\n";
    else
        resourcesTable(o, d);

    o << "\n## Chain (500 nodes in the thesis: 10 streams × 50 hops, 10240 B)\n\n";
    chainTable(o, d);

    o << "\n## Package overhead (Table 4.2 equivalent)\n\n";
    overheadTable(o, d);

    const fs::path report = dir / "report.md";
    const fs::path tmp = dir / "report.md.tmp";
    {
        std::ofstream out(tmp, std::ios::trunc);
        if (!out) throw std::runtime_error(tmp.string() + ": cannot write");
        out << o.str();
        out.close();
        if (!out) throw std::runtime_error(tmp.string() + ": write failed");
    }
    std::error_code ec;
    fs::rename(tmp, report, ec);
    if (ec) throw std::runtime_error(report.string() + ": " + ec.message());
    return report;
}

}  // namespace pnp::bench::report
