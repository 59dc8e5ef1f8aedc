#include "bench/runner/runner.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/utsname.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "bench/runner/netns.hpp"
#include "bench/runner/overhead.hpp"
#include "bench/runner/process.hpp"
#include "bench/runner/resources.hpp"

#ifndef PNP_MW_ADAPTER_DIR_DEFAULT
#define PNP_MW_ADAPTER_DIR_DEFAULT "mw"
#endif

namespace pnp::bench::runner {

namespace fs = std::filesystem;
using Json = nlohmann::json;
using namespace std::chrono_literals;

const std::vector<std::string>& knownAdapters() {
    static const std::vector<std::string> names = {"tcp", "udp", "opcua", "mqtt", "dds", "ros"};
    return names;
}

fs::path defaultAdapterDir() { return PNP_MW_ADAPTER_DIR_DEFAULT; }

namespace {

void onStopSignal(int) { stopRequested().store(true); }

std::string isoNow() {
    const std::time_t t = std::time(nullptr);
    std::tm tm{};
    ::gmtime_r(&t, &tm);
    char buf[32];
    std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
    return buf;
}

std::string readFirstLine(const std::string& path, const std::string& prefix) {
    std::ifstream f(path);
    std::string line;
    while (std::getline(f, line))
        if (line.rfind(prefix, 0) == 0) return line.substr(prefix.size());
    return {};
}

long memInfoKib(const std::string& key) {
    return std::atol(readFirstLine("/proc/meminfo", key + ":").c_str());
}

std::string trim(std::string s) {
    const auto b = s.find_first_not_of(" \t:\"");
    const auto e = s.find_last_not_of(" \t\"");
    return b == std::string::npos ? std::string() : s.substr(b, e - b + 1);
}

Json machine() {
    utsname u{};
    ::uname(&u);
    char host[256] = {};
    ::gethostname(host, sizeof host - 1);
    return {{"cpu_model", trim(readFirstLine("/proc/cpuinfo", "model name"))},
            {"cores", std::thread::hardware_concurrency()},
            {"memory_mib", memInfoKib("MemTotal") / 1024},
            {"kernel", u.release},
            {"os", trim(readFirstLine("/etc/os-release", "PRETTY_NAME="))},
            {"hostname", host}};
}

std::string join(const std::vector<std::string>& v, const std::string& sep = ",") {
    std::string s;
    for (const auto& x : v) s += (s.empty() ? "" : sep) + x;
    return s;
}

template <class T>
std::string joinNumbers(const std::vector<T>& v) {
    std::string s;
    for (const auto& x : v) s += (s.empty() ? "" : ",") + std::to_string(x);
    return s;
}

double round1(double v) { return std::round(v * 10) / 10; }

// A port that was free on 127.0.0.1 for TCP and UDP a moment ago (not iperf3's 5201).
int freePort() {
    for (int attempt = 0; attempt < 50; ++attempt) {
        const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
        socklen_t len = sizeof a;
        ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
        ::close(fd);
        const int port = ntohs(a.sin_port);
        const int u = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
        const bool udpFree = ::bind(u, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
        ::close(u);
        if (udpFree && port != 5201 && port < 65000) return port;
    }
    throw std::runtime_error("no free port");
}

bool portFree(int port) {
    for (int type : {SOCK_STREAM, SOCK_DGRAM}) {
        const int fd = ::socket(AF_INET, type | SOCK_CLOEXEC, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        a.sin_port = htons(static_cast<std::uint16_t>(port));
        const bool ok = ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
        ::close(fd);
        if (!ok) return false;
    }
    return true;
}

// A base port with base .. base + count - 1 free (chain nodes use base + 1 + i).
int freePortRange(int count) {
    std::uint32_t x = static_cast<std::uint32_t>(::getpid()) * 2654435761u ^
                      static_cast<std::uint32_t>(std::time(nullptr));
    for (int attempt = 0; attempt < 40; ++attempt) {
        x = x * 1664525u + 1013904223u;
        const int base = 20000 + static_cast<int>(x % 30000u);
        bool ok = true;
        for (int p = base; ok && p < base + count; ++p) ok = p != 5201 && portFree(p);
        if (ok) return base;
    }
    throw std::runtime_error("no free range of " + std::to_string(count) + " ports");
}

struct AdapterInfo {
    std::string name;
    std::string exe;
    std::vector<std::string> variants;
    std::string description;
    bool chain = false;
    bool ok = false;
    std::string reason;
};

// Where the processes of a run live: the runner's own namespace on loopback, or the two
// namespaces of the network load.
struct Site {
    std::string serverNs, clientNs;
    std::string serverAddr = "127.0.0.1", clientAddr = "127.0.0.1";
};

// The broker (mqtt) or master (ros) of an adapter, and what its processes are told of it.
struct Peer {
    std::unique_ptr<Process> proc;
    std::vector<std::string> args;
    std::string uri;
};

constexpr int kPilotReps = 5;

struct Settings {
    int reps = 5000, repsUnderLoad = 1000, warmup = 100;
    std::vector<std::size_t> sizes;
    double restingSeconds = 15, restingMaxPause = 3;
    std::string placement = "different";
    int clientCpu = 0, serverCpu = 1;
    int chainStreams = 10, chainHops = 50, chainRuns = 100;
    std::size_t chainPayload = 10240;
    int overheadReps = 100;
    // Seconds one ACK / Echo run may take (estimated by a pilot); a slower middleware gets
    // fewer reps, at least minReps.
    double runBudgetIdle = 40, runBudgetLoad = 30;
    int minReps = 20;
    std::vector<std::string> loads, modes;
};

class Runner {
  public:
    explicit Runner(const Options& o) : options_(o) {}
    fs::path run();

  private:
    void say(const std::string& line) {
        if (options_.progress)
            options_.progress(line);
        else
            std::cerr << line << std::endl;
    }
    void settle();
    void discover();
    void save();
    std::string log(const std::string& name) const { return (out_ / "logs" / name).string(); }
    std::vector<std::string> env(const AdapterInfo& a, const std::string& ownAddr,
                                 const Peer& peer) const;
    std::vector<std::string> addressing(const AdapterInfo& a, const std::string& variant,
                                        const std::string& host, const std::string& local, int port,
                                        const Peer& peer, int domain, int cpu) const;
    bool usesPort(const AdapterInfo& a) const {
        return a.name != "mqtt" && a.name != "ros" && a.name != "dds";
    }
    int nextDomain() { return 1 + (domainBase_ + domainCount_++) % 200; }
    Peer startPeer(const AdapterInfo& a, const Site& site, const std::string& tag);
    // The adapter's server (`server --mode MODE`) in the site's server namespace, READY or
    // null with the reason in `error`.
    std::unique_ptr<Process> startServer(const AdapterInfo& a, const std::string& variant,
                                         const std::string& mode, const Site& site,
                                         const Peer& peer, int port, int domain, int cpu,
                                         const std::string& tag, std::string& error);
    Json runOne(const AdapterInfo& a, const std::string& variant, const std::string& mode,
                const std::string& load, const Site& site, const Peer& peer);
    Json chainRecord(const AdapterInfo& a, int hops) const;
    Json runChain(const AdapterInfo& a, int hops);
    Json runChainLargestThatWorks(const AdapterInfo& a);
    Json runOverhead(const AdapterInfo& a, const std::string& variant);
    void runLoad(const std::string& load);

    const Options& options_;
    Settings s_;
    fs::path out_;
    Json summary_;
    std::vector<AdapterInfo> adapters_;
    std::chrono::steady_clock::time_point start_;
    int domainBase_ = static_cast<int>(::getpid() % 200);
    int domainCount_ = 0;
    int runIndex_ = 0, runTotal_ = 0;
};

void Runner::settle() {
    const Options& o = options_;
    const bool q = o.quick;
    s_.reps = o.reps > 0 ? o.reps : (q ? 50 : 5000);
    s_.repsUnderLoad = o.repsUnderLoad > 0 ? o.repsUnderLoad : o.reps > 0 ? o.reps : (q ? 50 : 500);
    s_.warmup = o.warmup >= 0 ? o.warmup : (q ? 5 : 100);
    s_.sizes = o.sizes;
    if (s_.sizes.empty())
        for (std::size_t n = 2; n <= 32768; n *= 2) s_.sizes.push_back(n);
    s_.restingSeconds = o.restingSeconds > 0 ? o.restingSeconds : (q ? 2 : 15);
    s_.restingMaxPause = o.restingMaxPause > 0 ? o.restingMaxPause : (q ? 0.3 : 3);
    s_.placement = o.placement;
    const int cores = static_cast<int>(std::thread::hardware_concurrency());
    if (s_.placement == "different" && cores >= 2) {
        s_.clientCpu = 0;
        s_.serverCpu = 1;
    } else if (s_.placement == "different" || s_.placement == "same") {
        s_.clientCpu = s_.serverCpu = 0;
    } else if (s_.placement == "none") {
        s_.clientCpu = s_.serverCpu = -1;
    } else {
        throw std::invalid_argument("--placement is different, same or none, not " + s_.placement);
    }
    if (q) {
        s_.chainStreams = 2;
        s_.chainHops = 5;
        s_.chainRuns = 10;
    }
    s_.overheadReps = q ? 10 : 100;
    if (q) {
        s_.runBudgetIdle = s_.runBudgetLoad = 4;
        s_.minReps = 10;
    }
    s_.loads = o.loads.empty() ? (q ? std::vector<std::string>{"idle"}
                                    : std::vector<std::string>{"idle", "cpu", "net"})
                               : o.loads;
    for (const auto& l : s_.loads)
        if (l != "idle" && l != "cpu" && l != "net")
            throw std::invalid_argument("unknown load '" + l + "' (idle, cpu, net)");
    s_.modes = o.modes.empty() ? std::vector<std::string>{"ack", "echo", "resting"} : o.modes;
    for (const auto& m : s_.modes)
        if (m != "ack" && m != "echo" && m != "resting")
            throw std::invalid_argument("unknown mode '" + m + "' (ack, echo, resting)");
    for (const auto& a : o.only)
        if (std::find(knownAdapters().begin(), knownAdapters().end(), a) == knownAdapters().end())
            throw std::invalid_argument("unknown adapter '" + a + "' (" + join(knownAdapters()) +
                                        ")");
    if (s_.reps < 1 || s_.reps > 1000000 || s_.repsUnderLoad < 1 || s_.repsUnderLoad > 1000000)
        throw std::invalid_argument("--reps out of range (1 .. 1000000)");
}

void Runner::discover() {
    const fs::path dir = options_.adapterDir.empty() ? defaultAdapterDir() : options_.adapterDir;
    for (const auto& name : knownAdapters()) {
        if (!options_.only.empty() &&
            std::find(options_.only.begin(), options_.only.end(), name) == options_.only.end())
            continue;
        AdapterInfo a;
        a.name = name;
        a.exe = (dir / ("pnp-mw-" + name)).string();
        if (::access(a.exe.c_str(), X_OK) != 0) {
            a.reason = "pnp-mw-" + name + " not built (no executable " + a.exe + ")";
        } else {
            std::string out;
            const int rc = runCommandOutput({a.exe, "info"}, out, log("info.log"), 15s);
            try {
                const Json j = Json::parse(out);
                a.variants = j.at("variants").get<std::vector<std::string>>();
                a.description = j.value("description", "");
                a.chain = j.value("chain", false);
                a.ok = rc == 0 && !a.variants.empty();
                if (!a.ok)
                    a.reason =
                        "`pnp-mw-" + name + " info` failed (exit " + std::to_string(rc) + ")";
            } catch (const std::exception& e) {
                a.reason = "`pnp-mw-" + name + " info` printed no JSON (exit " +
                           std::to_string(rc) + "): " + e.what();
            }
        }
        if (a.ok && name == "mqtt" && findExecutable("/usr/sbin/mosquitto").empty() &&
            findExecutable("mosquitto").empty()) {
            a.ok = false;
            a.reason = "no mosquitto broker installed";
        }
        if (a.ok && name == "ros" && findExecutable("rosmaster").empty()) {
            a.ok = false;
            a.reason = "no rosmaster installed (python3-rosmaster)";
        }
        say(a.ok ? "adapter " + name + ": " + join(a.variants) + (a.chain ? " (chain)" : "")
                 : "adapter " + name + ": skipped, " + a.reason);
        adapters_.push_back(a);
        summary_["adapters"].push_back({{"name", a.name},
                                        {"variants", a.variants},
                                        {"description", a.description},
                                        {"status", a.ok ? "ok" : "skipped"},
                                        {"reason", a.reason}});
    }
}

void Runner::save() {
    summary_["finished"] = isoNow();
    summary_["duration_s"] =
        round1(std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count());
    const fs::path tmp = out_ / "summary.json.tmp";
    {
        std::ofstream f(tmp, std::ios::trunc);
        f << summary_.dump(2) << '\n';
        if (!f) throw std::runtime_error("cannot write " + tmp.string());
    }
    fs::rename(tmp, out_ / "summary.json");
}

std::vector<std::string> Runner::env(const AdapterInfo& a, const std::string& ownAddr,
                                     const Peer& peer) const {
    if (a.name != "ros") return {};
    const std::string rosHome = (out_ / "logs" / "ros").string();
    std::vector<std::string> e = {"ROS_HOME=" + rosHome, "ROS_LOG_DIR=" + rosHome,
                                  "ROS_IP=" + ownAddr};
    if (!peer.uri.empty()) e.push_back("ROS_MASTER_URI=" + peer.uri);
    return e;
}

std::vector<std::string> Runner::addressing(const AdapterInfo& a, const std::string& variant,
                                            const std::string& host, const std::string& local,
                                            int port, const Peer& peer, int domain, int cpu) const {
    std::vector<std::string> v = {"--variant", variant, "--host", host, "--local", local};
    if (usesPort(a) && port > 0) v.insert(v.end(), {"--port", std::to_string(port)});
    v.insert(v.end(), peer.args.begin(), peer.args.end());
    if (a.name == "dds" && domain >= 0)
        v.insert(v.end(), {"--set", "domain=" + std::to_string(domain)});
    if (cpu >= 0) v.insert(v.end(), {"--cpu", std::to_string(cpu)});
    return v;
}

Peer Runner::startPeer(const AdapterInfo& a, const Site& site, const std::string& tag) {
    Peer p;
    if (a.name != "mqtt" && a.name != "ros") return p;
    const int port = freePort();
    Spawn sp;
    sp.netns = site.serverNs;
    sp.cpu = s_.serverCpu;
    sp.captureStdout = false;
    if (a.name == "mqtt") {
        const std::string conf = log(tag + "-mosquitto.conf");
        std::ofstream(conf) << "listener " << port << " " << site.serverAddr
                            << "\nallow_anonymous true\npersistence false\n"
                            // Nagle off, as on every other middleware's sockets: without it
                            // a QoS 1 request waits ~40 ms for the delayed ACK.
                            << "set_tcp_nodelay true\n";
        std::string exe = findExecutable("/usr/sbin/mosquitto");
        if (exe.empty()) exe = findExecutable("mosquitto");
        sp.argv = {exe, "-c", conf};
        sp.log = log(tag + "-mosquitto.log");
        p.args = {"--port", std::to_string(port)};
        p.uri = "mqtt://" + site.serverAddr + ":" + std::to_string(port);
    } else {
        p.uri = "http://" + site.serverAddr + ":" + std::to_string(port);
        sp.argv = {findExecutable("rosmaster"), "--core", "-p", std::to_string(port)};
        sp.log = log(tag + "-rosmaster.log");
        sp.env = env(a, site.serverAddr, p);
        p.args = {"--set", "master=" + p.uri};
    }
    p.proc = Process::start(sp);
    if (!waitForPort(site.serverNs, site.serverAddr, port, 20s)) {
        checkStop();
        throw std::runtime_error(p.proc->name() + " does not accept connections on " + p.uri +
                                 " within 20 s: " + p.proc->logTail(400));
    }
    return p;
}

Json summaryOf(const Json& line) {
    Json s = Json::object();
    for (const char* k : {"payload", "n", "min_us", "q1_us", "median_us", "q3_us", "mean_us",
                          "p99_us", "max_us", "msgs_per_s"})
        s[k] = line.value(k, Json(0));
    return s;
}

Json usageJson(const Usage& u) {
    return {{"cpu_pct", round1(u.cpuPct)}, {"rss_kib_max", u.rssKibMax}};
}

std::string describeSizes(const Json& sizes) {
    if (sizes.empty()) return "";
    auto one = [](const Json& s) {
        std::ostringstream o;
        o.precision(1);
        o << std::fixed << s.value("payload", 0) << " B " << s.value("median_us", 0.0) << " us";
        return o.str();
    };
    return "median " + one(sizes.front()) +
           (sizes.size() > 1 ? ", " + one(sizes.back()) : std::string());
}

std::unique_ptr<Process> Runner::startServer(const AdapterInfo& a, const std::string& variant,
                                             const std::string& mode, const Site& site,
                                             const Peer& peer, int port, int domain, int cpu,
                                             const std::string& tag, std::string& error) {
    Spawn ss;
    ss.argv = {a.exe, "server", "--mode", mode};
    auto addr = addressing(a, variant, site.serverAddr, site.serverAddr, port, peer, domain, cpu);
    ss.argv.insert(ss.argv.end(), addr.begin(), addr.end());
    ss.log = log(tag + "-server.log");
    ss.netns = site.serverNs;
    ss.env = env(a, site.serverAddr, peer);
    auto server = Process::start(ss);
    if (!server->waitForLine("READY", 30s, error)) {
        checkStop();
        error = "server not ready: " + error;
        return nullptr;
    }
    return server;
}

Json Runner::runOne(const AdapterInfo& a, const std::string& variant, const std::string& mode,
                    const std::string& load, const Site& site, const Peer& peer) {
    const std::string tag = load + "/" + a.name + "-" + variant + "-" + mode;
    const std::string csvRel =
        "samples/" + load + "/" + a.name + "-" + variant + "-" + mode + ".csv";
    fs::create_directories(out_ / "samples" / load);
    fs::create_directories(out_ / "logs" / load);
    Json run = {{"adapter", a.name}, {"variant", variant},     {"mode", mode},
                {"load", load},      {"status", "failed"},     {"reason", ""},
                {"csv", csvRel},     {"sizes", Json::array()}, {"resources", nullptr}};
    const auto t0 = std::chrono::steady_clock::now();
    int reps = load == "idle" ? s_.reps : s_.repsUnderLoad;
    int warmup = s_.warmup;
    const int port = usesPort(a) ? freePort() : 0;
    const int domain = nextDomain();
    // The server: resting uses an ACK server.
    std::string error;
    auto server = startServer(a, variant, mode == "echo" ? "echo" : "ack", site, peer, port, domain,
                              s_.serverCpu, tag, error);
    if (!server) {
        run["reason"] = error;
        return run;
    }
    std::string note;
    if (mode != "resting") {
        // Pilot: a few requests per size estimate the run's time; a middleware that is far
        // slower than the rest gets fewer reps, so that the whole evaluation keeps its budget.
        Spawn ps;
        ps.argv = {a.exe, "client", "--mode", mode};
        auto pa = addressing(a, variant, site.serverAddr, site.clientAddr, port, peer, domain,
                             s_.clientCpu);
        ps.argv.insert(ps.argv.end(), pa.begin(), pa.end());
        const std::vector<std::string> po = {
            "--reps",  std::to_string(kPilotReps), "--warmup",     "1",
            "--sizes", joinNumbers(s_.sizes),      "--timeout-ms", "10000"};
        ps.argv.insert(ps.argv.end(), po.begin(), po.end());
        ps.log = log(tag + "-pilot.log");
        ps.netns = site.clientNs;
        ps.env = env(a, site.clientAddr, peer);
        auto pilot = Process::start(ps);
        const auto pilotEnd = std::chrono::steady_clock::now() + 120s;
        while (!pilot->exited() && std::chrono::steady_clock::now() < pilotEnd) {
            if (stopRequested()) throw Interrupted();
            pilot->pump();
            server->pump();
            std::this_thread::sleep_for(20ms);
        }
        pilot->stop(500ms);
        double perRepUs = 0;  // one request of every size
        for (const auto& l : pilot->lines()) {
            try {
                const Json j = Json::parse(l);
                perRepUs += j.value("mean_us", 0.0);
            } catch (const std::exception&) {
            }
        }
        const double estimate = perRepUs * (reps + warmup) / 1e6;
        const double budget = load == "idle" ? s_.runBudgetIdle : s_.runBudgetLoad;
        if (pilot->exitCode() == 0 && estimate > budget) {
            const int fewer = std::max(s_.minReps, static_cast<int>(reps * budget / estimate));
            if (fewer < reps) {
                std::ostringstream n;
                n.precision(1);
                n << std::fixed << "reps reduced from " << reps << " to " << fewer
                  << ": a pilot of " << kPilotReps << " requests per size estimated " << estimate
                  << " s, over the run budget of " << budget << " s";
                note = n.str();
                warmup = std::min(warmup, std::max(1, fewer / 10));
                reps = fewer;
            }
        }
    }
    run["reps"] = reps;
    run["note"] = note;
    Spawn cs;
    cs.argv = {a.exe, "client", "--mode", mode};
    const auto addr =
        addressing(a, variant, site.serverAddr, site.clientAddr, port, peer, domain, s_.clientCpu);
    cs.argv.insert(cs.argv.end(), addr.begin(), addr.end());
    const std::vector<std::string> clientOpts = {"--reps",
                                                 std::to_string(reps),
                                                 "--warmup",
                                                 std::to_string(warmup),
                                                 "--sizes",
                                                 mode == "resting" ? "4" : joinNumbers(s_.sizes),
                                                 "--csv",
                                                 (out_ / csvRel).string(),
                                                 "--resting-seconds",
                                                 std::to_string(s_.restingSeconds),
                                                 "--resting-max-pause",
                                                 std::to_string(s_.restingMaxPause),
                                                 "--timeout-ms",
                                                 "10000"};
    cs.argv.insert(cs.argv.end(), clientOpts.begin(), clientOpts.end());
    cs.log = log(tag + "-client.log");
    cs.netns = site.clientNs;
    cs.env = env(a, site.clientAddr, peer);
    // Bound: generous against slow middlewares, a hang still ends.
    const double requests = mode == "resting" ? 0
                                              : static_cast<double>(reps + warmup) *
                                                    static_cast<double>(s_.sizes.size());
    const auto limit = std::chrono::seconds(120) +
                       std::chrono::milliseconds(static_cast<long>(requests * 20)) +
                       std::chrono::seconds(static_cast<long>(
                           mode == "resting" ? 2 * s_.restingSeconds + 2 * s_.restingMaxPause : 0));
    ResourceSampler rs;
    auto client = Process::start(cs);
    rs.add("client", {client->pid()});
    rs.add("server", {server->pid()});
    if (peer.proc) rs.add("broker", {peer.proc->pid()});
    rs.sample();
    const auto deadline = std::chrono::steady_clock::now() + limit;
    bool timedOut = false;
    for (;;) {
        client->pump();
        if (client->exitedUnreaped()) {
            rs.sample();  // its last CPU times, before it is reaped
            break;
        }
        if (stopRequested()) {
            client->stop(1000ms);
            throw Interrupted();
        }
        if (std::chrono::steady_clock::now() >= deadline) {
            timedOut = true;
            break;
        }
        std::this_thread::sleep_for(100ms);
        server->pump();  // a chatty server must not block on a full pipe
        rs.sample();
    }
    if (timedOut) client->stop(1000ms);
    client->exited();
    client->pump();
    const bool serverAlive = !server->exited();
    server->stop();
    Json sizes = Json::array();
    for (const auto& l : client->lines()) {
        if (l.empty() || l.front() != '{') continue;
        try {
            const Json j = Json::parse(l);
            if (j.contains("payload")) sizes.push_back(summaryOf(j));
        } catch (const std::exception&) {
            // not a summary line
        }
    }
    run["sizes"] = sizes;
    Json res = {{"client", usageJson(rs.usage("client"))},
                {"server", usageJson(rs.usage("server"))},
                {"broker", peer.proc ? usageJson(rs.usage("broker")) : Json(nullptr)}};
    run["resources"] = res;
    const std::size_t expected = mode == "resting" ? 1 : s_.sizes.size();
    bool allSamples = sizes.size() == expected;
    for (const auto& s : sizes) allSamples = allSamples && s.value("n", 0) > 0;
    std::string reason;
    if (timedOut)
        reason = "client did not finish within " +
                 std::to_string(std::chrono::duration_cast<std::chrono::seconds>(limit).count()) +
                 " s";
    else if (client->exitCode() != 0)
        reason = "client exit code " + std::to_string(client->exitCode()) +
                 (client->exitCode() == 4 ? " (a reply that is not what was sent)" : "") + ": " +
                 client->logTail(600);
    else if (!allSamples)
        reason = "client printed " + std::to_string(sizes.size()) + " of " +
                 std::to_string(expected) + " summaries (or one with n = 0)";
    if (!serverAlive)
        reason += std::string(reason.empty() ? "" : "; ") + "server exited during the run (code " +
                  std::to_string(server->exitCode()) + "): " + server->logTail(300);
    run["status"] = reason.empty() ? "ok" : "failed";
    run["reason"] = reason;
    const double secs =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::ostringstream line;
    line.precision(1);
    line << std::fixed << "[" << ++runIndex_ << "/" << runTotal_ << "] " << load << " " << a.name
         << "/" << variant << " " << mode << ": " << (reason.empty() ? "ok" : "FAILED") << " ("
         << secs << " s) " << (reason.empty() ? describeSizes(sizes) : reason.substr(0, 300))
         << (note.empty() ? "" : " [" + note + "]");
    say(line.str());
    return run;
}

// The processes of a load scenario, stopped / removed when it ends.
struct LoadScope {
    std::unique_ptr<NetPair> net;
    std::unique_ptr<Process> stress, iperfServer, iperfClient;
    Site site;
    ~LoadScope() {
        if (iperfClient) iperfClient->stop(2000ms);
        if (iperfServer) iperfServer->stop(2000ms);
        if (stress) stress->stop(3000ms);
        if (net) net->remove();
    }
};

void Runner::runLoad(const std::string& load) {
    LoadScope scope;
    fs::create_directories(out_ / "logs" / load);
    const std::string loadLog = log(load + "-load.log");
    if (load == "cpu") {
        const std::string exe = findExecutable("stress-ng");
        if (exe.empty()) throw std::runtime_error("stress-ng not installed");
        std::vector<int> cores;
        if (s_.clientCpu >= 0) cores.push_back(s_.clientCpu);
        if (s_.serverCpu >= 0 && s_.serverCpu != s_.clientCpu) cores.push_back(s_.serverCpu);
        if (cores.empty())
            for (int c = 0; c < static_cast<int>(std::thread::hardware_concurrency()); ++c)
                cores.push_back(c);
        Spawn sp;
        sp.argv = {exe,
                   "--cpu",
                   std::to_string(cores.size()),
                   "--taskset",
                   joinNumbers(cores),
                   "--cpu-load",
                   "100",
                   "--timeout",
                   "86400s"};
        sp.log = loadLog;
        sp.captureStdout = false;
        scope.stress = Process::start(sp);
        summary_["settings"]["cpu_load"] =
            join(std::vector<std::string>(sp.argv.begin() + 1, sp.argv.end()), " ");
        summary_["settings"]["cpu_load"] =
            "stress-ng " + summary_["settings"]["cpu_load"].get<std::string>() +
            " (started before the scenario's first run, stopped after its last)";
        std::this_thread::sleep_for(1s);
        if (scope.stress->exited())
            throw std::runtime_error("stress-ng exited: " + scope.stress->logTail(400));
    } else if (load == "net") {
        NetPairConfig c;
        c.name = "pnpmw" + std::to_string(::getpid());
        c.rate = options_.netRate;
        c.log = loadLog;
        scope.net = std::make_unique<NetPair>(c);
        scope.site = {scope.net->serverNs(), scope.net->clientNs(), NetPair::kServerAddr,
                      NetPair::kClientAddr};
        const std::string exe = findExecutable("iperf3");
        if (exe.empty()) throw std::runtime_error("iperf3 not installed");
        Spawn srv;
        srv.argv = {exe, "-s", "-B", NetPair::kServerAddr, "-p", "5201"};
        srv.log = log("net-iperf3-server.log");
        srv.captureStdout = false;
        srv.netns = scope.net->serverNs();
        scope.iperfServer = Process::start(srv);
        if (!waitForPort(srv.netns, NetPair::kServerAddr, 5201, 10s)) {
            checkStop();
            throw std::runtime_error("iperf3 server not listening: " +
                                     scope.iperfServer->logTail(400));
        }
        Spawn cl;
        cl.argv = {
            exe,  "-c", NetPair::kServerAddr, "-p", "5201", "-t", "86400", "-P", "2", "--bidir",
            "-i", "10"};
        cl.log = log("net-iperf3-client.log");
        cl.captureStdout = false;
        cl.netns = scope.net->clientNs();
        scope.iperfClient = Process::start(cl);
        std::this_thread::sleep_for(1s);
        if (scope.iperfClient->exited())
            throw std::runtime_error("iperf3 client exited: " + scope.iperfClient->logTail(400));
        summary_["settings"]["net_load"] =
            scope.net->describe() + "; `iperf3 -s` in the server netns, `iperf3 -c " +
            NetPair::kServerAddr +
            " -P 2 --bidir -t 86400` in the client netns (two TCP streams each way) for the "
            "whole scenario; adapter server, broker and master in the server netns, the client "
            "in the client netns";
    }
    save();
    for (const auto& a : adapters_) {
        if (!a.ok) continue;
        checkStop();
        Peer peer;
        try {
            peer = startPeer(a, scope.site, load + "/" + a.name);
        } catch (const Interrupted&) {
            throw;
        } catch (const std::exception& e) {
            say(load + " " + a.name + ": " + e.what());
            for (const auto& v : a.variants)
                for (const auto& m : s_.modes) {
                    summary_["runs"].push_back({{"adapter", a.name},
                                                {"variant", v},
                                                {"mode", m},
                                                {"load", load},
                                                {"status", "failed"},
                                                {"reason", e.what()},
                                                {"csv", ""},
                                                {"sizes", Json::array()},
                                                {"resources", nullptr}});
                    ++runIndex_;
                }
            save();
            continue;
        }
        for (const auto& v : a.variants)
            for (const auto& m : s_.modes) {
                checkStop();
                Json r;
                try {
                    r = runOne(a, v, m, load, scope.site, peer);
                } catch (const Interrupted&) {
                    throw;
                } catch (const std::exception& e) {
                    r = {{"adapter", a.name}, {"variant", v},           {"mode", m},
                         {"load", load},      {"status", "failed"},     {"reason", e.what()},
                         {"csv", ""},         {"sizes", Json::array()}, {"resources", nullptr}};
                    say(load + " " + a.name + "/" + v + " " + m + ": FAILED " + e.what());
                }
                summary_["runs"].push_back(r);
                save();
            }
        if (peer.proc) peer.proc->stop();
    }
    if (scope.stress && scope.stress->exited())
        say("warning: stress-ng ended during the cpu scenario: " + scope.stress->logTail(300));
    if (scope.iperfClient && scope.iperfClient->exited())
        say("warning: iperf3 ended during the net scenario: " + scope.iperfClient->logTail(300));
}

// Nodes per process in the chain test: tcp, udp, opcua and mqtt serve many nodes from one
// process's threads; a DDS participant per node is heavy (threads, discovery), so fewer per
// process; ros forks one process per node itself.
int nodesPerProcess(const std::string& adapter) { return adapter == "dds" ? 25 : 50; }

// A chain's summary.json record before anything ran (status failed, no reason yet).
Json Runner::chainRecord(const AdapterInfo& a, int hops) const {
    const std::string variant = a.variants.front();
    return {{"adapter", a.name},
            {"variant", variant},
            {"status", "failed"},
            {"reason", ""},
            {"nodes", 0},
            {"streams", s_.chainStreams},
            {"hops", hops},
            {"runs", s_.chainRuns},
            {"payload", s_.chainPayload},
            {"processes", 0},
            {"note", ""},
            {"summary", nullptr},
            {"rss_kib_total", 0},
            {"csv", "samples/chain/" + a.name + "-" + variant + ".csv"}};
}

Json Runner::runChain(const AdapterInfo& a, int hops) {
    const std::string variant = a.variants.front();
    Json c = chainRecord(a, hops);
    const std::string csvRel = c["csv"];
    if (!a.chain) {
        c["status"] = "skipped";
        c["reason"] = "pnp-mw-" + a.name + " has no chain test (info: chain false)";
        return c;
    }
    const auto t0 = std::chrono::steady_clock::now();
    fs::create_directories(out_ / "samples" / "chain");
    fs::create_directories(out_ / "logs" / "chain");
    const Site site;
    Peer peer = startPeer(a, site, "chain/" + a.name);
    const int streams = s_.chainStreams;
    const int domain = nextDomain();
    std::string note;
    std::vector<std::unique_ptr<Process>> nodes;
    int base = 0;
    auto startNodes = [&](int first, int count, int hopsNow) {
        for (const auto& n : nodes) n->pump();  // chatty nodes must not block on a full pipe
        Spawn sp;
        sp.argv = {a.exe,       "node",
                   "--first",   std::to_string(first),
                   "--count",   std::to_string(count),
                   "--streams", std::to_string(streams),
                   "--hops",    std::to_string(hopsNow)};
        auto ad = addressing(a, variant, site.serverAddr, site.serverAddr, base, peer, domain,
                             s_.serverCpu);
        sp.argv.insert(sp.argv.end(), ad.begin(), ad.end());
        sp.log = log("chain/" + a.name + "-" + variant + "-nodes" + std::to_string(first) + ".log");
        sp.env = env(a, site.serverAddr, peer);
        auto p = Process::start(sp);
        std::string error;
        // Bounded by the node count: a middleware registering each node takes its time.
        if (!p->waitForLine("READY", std::chrono::seconds(30 + count), error)) {
            checkStop();
            throw std::runtime_error("chain nodes " + std::to_string(first) + ".." +
                                     std::to_string(first + count - 1) + " not ready: " + error);
        }
        nodes.push_back(std::move(p));
    };
    const int perProcess = std::min(nodesPerProcess(a.name), streams * hops);
    base = usesPort(a) ? freePortRange(streams * hops + 3) : 0;
    // Probe: the first process's resident memory per node, against what is available.
    startNodes(0, perProcess, hops);
    std::this_thread::sleep_for(300ms);
    ResourceSampler probe;
    probe.add("nodes", {nodes.front()->pid()});
    probe.sample();
    const long perNodeKib = std::max(1L, probe.usage("nodes").rssKibMax / perProcess);
    const long availKib = memInfoKib("MemAvailable");
    const long budgetKib = availKib * 6 / 10;  // leave room for the client, broker and the rest
    if (perNodeKib * streams * hops > budgetKib) {
        const int fit = static_cast<int>(budgetKib / perNodeKib / streams);
        const int newHops = std::max(1, std::min(hops, fit));
        note = "a node takes ~" + std::to_string(perNodeKib) + " KiB resident (probe of " +
               std::to_string(perProcess) + " nodes); " + std::to_string(streams * hops) +
               " nodes need ~" + std::to_string(perNodeKib * streams * hops / 1024) +
               " MiB, more than 60 % of MemAvailable (" + std::to_string(availKib / 1024) +
               " MiB): hops reduced from " + std::to_string(hops) + " to " +
               std::to_string(newHops);
        say("chain " + a.name + ": " + note);
        hops = newHops;
        nodes.clear();
        base = usesPort(a) ? freePortRange(streams * hops + 3) : 0;
        startNodes(0, std::min(perProcess, streams * hops), hops);
    }
    const int total = streams * hops;
    for (int first = static_cast<int>(perProcess); first < total; first += perProcess) {
        checkStop();
        startNodes(first, std::min(perProcess, total - first), hops);
    }
    c["hops"] = hops;
    c["nodes"] = total;
    c["processes"] = nodes.size();
    c["note"] = note;
    Spawn cs;
    cs.argv = {a.exe,
               "client",
               "--mode",
               "chain",
               "--streams",
               std::to_string(streams),
               "--hops",
               std::to_string(hops),
               "--runs",
               std::to_string(s_.chainRuns),
               "--chain-payload",
               std::to_string(s_.chainPayload),
               "--timeout-ms",
               "30000",
               "--csv",
               (out_ / csvRel).string(),
               "--set",
               "sink-host=" + site.clientAddr};
    auto ad =
        addressing(a, variant, site.serverAddr, site.clientAddr, base, peer, domain, s_.clientCpu);
    cs.argv.insert(cs.argv.end(), ad.begin(), ad.end());
    cs.log = log("chain/" + a.name + "-" + variant + "-client.log");
    cs.env = env(a, site.clientAddr, peer);
    ResourceSampler rs;
    std::vector<pid_t> nodePids;
    for (const auto& n : nodes) nodePids.push_back(n->pid());
    rs.add("nodes", nodePids);
    auto client = Process::start(cs);
    rs.sample();
    const auto deadline = std::chrono::steady_clock::now() + 120s + s_.chainRuns * 5s;
    bool timedOut = false;
    for (;;) {
        client->pump();
        if (client->exitedUnreaped()) break;
        if (stopRequested()) throw Interrupted();
        if (std::chrono::steady_clock::now() >= deadline) {
            timedOut = true;
            break;
        }
        std::this_thread::sleep_for(100ms);
        for (const auto& n : nodes) n->pump();
        rs.sample();
    }
    client->stop(1000ms);
    client->pump();
    c["rss_kib_total"] = rs.rssKibTotalMax();
    for (const auto& l : client->lines()) {
        if (l.empty() || l.front() != '{') continue;
        try {
            const Json j = Json::parse(l);
            if (!j.contains("payload")) continue;
            Json s = summaryOf(j);
            s.erase("payload");
            s.erase("msgs_per_s");
            c["summary"] = s;
        } catch (const std::exception&) {
        }
    }
    std::string reason;
    if (timedOut)
        reason = "chain client did not finish in time";
    else if (client->exitCode() != 0)
        reason = "chain client exit code " + std::to_string(client->exitCode()) + ": " +
                 client->logTail(600);
    else if (c["summary"].is_null() || c["summary"].value("n", 0) <= 0)
        reason = "chain client printed no summary";
    for (const auto& n : nodes)
        if (n->exited())
            reason += std::string(reason.empty() ? "" : "; ") + "a node process exited (code " +
                      std::to_string(n->exitCode()) + "): " + n->logTail(300);
    nodes.clear();  // stops them
    c["status"] = reason.empty() ? "ok" : "failed";
    c["reason"] = reason;
    std::ostringstream line;
    line.precision(1);
    line << std::fixed << "chain " << a.name << "/" << variant << " (" << total << " nodes, "
         << c["processes"].get<int>() << " processes): " << (reason.empty() ? "ok" : "FAILED")
         << " (" << std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()
         << " s) ";
    if (reason.empty())
        line << "median " << c["summary"].value("median_us", 0.0) << " us, nodes' RSS "
             << rs.rssKibTotalMax() / 1024 << " MiB";
    else
        line << reason.substr(0, 300);
    say(line.str());
    return c;
}

// The chain at the configured size; when it fails (Fast DDS's discovery gives up at a few
// hundred participants, as in the thesis), again with a fifth of the hops until one works:
// the report gives the largest N that routed, and why the larger ones did not.
Json Runner::runChainLargestThatWorks(const AdapterInfo& a) {
    std::string failures;
    for (int hops = s_.chainHops;; hops /= 5) {
        checkStop();
        Json c;
        try {
            c = runChain(a, hops);
        } catch (const Interrupted&) {
            throw;
        } catch (const std::exception& e) {
            c = chainRecord(a, hops);
            c["reason"] = e.what();
            say("chain " + a.name + ": FAILED " + e.what());
        }
        const bool ok = c.value("status", "") == "ok";
        if (!failures.empty()) {
            const std::string note = c.value("note", "");
            c["note"] = failures + (note.empty() ? "" : "; " + note);
        }
        if (ok || hops / 5 < 1 || options_.quick) return c;
        failures += std::string(failures.empty() ? "" : "; ") + "with " +
                    std::to_string(s_.chainStreams * hops) +
                    " nodes: " + c.value("reason", "failed").substr(0, 200) + " - so " +
                    std::to_string(s_.chainStreams * (hops / 5)) + " nodes were tried";
        say("chain " + a.name + ": trying " + std::to_string(s_.chainStreams * (hops / 5)) +
            " nodes");
    }
}

Json Runner::runOverhead(const AdapterInfo& a, const std::string& variant) {
    Json o = {{"adapter", a.name},
              {"variant", variant},
              {"status", "failed"},
              {"reason", ""},
              {"method", ""},
              {"per_message", Json::array()},
              {"connection_bytes", nullptr}};
    const std::string dumpcap = findExecutable("dumpcap");
    if (dumpcap.empty()) {
        o["status"] = "skipped";
        o["reason"] = "dumpcap (tshark) not installed";
        return o;
    }
    const auto t0 = std::chrono::steady_clock::now();
    const int k = s_.overheadReps;
    o["method"] =
        "client in a network namespace of its own, server (and broker / master) in another, "
        "joined by an unshaped veth pair; `dumpcap -i <client veth> -s 128 -P` around "
        "each client run, so that only the client's traffic is captured (not the broker's "
        "traffic to the server); TCP payload (IP length - IP and TCP headers) and UDP payload "
        "(udp.length - 8, first fragments) summed per direction (request: from the client's "
        "address; response: everything else it receives, including multicast). The ACK client "
        "runs with K = " +
        std::to_string(k) +
        " and 2K requests (no warm-up) per payload on a fresh connection: "
        "per message = (bytes(2K) - bytes(K)) / K; connection = bytes(K, payload 0) - K x per "
        "message(payload 0) (set-up, discovery and tear-down, as seen from the client)";
    fs::create_directories(out_ / "logs" / "overhead");
    NetPairConfig nc;
    nc.name = "pnpmw" + std::to_string(::getpid());
    nc.shape = false;
    nc.log = log("overhead/netns.log");
    NetPair net(nc);
    const Site site{net.serverNs(), net.clientNs(), NetPair::kServerAddr, NetPair::kClientAddr};
    const std::string tag = "overhead/" + a.name + "-" + variant;
    Peer peer = startPeer(a, site, tag);
    const int port = usesPort(a) ? freePort() : 0;
    const int domain = nextDomain();
    std::string error;
    auto server = startServer(a, variant, "ack", site, peer, port, domain, -1, tag, error);
    if (!server) {
        o["reason"] = error;
        return o;
    }
    // One capture around one client run. A capture that dropped packets is marked.
    struct Captured {
        long request = 0, response = 0;
        bool complete = true;
    };
    int attemptNo = 0;
    auto capture = [&](std::size_t payload, int reps) -> Captured {
        const std::string name = tag + "-" + std::to_string(payload) + "-" + std::to_string(reps) +
                                 "-" + std::to_string(attemptNo);
        const std::string pcap = log(name + ".pcap");
        Spawn dc;
        dc.argv = {dumpcap, "-q", "-i", net.clientDev(), "-s", "128", "-P", "-w", pcap};
        dc.log = log(name + "-dumpcap.log");
        dc.captureStdout = false;
        dc.netns = site.clientNs;
        auto cap = Process::start(dc);
        // dumpcap says "Capturing on ..." once it captures.
        const auto until = std::chrono::steady_clock::now() + 15s;
        while (cap->logTail().find("Capturing on") == std::string::npos) {
            checkStop();
            if (cap->exited() || std::chrono::steady_clock::now() >= until)
                throw std::runtime_error("dumpcap did not start: " + cap->logTail(300));
            std::this_thread::sleep_for(50ms);
        }
        std::this_thread::sleep_for(200ms);
        Spawn cs;
        cs.argv = {a.exe, "client", "--mode", "ack"};
        auto cad = addressing(a, variant, site.serverAddr, site.clientAddr, port, peer, domain, -1);
        cs.argv.insert(cs.argv.end(), cad.begin(), cad.end());
        const std::vector<std::string> opts = {
            "--reps",  std::to_string(reps),    "--warmup",     "0",
            "--sizes", std::to_string(payload), "--timeout-ms", "10000"};
        cs.argv.insert(cs.argv.end(), opts.begin(), opts.end());
        cs.log = log(name + "-client.log");
        cs.netns = site.clientNs;
        cs.env = env(a, site.clientAddr, peer);
        auto client = Process::start(cs);
        const auto deadline = std::chrono::steady_clock::now() + 120s;
        while (!client->exited()) {
            client->pump();
            if (stopRequested()) throw Interrupted();
            if (std::chrono::steady_clock::now() >= deadline) {
                client->stop(500ms);
                throw std::runtime_error("overhead client did not finish within 120 s");
            }
            std::this_thread::sleep_for(20ms);
            server->pump();
        }
        if (client->exitCode() != 0)
            throw std::runtime_error("overhead client exit code " +
                                     std::to_string(client->exitCode()) + ": " +
                                     client->logTail(400));
        std::this_thread::sleep_for(500ms);  // the tear-down's last segments
        cap->stop(5000ms);
        const Traffic t = readPcap(pcap, NetPair::kClientAddr);
        Captured c{t.requestBytes, t.responseBytes, true};
        // "Packets received/dropped on interface 'X': 609/0 (...)"
        const std::string stats = cap->logTail(2000);
        const auto at = stats.find("received/dropped");
        if (at == std::string::npos) {
            c.complete = false;
        } else {
            const auto slash = stats.find('/', stats.find("':", at));
            c.complete = slash != std::string::npos && stats.compare(slash, 3, "/0 ") == 0;
        }
        return c;
    };
    try {
        long connection = -1;
        for (std::size_t payload :
             {std::size_t{0}, std::size_t{100}, std::size_t{1000}, std::size_t{10000}}) {
            // A capture with drops, or a result below the payload itself, is taken again.
            double req = 0, resp = 0;
            Captured once, twice;
            for (attemptNo = 0; attemptNo < 3; ++attemptNo) {
                once = capture(payload, k);
                twice = capture(payload, 2 * k);
                req = static_cast<double>(twice.request - once.request) / k;
                resp = static_cast<double>(twice.response - once.response) / k;
                const double conn =
                    static_cast<double>(once.request + once.response) - k * (req + resp);
                if (once.complete && twice.complete && req >= static_cast<double>(payload) &&
                    resp >= 0 && conn >= 0)
                    break;
                say("overhead " + a.name + "/" + variant + ": payload " + std::to_string(payload) +
                    " measured again (" +
                    (once.complete && twice.complete ? "implausible" : "capture dropped packets") +
                    ")");
            }
            if (attemptNo == 3)
                throw std::runtime_error("payload " + std::to_string(payload) +
                                         ": no plausible capture in 3 attempts");
            o["per_message"].push_back({{"payload", payload},
                                        {"request_bytes", round1(req)},
                                        {"response_bytes", round1(resp)}});
            if (payload == 0)
                connection = std::lround(static_cast<double>(once.request + once.response) -
                                         k * (req + resp));
        }
        o["connection_bytes"] = connection;
        o["status"] = "ok";
    } catch (const Interrupted&) {
        throw;
    } catch (const std::exception& e) {
        o["reason"] = e.what();
    }
    server->stop();
    if (peer.proc) peer.proc->stop();
    std::ostringstream line;
    line.precision(1);
    line << std::fixed << "overhead " << a.name << "/" << variant << ": "
         << (o["status"] == "ok" ? "ok" : "FAILED") << " ("
         << std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() << " s)";
    if (o["status"] == "ok") {
        for (const auto& m : o["per_message"])
            line << " " << m["payload"].get<int>() << "B:" << m["request_bytes"].get<double>()
                 << "/" << m["response_bytes"].get<double>();
        line << " connection " << o["connection_bytes"].get<long>() << " B";
    } else {
        line << " " << o["reason"].get<std::string>().substr(0, 300);
    }
    say(line.str());
    return o;
}

fs::path Runner::run() {
    start_ = std::chrono::steady_clock::now();
    settle();
    out_ = options_.out;
    fs::create_directories(out_ / "logs");
    fs::create_directories(out_ / "samples");
    for (const auto& n : removeStaleNamespaces(log("netns-cleanup.log")))
        say("removed the namespace " + n + " left by a runner that no longer runs");
    summary_ = {{"version", 1},
                {"started", isoNow()},
                {"finished", nullptr},
                {"duration_s", 0},
                {"quick", options_.quick},
                {"machine", machine()},
                {"adapters", Json::array()},
                {"runs", Json::array()},
                {"chain", Json::array()},
                {"overhead", Json::array()}};
    Json cpus = nullptr;
    if (s_.clientCpu >= 0) cpus = {{"client", s_.clientCpu}, {"server", s_.serverCpu}};
    summary_["settings"] = {
        {"reps", s_.reps},
        {"reps_under_load", s_.repsUnderLoad},
        {"warmup", s_.warmup},
        {"sizes", s_.sizes},
        {"placement", s_.placement},
        {"cpus", cpus},
        {"resting_seconds", s_.restingSeconds},
        {"resting_max_pause_s", s_.restingMaxPause},
        {"run_budget_s", {{"idle", s_.runBudgetIdle}, {"load", s_.runBudgetLoad}}},
        {"min_reps", s_.minReps},
        {"loads", s_.loads},
        {"modes", s_.modes},
        {"cpu_load", ""},
        {"net_load", ""},
        {"chain", options_.chain},
        {"overhead", options_.overhead && !options_.quick}};
    discover();
    int variants = 0;
    for (const auto& a : adapters_)
        if (a.ok) variants += static_cast<int>(a.variants.size());
    runTotal_ = variants * static_cast<int>(s_.modes.size() * s_.loads.size());
    save();
    try {
        for (const auto& load : s_.loads) {
            checkStop();
            say("== load " + load);
            try {
                runLoad(load);
            } catch (const Interrupted&) {
                throw;
            } catch (const std::exception& e) {
                say("load " + load + " failed: " + e.what());
                for (const auto& a : adapters_)
                    if (a.ok)
                        for (const auto& v : a.variants)
                            for (const auto& m : s_.modes) {
                                bool have = false;
                                for (const auto& r : summary_["runs"])
                                    have = have || (r["adapter"] == a.name && r["variant"] == v &&
                                                    r["mode"] == m && r["load"] == load);
                                if (!have)
                                    summary_["runs"].push_back(
                                        {{"adapter", a.name},
                                         {"variant", v},
                                         {"mode", m},
                                         {"load", load},
                                         {"status", "failed"},
                                         {"reason", std::string("load set-up: ") + e.what()},
                                         {"csv", ""},
                                         {"sizes", Json::array()},
                                         {"resources", nullptr}});
                            }
            }
            save();
        }
        if (options_.chain) {
            say("== chain");
            for (const auto& a : adapters_) {
                if (!a.ok) continue;
                checkStop();
                summary_["chain"].push_back(runChainLargestThatWorks(a));
                save();
            }
        }
        if (options_.overhead && !options_.quick) {
            say("== package overhead");
            for (const auto& a : adapters_) {
                if (!a.ok) continue;
                for (const auto& v : a.variants) {
                    checkStop();
                    Json o;
                    try {
                        o = runOverhead(a, v);
                    } catch (const Interrupted&) {
                        throw;
                    } catch (const std::exception& e) {
                        o = {{"adapter", a.name},
                             {"variant", v},
                             {"status", "failed"},
                             {"reason", e.what()},
                             {"per_message", Json::array()},
                             {"connection_bytes", nullptr}};
                        say("overhead " + a.name + "/" + v + ": FAILED " + e.what());
                    }
                    summary_["overhead"].push_back(o);
                    save();
                }
            }
        }
    } catch (const Interrupted&) {
        summary_["interrupted"] = true;
        save();
        throw;
    }
    save();
    return out_ / "summary.json";
}

}  // namespace

void installStopHandlers() {
    struct sigaction sa {};
    sa.sa_handler = onStopSignal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = 0;  // no SA_RESTART: a blocking call returns and the loop sees the flag
    ::sigaction(SIGINT, &sa, nullptr);
    ::sigaction(SIGTERM, &sa, nullptr);
}

fs::path run(const Options& options) {
    Runner r(options);
    return r.run();
}

}  // namespace pnp::bench::runner
