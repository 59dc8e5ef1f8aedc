// pnp_bench: the benchmark driver (see bench/README.md). One run prints
//   (a) Write of a ByteString (2 B ... 32 KiB) to the demo variable: median / p99 round trip,
//       next to a raw TCP echo of the same payload, and the ratio OPC UA / raw;
//   (b) the same for Call Demo.Echo(ByteString);
//   (c) client start -> first Read, in-process (top of main) and spawn -> result;
//   (d) the idle server: VmRSS after a session came and went, spawn -> accepting;
//   (e) a value change in the server -> the data-change callback of a subscriber, next to a
//       raw round trip interleaved with the changes, with the CPUs idle and kept busy.
// Server, raw echo server and clients are separate processes, pinned to CPUs (same core by
// default, like `taskset -c 0`). Every wait is bounded; every child is stopped by its PID.
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <spawn.h>
#include <sys/utsname.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cinttypes>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"
#include "ua/types/ns0_ids.hpp"

extern char** environ;

namespace pnp::bench {
namespace {

using namespace std::chrono_literals;
namespace ua = pnp::ua;

// ---- options ------------------------------------------------------------------------------
struct Options {
    std::vector<std::size_t> sizes;  // default: 2, 4, ..., 32768
    std::size_t iterations = 2000;   // measured round trips per size, each of OPC UA and raw
    std::size_t warmup = 200;        // per size, each of OPC UA and raw
    std::size_t block = 100;         // OPC UA and raw alternate in blocks of this many
    std::size_t startRuns = 30;      // (c)
    std::size_t listenRuns = 10;     // (d)
    int tickMs = 15;                 // (e): a value change every tickMs
    int serverCpu = 0;
    int clientCpu = 0;
    bool realtime = false;        // SCHED_FIFO for every benchmark process (decided in run())
    std::string server = "auto";  // auto | pnp | bench
    std::string pnpExe;           // `pnp` binary
    std::string helperDir;        // pnp_bench_* binaries
    std::string jsonPath;
    std::string sections = "abcde";
    bool quiet = false;
    bool skipRaw = false;   // profiling: OPC UA round trips only
    int realtimeMode = -1;  // -1 auto, 0 off, 1 on
};

void usage() {
    std::printf(
        "usage: pnp_bench [options]\n"
        "  --placement same|split  same: server and clients on CPU 0 (default, = taskset -c 0)\n"
        "                          split: server on CPU 0, clients on CPU 1\n"
        "  --server-cpu N --client-cpu N   explicit CPUs (-1: not pinned)\n"
        "  --server auto|pnp|bench OPC UA server for (a)-(c): `pnp ua serve` (auto: if built)\n"
        "                          or pnp_bench_server; (d) measures every available one\n"
        "  --iterations N          measured round trips per size (default 2000, minimum 100)\n"
        "  --warmup N              warm-up round trips per size (default 200)\n"
        "  --sizes 2,4,...         payload sizes in bytes (default 2..32768, powers of two)\n"
        "  --start-runs N          runs of (c) (default 30)\n"
        "  --listen-runs N         runs of (d) (default 10)\n"
        "  --tick-ms N             (e): a value change every N ms (default 15; 2..1000)\n"
        "  --only abcde            sections to run (default abcde; e: value change -> data-change\n"
        "                          callback of a subscription)\n"
        "  --realtime | --no-realtime\n"
        "                          SCHED_FIFO (priority 10) for every benchmark process, or not.\n"
        "                          Default (auto): on when running as root and the 1-minute load\n"
        "                          average exceeds 1, i.e. other work competes for the CPUs\n"
        "  --json PATH             also write the JSON result to PATH\n"
        "  --pnp PATH              the `pnp` executable\n");
}

// ---- child processes ------------------------------------------------------------------------
// PIDs of running children, for the signal handler (stop them when we are interrupted).
constexpr int kMaxChildren = 16;
std::atomic<pid_t> gChildren[kMaxChildren];

void registerChild(pid_t pid) {
    for (auto& c : gChildren) {
        pid_t expected = 0;
        if (c.compare_exchange_strong(expected, pid)) return;
    }
}
void unregisterChild(pid_t pid) {
    for (auto& c : gChildren) {
        pid_t expected = pid;
        if (c.compare_exchange_strong(expected, 0)) return;
    }
}
extern "C" void onSignal(int sig) {
    for (auto& c : gChildren) {
        pid_t p = c.load();
        if (p > 0) ::kill(p, SIGKILL);
    }
    ::signal(sig, SIG_DFL);
    ::raise(sig);
}

// Spawns argv with posix_spawn (vfork-like: the cost does not depend on our size). The child
// inherits the calling thread's CPU affinity, so the caller pins itself to `cpu` around the
// spawn. stdout -> a pipe (returned), stderr -> `stderrPath` ("" = inherit).
struct Spawned {
    pid_t pid = -1;
    int out = -1;  // read end of the child's stdout
    std::int64_t spawnNs = 0;
};

Spawned spawnProcess(const std::vector<std::string>& argv, int cpu, bool realtime,
                     const std::string& stderrPath) {
    int fds[2];
    if (::pipe2(fds, O_CLOEXEC) != 0) fail("pipe2");
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, fds[1], 1);
    if (!stderrPath.empty())
        posix_spawn_file_actions_addopen(&fa, 2, stderrPath.c_str(), O_WRONLY | O_CREAT | O_TRUNC,
                                         0644);
    posix_spawnattr_t attr;
    posix_spawnattr_init(&attr);
    short flags = 0;
    if (realtime) {
        sched_param sp{};
        sp.sched_priority = 10;
        posix_spawnattr_setschedpolicy(&attr, SCHED_FIFO);
        posix_spawnattr_setschedparam(&attr, &sp);
        flags |= POSIX_SPAWN_SETSCHEDULER;
    }
    posix_spawnattr_setflags(&attr, flags);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);

    cpu_set_t saved;
    CPU_ZERO(&saved);
    sched_getaffinity(0, sizeof saved, &saved);
    if (cpu >= 0) pinToCpu(cpu);
    Spawned s;
    s.spawnNs = nowNs();
    int rc = posix_spawn(&s.pid, args[0], &fa, &attr, args.data(), environ);
    sched_setaffinity(0, sizeof saved, &saved);
    posix_spawn_file_actions_destroy(&fa);
    posix_spawnattr_destroy(&attr);
    ::close(fds[1]);
    if (rc != 0) {
        ::close(fds[0]);
        errno = rc;
        fail("cannot start " + argv[0]);
    }
    registerChild(s.pid);
    s.out = fds[0];
    return s;
}

// Reads one line from fd until `timeout` passes. nullopt on timeout or EOF.
std::optional<std::string> readLine(int fd, std::chrono::milliseconds timeout) {
    auto deadline = Clock::now() + timeout;
    std::string line;
    for (;;) {
        auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
        if (left.count() < 0) return std::nullopt;
        pollfd p{fd, POLLIN, 0};
        int r = ::poll(&p, 1, static_cast<int>(left.count()) + 1);
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) return std::nullopt;
        char c;
        ssize_t n = ::read(fd, &c, 1);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) return std::nullopt;
        if (c == '\n') return line;
        line.push_back(c);
        if (line.size() > 4096) return std::nullopt;
    }
}

// Waits (bounded) for the child to exit; returns its wait status or -1 on timeout.
int waitExit(pid_t pid, std::chrono::milliseconds timeout) {
    auto deadline = Clock::now() + timeout;
    for (;;) {
        int st = 0;
        pid_t r = ::waitpid(pid, &st, WNOHANG);
        if (r == pid) return st;
        if (r < 0 && errno != EINTR) return 0;  // already reaped
        if (Clock::now() >= deadline) return -1;
        std::this_thread::sleep_for(200us);
    }
}

// SIGTERM, then SIGKILL after 3 s.
void stopProcess(Spawned& s) {
    if (s.pid <= 0) return;
    ::kill(s.pid, SIGTERM);
    if (waitExit(s.pid, 3000ms) == -1) {
        ::kill(s.pid, SIGKILL);
        ::waitpid(s.pid, nullptr, 0);
    }
    unregisterChild(s.pid);
    s.pid = -1;
    if (s.out >= 0) ::close(s.out);
    s.out = -1;
}

// A running server process (OPC UA or raw echo): started, its "listening on ..." line read.
class ServerProcess {
  public:
    ServerProcess(std::string name, std::vector<std::string> argv, int cpu, bool realtime)
        : name_(std::move(name)) {
        logPath_ = "/tmp/pnp_bench_" + std::to_string(::getpid()) + "_" + name_ + ".log";
        proc_ = spawnProcess(argv, cpu, realtime, logPath_);
        auto line = readLine(proc_.out, 10s);
        lineNs_ = nowNs();
        if (!line || line->rfind("listening on ", 0) != 0) {
            stopProcess(proc_);
            throw std::runtime_error(name_ + " did not report \"listening on ...\" within 10 s (" +
                                     (line ? "got \"" + *line + "\"" : "no line") + "; see " +
                                     logPath_ + ")");
        }
        endpoint_ = line->substr(13);
        auto colon = endpoint_.rfind(':');
        std::string p = endpoint_.substr(colon + 1);
        auto slash = p.find('/');
        if (slash != std::string::npos) p = p.substr(0, slash);
        port_ = static_cast<std::uint16_t>(std::stoi(p));
    }
    ~ServerProcess() {
        stopProcess(proc_);
        ::unlink(logPath_.c_str());
    }
    ServerProcess(const ServerProcess&) = delete;
    ServerProcess& operator=(const ServerProcess&) = delete;

    // Stops the process (SIGTERM) and returns what it wrote on stderr.
    std::string stopAndReadLog() {
        stopProcess(proc_);
        std::ifstream in(logPath_);
        return std::string(std::istreambuf_iterator<char>(in), {});
    }

    pid_t pid() const { return proc_.pid; }
    std::uint16_t port() const { return port_; }
    std::int64_t spawnNs() const { return proc_.spawnNs; }
    std::int64_t lineNs() const { return lineNs_; }
    const std::string& endpoint() const { return endpoint_; }

  private:
    std::string name_;
    std::string logPath_;
    Spawned proc_;
    std::int64_t lineNs_ = 0;
    std::string endpoint_;
    std::uint16_t port_ = 0;
};

struct ServerKind {
    std::string label;  // "pnp ua serve", "pnp_bench_server"
    std::vector<std::string> argv;
};

std::string opcUrl(std::uint16_t port) { return "opc.tcp://127.0.0.1:" + std::to_string(port); }

// /proc/<pid>/status fields in kB.
std::map<std::string, long> procStatus(pid_t pid) {
    std::ifstream f("/proc/" + std::to_string(pid) + "/status");
    std::map<std::string, long> r;
    std::string line;
    while (std::getline(f, line)) {
        for (const char* k : {"VmRSS", "VmHWM", "RssAnon", "RssFile", "RssShmem", "Threads"}) {
            std::string key = std::string(k) + ":";
            if (line.rfind(key, 0) == 0) r[k] = std::strtol(line.c_str() + key.size(), nullptr, 10);
        }
    }
    return r;
}

// ---- (a), (b): round trips -----------------------------------------------------------------
struct RttRow {
    std::size_t bytes = 0;
    Summary ua, raw;
};

// One raw echo round trip of `frame` (4-byte length + payload); returns ns.
class RawClient {
  public:
    explicit RawClient(std::uint16_t port) {
        fd_ = connectLoopback(port);
        if (fd_ < 0) fail("connect to the raw echo server");
    }
    ~RawClient() {
        if (fd_ >= 0) ::close(fd_);
    }
    void prepare(std::size_t n, unsigned char seed) {
        frame_.resize(4 + n);
        std::uint32_t len = static_cast<std::uint32_t>(n);
        std::memcpy(frame_.data(), &len, 4);
        for (std::size_t i = 0; i < n; ++i)
            frame_[4 + i] = static_cast<unsigned char>(seed + i * 7);
        reply_.assign(4 + n, 0);
    }
    double roundTrip(bool verify) {
        std::int64_t t0 = nowNs();
        if (!sendAll(fd_, frame_.data(), frame_.size())) fail("raw echo: send");
        long n = recvFrame(fd_, reply_, frame_.size() - 4);
        std::int64_t t1 = nowNs();
        if (n != static_cast<long>(frame_.size() - 4))
            throw std::runtime_error("raw echo: bad reply");
        if (verify && std::memcmp(reply_.data(), frame_.data(), frame_.size()) != 0)
            throw std::runtime_error("raw echo: payload differs");
        return static_cast<double>(t1 - t0);
    }
    // One-way latencies (ns) of `count` timestamps the echo server sends every `periodMs`
    // (its TICK request): sender's clock before send() -> here after the receive.
    std::vector<double> ticks(std::uint32_t periodMs, std::uint32_t count) {
        unsigned char req[16] = {12, 0, 0, 0, 'T', 'I', 'C', 'K'};
        std::memcpy(req + 8, &periodMs, 4);
        std::memcpy(req + 12, &count, 4);
        if (!sendAll(fd_, req, sizeof req)) fail("raw echo: send TICK");
        std::vector<double> out;
        std::vector<unsigned char> frame;
        for (std::uint32_t i = 0; i < count; ++i) {
            if (recvFrame(fd_, frame, 8) != 8) throw std::runtime_error("raw echo: bad tick");
            const std::int64_t t1 = nowNs();
            std::int64_t t0 = 0;
            std::memcpy(&t0, frame.data() + 4, 8);
            out.push_back(static_cast<double>(t1 - t0));
        }
        return out;
    }

  private:
    int fd_ = -1;
    std::vector<unsigned char> frame_;
    std::vector<unsigned char> reply_;
};

ua::ByteString payload(std::size_t n, unsigned char seed) {
    std::string s(n, '\0');
    for (std::size_t i = 0; i < n; ++i) s[i] = static_cast<char>(seed + i * 7);
    return ua::ByteString(std::move(s));
}

// One OPC UA round trip; the argument objects are built before the clock starts.
using UaOp = std::function<double(const ua::ByteString& value, bool verify)>;

RttRow measureSize(std::size_t n, const Options& o, RawClient& raw, const UaOp& uaOp) {
    RttRow row;
    row.bytes = n;
    unsigned char seed = static_cast<unsigned char>(n * 31 + 5);
    ua::ByteString value = payload(n, seed);
    raw.prepare(n, seed);
    for (std::size_t i = 0; i < o.warmup; ++i) {
        if (!o.skipRaw) raw.roundTrip(i == 0);
        uaOp(value, i == 0);
    }
    std::vector<double> uaNs, rawNs;
    uaNs.reserve(o.iterations);
    rawNs.reserve(o.iterations);
    // Alternate blocks so that both see the same machine state (other load, frequency).
    while (uaNs.size() < o.iterations) {
        std::size_t k = std::min(o.block, o.iterations - uaNs.size());
        if (!o.skipRaw)
            for (std::size_t i = 0; i < k; ++i) rawNs.push_back(raw.roundTrip(i == 0));
        for (std::size_t i = 0; i < k; ++i) uaNs.push_back(uaOp(value, i == 0));
    }
    for (auto* v : {&uaNs, &rawNs})
        for (double& x : *v) x /= 1000.0;  // µs
    row.ua = summarize(uaNs);
    row.raw = summarize(rawNs);
    return row;
}

// ---- output helpers -------------------------------------------------------------------------
std::string num(double v, int decimals = 3) {
    if (!std::isfinite(v)) return "null";
    char b[64];
    std::snprintf(b, sizeof b, "%.*f", decimals, v);
    return b;
}
std::string jstr(const std::string& s) {
    std::string r = "\"";
    for (char c : s) {
        if (c == '"' || c == '\\') r += '\\';
        if (static_cast<unsigned char>(c) < 0x20) {
            r += ' ';
            continue;
        }
        r += c;
    }
    return r + "\"";
}

// ---- (e) value change in the server -> data-change callback in the client ----------------
struct ValueChangeRun {
    bool busyCores = false;
    Summary change, raw, rawBackToBack, rawTick;
    double serverSetValueUs = -1;  // median, from the server's log; -1: not reported
};

// The CPUs section (e) runs on: the pinned ones, or all of them when not pinned.
std::vector<int> benchmarkCpus(const Options& o) {
    std::vector<int> cpus;
    if (o.serverCpu < 0 || o.clientCpu < 0) {
        for (unsigned i = 0; i < std::max(1u, std::thread::hardware_concurrency()); ++i)
            cpus.push_back(static_cast<int>(i));
        return cpus;
    }
    cpus.push_back(o.serverCpu);
    if (o.clientCpu != o.serverCpu) cpus.push_back(o.clientCpu);
    return cpus;
}

ValueChangeRun measureValueChange(const Options& o, const std::string& echoExe, bool busyCores) {
    ValueChangeRun res;
    res.busyCores = busyCores;
    std::optional<BusyCores> busy;
    if (busyCores) busy.emplace(benchmarkCpus(o));
    // Changes every kTickMs (default 15) > the publishing interval: none waits for a cycle.
    const int kTickMs = o.tickMs;
    const double publishingMs = kTickMs > 10 ? 10.0 : std::max(1.0, kTickMs - 1.0);
    const std::size_t changes = std::max<std::size_t>(200, o.iterations / 4);
    const std::size_t warm = 20;
    ServerProcess ticker("ticker",
                         {o.helperDir + "/pnp_bench_server", "--host", "127.0.0.1", "--port", "0",
                          "--ticker", std::to_string(kTickMs)},
                         o.serverCpu, o.realtime);
    ServerProcess echoServer("echo", {echoExe, "--port", "0", "--max-payload", "64"}, o.serverCpu,
                             o.realtime);
    RawClient raw(echoServer.port());
    raw.prepare(8, 3);
    // The baseline, interleaved with the changes so that both see the same machine state
    // (it drifts by tens of µs within minutes on a VM): half a period after each change,
    // one raw round trip. Before it, both ends were idle for half a period, as before each
    // change. Information, half before and half after the subscription: back-to-back round
    // trips and one-way ticks from a thread of the echo server every kTickMs (the raw analog
    // of the measured path, but minutes away from it).
    std::vector<double> rawNs, pacedNs, tickNs, changeNs;
    std::vector<std::int64_t> changeAt;  // when each callback ran
    auto information = [&] {
        for (std::size_t i = 0; i < o.iterations / 2; ++i) rawNs.push_back(raw.roundTrip(false));
        auto t = raw.ticks(kTickMs, static_cast<std::uint32_t>(changes / 2 + 2));
        tickNs.insert(tickNs.end(), t.begin() + 2, t.end());
    };
    for (std::size_t i = 0; i < o.warmup; ++i) raw.roundTrip(false);
    information();
    {
        ua::client::Client client;
        client.connect(opcUrl(ticker.port()));
        const ua::NodeId tickerId(client.namespaceIndex("urn:pnp:demo"), "Bench.Ticker");
        std::mutex m;
        std::condition_variable cv;
        changeNs.reserve(changes + warm);
        changeAt.reserve(changes + warm);
        ua::client::Subscription sub(client, {.publishingInterval = publishingMs});
        ua::client::MonitoredItem item = sub.monitorValue(
            tickerId,
            [&](const ua::DataValue& v) {
                const std::int64_t now = nowNs();
                const ua::Int64* t = v.value ? v.value->scalar<ua::Int64>() : nullptr;
                if (t == nullptr || *t == 0) return;  // the initial value
                std::lock_guard lock(m);
                changeNs.push_back(static_cast<double>(now - *t));
                changeAt.push_back(now);
                cv.notify_all();
            },
            {.samplingInterval = 0});
        client.startBackgroundThread();
        const auto giveUp = std::chrono::steady_clock::now() +
                            std::chrono::milliseconds(kTickMs * (changes + warm) * 3 + 5000);
        std::unique_lock lock(m);
        bool complete = true;
        for (std::size_t seen = 0; seen < changes + warm; ++seen) {
            if (!cv.wait_until(lock, giveUp, [&] { return changeNs.size() > seen; })) {
                complete = false;
                break;
            }
            const std::int64_t halfway = changeAt[seen] + kTickMs * 500'000LL;
            lock.unlock();
            std::this_thread::sleep_for(std::chrono::nanoseconds(halfway - nowNs()));
            if (seen >= warm) pacedNs.push_back(raw.roundTrip(false));
            lock.lock();
        }
        lock.unlock();
        client.stopBackgroundThread();
        if (!complete)
            throw std::runtime_error("(e): " + std::to_string(changeNs.size()) + " of " +
                                     std::to_string(changes + warm) +
                                     " value changes arrived in time");
    }
    information();
    // The server's part: its ticker thread times setValue(), which writes the change.
    {
        const std::string log = ticker.stopAndReadLog();
        const auto at = log.find("setValue on the ticker: median ");
        if (at != std::string::npos)
            res.serverSetValueUs = std::strtod(log.c_str() + at + 31, nullptr);
    }
    changeNs.erase(changeNs.begin(), changeNs.begin() + warm);
    for (auto* v : {&changeNs, &rawNs, &pacedNs, &tickNs})
        for (auto& x : *v) x /= 1000.0;
    res.change = summarize(changeNs);
    res.raw = summarize(pacedNs);
    res.rawBackToBack = summarize(rawNs);
    res.rawTick = summarize(tickNs);
    return res;
}

void printValueChange(const Options& o, const ValueChangeRun& r) {
    std::printf(
        "\n(e) value change in the server (setValue, sampling interval 0) -> data-change "
        "callback in the client, CPUs %s\n  (µs; %zu changes every %d ms, Int64 = "
        "CLOCK_MONOTONIC before setValue; raw TCP, 8 bytes: the baseline halfway between the "
        "changes, the information before and after)\n",
        r.busyCores ? "kept busy (SCHED_IDLE spinners: no idle wake-up)"
                    : "idle between changes (information)",
        r.change.n, o.tickMs);
    auto row = [&](const char* label, const Summary& x, bool ratio) {
        std::printf("  %-46s median %7.1f  p99 %7.1f", label, x.median, x.p99);
        if (ratio) std::printf("  | change/this %.2f", r.change.median / x.median);
        std::printf("\n");
    };
    row("change -> callback", r.change, false);
    if (r.serverSetValueUs >= 0)
        std::printf("    of which setValue() in the server (the write included) median %7.1f\n",
                    r.serverSetValueUs);
    const std::string every = " every " + std::to_string(o.tickMs) + " ms";
    row(("raw RTT, one" + every + ", interleaved (baseline)").c_str(), r.raw, true);
    row(("raw one-way tick" + every + " (info)").c_str(), r.rawTick, true);
    row("raw RTT back to back (info)", r.rawBackToBack, true);
    std::printf("  ratio %.2f  %s\n", r.change.median / r.raw.median,
                r.change.median <= 1.2 * r.raw.median ? "ok" : "MISS");
    std::fflush(stdout);
}

struct Results {
    std::vector<RttRow> write, call;
    std::string rttServer;
    // (c)
    Summary inproc, exec, premain, connect, read, cli, floorMain, dynamicCxx, staticAll;
    bool haveStart = false, haveCli = false;
    // (d)
    struct Idle {
        std::string label;
        Summary listen, listenLine, rssKb, hwmKb, anonKb, fileKb;
        long threads = 0;
    };
    std::vector<Idle> idle;
    // (e)
    ValueChangeRun changeIdle, changeBusy;
};

void printRttTable(const char* title, const std::vector<RttRow>& rows, const Options& o) {
    std::printf("\n%s\n", title);
    std::printf(
        "  (µs; %zu measured round trips per size and kind after %zu warm-up, OPC UA and raw "
        "alternating in blocks of %zu)\n",
        o.iterations, o.warmup, o.block);
    std::printf("  %7s | %9s %9s | %9s %9s | %6s %6s | %s\n", "bytes", "UA med", "UA p99",
                "raw med", "raw p99", "ratio", "r.p99", "≤1.20");
    std::printf("  --------+---------------------+---------------------+---------------+------\n");
    for (const auto& r : rows) {
        double ratio = r.ua.median / r.raw.median;
        double ratio99 = r.ua.p99 / r.raw.p99;
        std::printf("  %7zu | %9.1f %9.1f | %9.1f %9.1f | %6.2f %6.2f | %s\n", r.bytes, r.ua.median,
                    r.ua.p99, r.raw.median, r.raw.p99, ratio, ratio99,
                    ratio <= 1.2 ? "ok" : "MISS");
    }
}

std::string rttJson(const std::vector<RttRow>& rows) {
    std::string s = "[";
    for (std::size_t i = 0; i < rows.size(); ++i) {
        const auto& r = rows[i];
        if (i) s += ',';
        s += "{\"bytes\":" + std::to_string(r.bytes) + ",\"n\":" + std::to_string(r.ua.n) +
             ",\"ua_median_us\":" + num(r.ua.median) + ",\"ua_p99_us\":" + num(r.ua.p99) +
             ",\"raw_median_us\":" + num(r.raw.median) + ",\"raw_p99_us\":" + num(r.raw.p99) +
             ",\"ratio_median\":" + num(r.ua.median / r.raw.median) +
             ",\"ratio_p99\":" + num(r.ua.p99 / r.raw.p99) + "}";
    }
    return s + "]";
}

std::string summaryJson(const Summary& s, int decimals = 3) {
    return "{\"n\":" + std::to_string(s.n) + ",\"median\":" + num(s.median, decimals) +
           ",\"p99\":" + num(s.p99, decimals) + ",\"min\":" + num(s.min, decimals) +
           ",\"max\":" + num(s.max, decimals) + "}";
}

// ---- main -------------------------------------------------------------------------------------
std::string selfDir() {
    char buf[4096];
    ssize_t n = ::readlink("/proc/self/exe", buf, sizeof buf - 1);
    if (n <= 0) return ".";
    std::string p(buf, static_cast<std::size_t>(n));
    return p.substr(0, p.rfind('/'));
}

bool executable(const std::string& p) { return !p.empty() && ::access(p.c_str(), X_OK) == 0; }

std::string cpuModel() {
    std::ifstream f("/proc/cpuinfo");
    std::string line;
    while (std::getline(f, line))
        if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
    return "?";
}

std::string loadAvg() {
    std::ifstream f("/proc/loadavg");
    std::string a, b, c;
    f >> a >> b >> c;
    return a + " " + b + " " + c;
}

std::string placementText(const Options& o) {
    auto cpu = [](int c) { return c < 0 ? std::string("any") : std::to_string(c); };
    std::string kind =
        o.serverCpu >= 0 && o.serverCpu == o.clientCpu
            ? "same core (like `taskset -c " + std::to_string(o.serverCpu) + "` for both)"
            : "different cores";
    return "server CPU " + cpu(o.serverCpu) + ", client CPU " + cpu(o.clientCpu) + ": " + kind;
}

int run(Options o) {
    if (o.sizes.empty())
        for (std::size_t n = 2; n <= 32768; n *= 2) o.sizes.push_back(n);
    if (o.helperDir.empty()) o.helperDir = selfDir();
    const std::string echoExe = o.helperDir + "/pnp_bench_echo_server";
    const std::string benchServerExe = o.helperDir + "/pnp_bench_server";
    const std::string firstReadExe = o.helperDir + "/pnp_bench_first_read";
    const std::string emptyExe = o.helperDir + "/pnp_bench_empty";

    std::vector<ServerKind> kinds;
    if (executable(o.pnpExe))
        kinds.push_back(
            {"pnp ua serve", {o.pnpExe, "ua", "serve", "--host", "127.0.0.1", "--port", "0"}});
    if (executable(benchServerExe))
        kinds.push_back(
            {"pnp_bench_server", {benchServerExe, "--host", "127.0.0.1", "--port", "0"}});
    const ServerKind* rttKind = nullptr;
    for (const auto& k : kinds) {
        if (o.server == "auto" || (o.server == "pnp" && k.label == "pnp ua serve") ||
            (o.server == "bench" && k.label == "pnp_bench_server")) {
            rttKind = &k;
            break;
        }
    }
    if (!rttKind) throw std::runtime_error("no OPC UA server executable for --server " + o.server);

    // Scheduling: SCHED_FIFO keeps other processes (builds, ...) from preempting the
    // measured processes; without load it changes little. Auto: on when root and loaded.
    std::string schedReason;
    {
        double load1 = 0;
        std::ifstream("/proc/loadavg") >> load1;
        if (o.realtimeMode == 1) {
            o.realtime = true;
            schedReason = "--realtime";
        } else if (o.realtimeMode == 0) {
            schedReason = "--no-realtime";
        } else if (::geteuid() == 0 && load1 > 1.0) {
            o.realtime = true;
            schedReason = "auto: load average " + num(load1, 2) + " > 1; --no-realtime to disable";
        } else {
            schedReason = ::geteuid() == 0 ? "auto: load average " + num(load1, 2) + " <= 1"
                                           : "auto: not root";
        }
    }

    // The driver is the client of (a), (b), (d): pin it (and, by inheritance, (c)'s clients).
    pinToCpu(o.clientCpu);
    if (o.realtime) {
        sched_param sp{};
        sp.sched_priority = 10;
        if (sched_setscheduler(0, SCHED_FIFO, &sp) != 0) fail("sched_setscheduler(SCHED_FIFO)");
    }

    utsname u{};
    ::uname(&u);
    std::printf("pnp benchmark: %s %s, %ld CPUs (%s), load average %s\n", u.sysname, u.release,
                ::sysconf(_SC_NPROCESSORS_ONLN), cpuModel().c_str(), loadAvg().c_str());
    std::printf("placement: %s\n", placementText(o).c_str());
    std::printf("scheduling: %s (%s)\n", o.realtime ? "SCHED_FIFO 10" : "SCHED_OTHER",
                schedReason.c_str());
    std::printf("OPC UA server for (a)-(c): %s (%s)\n", rttKind->label.c_str(),
                rttKind->argv[0].c_str());
    std::printf("raw TCP baseline: %s (blocking sockets, TCP_NODELAY, 4-byte length prefix)\n",
                echoExe.c_str());
    std::fflush(stdout);

    Results res;
    res.rttServer = rttKind->label;
    const std::string loadBefore = loadAvg();

    bool needServer = o.sections.find_first_of("abc") != std::string::npos;
    if (needServer) {
        ServerProcess uaServer("opcua", rttKind->argv, o.serverCpu, o.realtime);
        std::string url = opcUrl(uaServer.port());
        ua::client::Client client;
        client.connect(url);
        const ua::UInt16 ns = client.namespaceIndex("urn:pnp:demo");
        const ua::NodeId varId(ns, "Scalar.ByteString");
        const ua::NodeId objId(ns, "Demo");
        const ua::NodeId echoId(ns, "Demo.Echo");

        if (o.sections.find_first_of("ab") != std::string::npos) {
            std::size_t maxSize = *std::max_element(o.sizes.begin(), o.sizes.end());
            ServerProcess echoServer(
                "echo", {echoExe, "--port", "0", "--max-payload", std::to_string(maxSize)},
                o.serverCpu, o.realtime);
            RawClient raw(echoServer.port());

            UaOp writeOp = [&](const ua::ByteString& value, bool verify) {
                ua::Variant v(value);  // the copy is made before the clock starts
                std::int64_t t0 = nowNs();
                ua::StatusCode st = client.writeValue(varId, std::move(v));
                std::int64_t t1 = nowNs();
                if (!st.isGood()) throw std::runtime_error("Write: " + st.toString());
                if (verify) {
                    ua::Variant back = client.readValue(varId);
                    const auto* b = back.scalar<ua::ByteString>();
                    if (!b || *b != value) throw std::runtime_error("Write: value not stored");
                }
                return static_cast<double>(t1 - t0);
            };
            UaOp callOp = [&](const ua::ByteString& value, bool verify) {
                std::vector<ua::Variant> in;
                in.emplace_back(value);
                std::int64_t t0 = nowNs();
                ua::client::CallResult r = client.call(objId, echoId, std::move(in));
                std::int64_t t1 = nowNs();
                if (!r.ok() || r.outputs.size() != 1)
                    throw std::runtime_error("Call Echo: " + r.status.toString());
                const auto* b = r.outputs[0].scalar<ua::ByteString>();
                if (!b || b->size() != value.size() || (verify && *b != value))
                    throw std::runtime_error("Call Echo: wrong output");
                return static_cast<double>(t1 - t0);
            };
            // Progress on a terminal only (one line, overwritten).
            const bool tty = !o.quiet && ::isatty(2);
            auto progress = [&](const char* section, std::size_t n) {
                if (tty) std::fprintf(stderr, "\r  %s %zu bytes done   ", section, n);
            };
            auto progressDone = [&] {
                if (tty) std::fprintf(stderr, "\r%40s\r", "");
            };
            // One-time warm-up of both paths (caches, allocator, CPU frequency) so that the
            // first size is not measured colder than the others.
            {
                Options w = o;
                w.iterations = 2000;
                w.warmup = 0;
                w.skipRaw = false;
                measureSize(o.sizes.front(), w, raw, writeOp);
                measureSize(o.sizes.front(), w, raw, callOp);
            }
            if (o.sections.find('a') != std::string::npos) {
                for (std::size_t n : o.sizes) {
                    res.write.push_back(measureSize(n, o, raw, writeOp));
                    progress("(a)", n);
                }
                progressDone();
                printRttTable("(a) Write ns=<demo>;s=Scalar.ByteString vs raw TCP echo", res.write,
                              o);
                std::fflush(stdout);
            }
            if (o.sections.find('b') != std::string::npos) {
                for (std::size_t n : o.sizes) {
                    res.call.push_back(measureSize(n, o, raw, callOp));
                    progress("(b)", n);
                }
                progressDone();
                printRttTable("(b) Call Demo.Echo(ByteString) vs raw TCP echo", res.call, o);
                std::fflush(stdout);
            }
        }

        if (o.sections.find('c') != std::string::npos) {
            client.disconnect();  // the server is idle again (one session less)
            std::vector<double> inproc, exec, premain, conn, rd, cli, floorMain;
            const std::string nsText = std::to_string(ns);
            // One timed start of `argv` (which prints "main=.. connected=.. read=.."); the
            // timestamps are CLOCK_MONOTONIC, the same clock as ours.
            struct Times {
                std::int64_t spawn, main, connected, read;
            };
            auto timedStart = [&](const std::vector<std::string>& argv) {
                Spawned s = spawnProcess(argv, o.clientCpu, o.realtime, "");
                auto line = readLine(s.out, 10s);
                int st = waitExit(s.pid, 10s);
                if (st == -1) {
                    stopProcess(s);
                    throw std::runtime_error(argv[0] + " did not exit within 10 s");
                }
                unregisterChild(s.pid);
                ::close(s.out);
                long long tMain = 0, tConn = 0, tRead = 0;
                if (!line ||
                    std::sscanf(line->c_str(), "main=%lld connected=%lld read=%lld", &tMain, &tConn,
                                &tRead) != 3 ||
                    !WIFEXITED(st) || WEXITSTATUS(st) != 0)
                    throw std::runtime_error(argv[0] + " failed");
                return Times{s.spawnNs, tMain, tConn, tRead};
            };
            // The same client linked with the shared libstdc++, and fully static: how much of
            // spawn -> Read is the dynamic loader (built by bench/CMakeLists.txt).
            struct Variant {
                std::string exe;
                std::vector<double> spawnToRead;
            };
            std::vector<Variant> linkVariants;
            for (const char* suffix : {"_dynamic_cxx", "_static"})
                if (executable(firstReadExe + suffix))
                    linkVariants.push_back({firstReadExe + suffix, {}});
            // Interleaved so that every variant sees the same machine state.
            for (std::size_t i = 0; i < o.startRuns + 2; ++i) {  // 2 untimed runs: page cache
                Times t = timedStart({firstReadExe, url, nsText, "Scalar.Int32"});
                Times f = timedStart({emptyExe});
                for (auto& v : linkVariants) {
                    Times tv = timedStart({v.exe, url, nsText, "Scalar.Int32"});
                    if (i >= 2)
                        v.spawnToRead.push_back(static_cast<double>(tv.read - tv.spawn) / 1000.0);
                }
                if (i < 2) continue;
                inproc.push_back(static_cast<double>(t.read - t.main) / 1000.0);
                exec.push_back(static_cast<double>(t.read - t.spawn) / 1000.0);
                premain.push_back(static_cast<double>(t.main - t.spawn) / 1000.0);
                conn.push_back(static_cast<double>(t.connected - t.main) / 1000.0);
                rd.push_back(static_cast<double>(t.read - t.connected) / 1000.0);
                floorMain.push_back(static_cast<double>(f.main - f.spawn) / 1000.0);
            }
            if (executable(o.pnpExe)) {
                std::string node = "ns=" + nsText + ";s=Scalar.Int32";
                for (std::size_t i = 0; i < o.startRuns + 2; ++i) {
                    Spawned s = spawnProcess({o.pnpExe, "ua", "read", url, node}, o.clientCpu,
                                             o.realtime, "/dev/null");
                    // Drain stdout while waiting (bounded), then take the exit time.
                    std::optional<std::string> out = readLine(s.out, 10s);
                    int st = waitExit(s.pid, 10s);
                    std::int64_t t1 = nowNs();
                    if (st == -1) {
                        stopProcess(s);
                        throw std::runtime_error("pnp ua read did not exit within 10 s");
                    }
                    unregisterChild(s.pid);
                    ::close(s.out);
                    if (!out || !WIFEXITED(st) || WEXITSTATUS(st) != 0) {
                        std::fprintf(stderr, "note: `pnp ua read` failed; CLI row skipped\n");
                        cli.clear();
                        break;
                    }
                    if (i >= 2) cli.push_back(static_cast<double>(t1 - s.spawnNs) / 1000.0);
                }
            }
            res.inproc = summarize(inproc);
            res.exec = summarize(exec);
            res.premain = summarize(premain);
            res.floorMain = summarize(floorMain);
            res.connect = summarize(conn);
            res.read = summarize(rd);
            res.haveStart = true;
            for (auto& v : linkVariants) {
                if (v.exe.ends_with("_dynamic_cxx"))
                    res.dynamicCxx = summarize(v.spawnToRead);
                else
                    res.staticAll = summarize(v.spawnToRead);
            }
            if (!cli.empty()) {
                res.cli = summarize(cli);
                res.haveCli = true;
            }
            std::printf(
                "\n(c) client start -> first completed Read (ns=<demo>;s=Scalar.Int32), %zu runs, "
                "µs\n",
                res.inproc.n);
            std::printf("  %-52s %9s %9s %9s | %s\n", "", "median", "p99", "min", "≤1000");
            auto rowc = [](const char* label, const Summary& s, bool target) {
                std::printf("  %-52s %9.0f %9.0f %9.0f | %s\n", label, s.median, s.p99, s.min,
                            target ? (s.median <= 1000 ? "ok" : "MISS") : "");
            };
            rowc("in-process: top of main() -> Read done", res.inproc, true);
            rowc("  of which connect (TCP+HEL+OPN+Create+Activate)", res.connect, false);
            rowc("  of which the Read", res.read, false);
            rowc("spawn (posix_spawn) -> Read done", res.exec, true);
            rowc("  of which spawn -> top of main() (exec, ld.so, init)", res.premain, false);
            rowc("empty C++ program (shared libstdc++): spawn -> main()", res.floorMain, false);
            if (res.dynamicCxx.n)
                rowc("same, shared libstdc++ (info): spawn -> Read", res.dynamicCxx, false);
            if (res.staticAll.n)
                rowc("same, fully static (-static): spawn -> Read", res.staticAll, false);
            if (res.haveCli) rowc("`pnp ua read` CLI: spawn -> exit (info)", res.cli, false);
            std::fflush(stdout);
        }
    }

    // ---- (e) value change in the server -> data-change callback in the client ---------------
    // Twice: first with the CPUs allowed to go idle between changes (information: on a VM that
    // is mostly the hypervisor's wake-up of a halted vCPU), then with them kept busy (target).
    if (o.sections.find('e') != std::string::npos) {
        res.changeIdle = measureValueChange(o, echoExe, false);
        printValueChange(o, res.changeIdle);
        res.changeBusy = measureValueChange(o, echoExe, true);
        printValueChange(o, res.changeBusy);
    }

    if (o.sections.find('d') != std::string::npos) {
        std::printf(
            "\n(d) idle server: spawn -> accepting, and VmRSS after one session came and went"
            " (%zu runs each, medians)\n",
            o.listenRuns);
        std::printf("  %-18s | %10s %10s | %9s %9s %9s %9s %7s | %s\n", "server", "accept ms",
                    "line ms", "RSS kB", "HWM kB", "anon kB", "file kB", "threads",
                    "≤100 ms / ≤8 MiB");
        for (const auto& k : kinds) {
            std::vector<double> listen, line, rss, hwm, anon, file;
            long threads = 0;
            for (std::size_t i = 0; i < o.listenRuns + 1; ++i) {  // 1 untimed run: page cache
                ServerProcess sp("idle", k.argv, o.serverCpu, o.realtime);
                int probe = connectLoopback(sp.port());
                std::int64_t tAccept = nowNs();
                if (probe < 0) throw std::runtime_error(k.label + ": listening but not accepting");
                ::close(probe);
                {
                    ua::client::Client c;
                    c.connect(opcUrl(sp.port()));
                    c.readValue(ua::NodeId(0, ua::ns0::Server_ServerStatus_State));
                    c.disconnect();
                }
                std::this_thread::sleep_for(300ms);  // let the server finish the close
                auto st = procStatus(sp.pid());
                if (i == 0) continue;
                listen.push_back(static_cast<double>(tAccept - sp.spawnNs()) / 1e6);
                line.push_back(static_cast<double>(sp.lineNs() - sp.spawnNs()) / 1e6);
                rss.push_back(static_cast<double>(st["VmRSS"]));
                hwm.push_back(static_cast<double>(st["VmHWM"]));
                anon.push_back(static_cast<double>(st["RssAnon"]));
                file.push_back(static_cast<double>(st["RssFile"]));
                threads = st["Threads"];
            }
            Results::Idle idle;
            idle.label = k.label;
            idle.listen = summarize(listen);
            idle.listenLine = summarize(line);
            idle.rssKb = summarize(rss);
            idle.hwmKb = summarize(hwm);
            idle.anonKb = summarize(anon);
            idle.fileKb = summarize(file);
            idle.threads = threads;
            std::printf("  %-18s | %10.2f %10.2f | %9.0f %9.0f %9.0f %9.0f %7ld | %s / %s\n",
                        k.label.c_str(), idle.listen.median, idle.listenLine.median,
                        idle.rssKb.median, idle.hwmKb.median, idle.anonKb.median,
                        idle.fileKb.median, threads, idle.listen.median <= 100 ? "ok" : "MISS",
                        idle.rssKb.median <= 8192 ? "ok" : "MISS");
            std::fflush(stdout);
            res.idle.push_back(idle);
        }
        std::printf(
            "  accept ms: spawn -> a TCP connect to the port succeeded (right after the"
            " \"listening on\" line, line ms)\n");
    }

    // ---- verdict + JSON ---------------------------------------------------------------------
    auto worst = [](const std::vector<RttRow>& rows) {
        double w = 0;
        for (const auto& r : rows) w = std::max(w, r.ua.median / r.raw.median);
        return w;
    };
    std::printf(
        "\nTargets: median RTT ≤ 1.2 × raw TCP at every size; client start -> first Read ≤"
        " 1 ms; idle RSS ≤ 8 MiB; accepting ≤ 100 ms after spawn\n");
    if (!res.write.empty())
        std::printf("  Write: worst median ratio %.2f  %s\n", worst(res.write),
                    worst(res.write) <= 1.2 ? "ok" : "MISS");
    if (!res.call.empty())
        std::printf("  Call:  worst median ratio %.2f  %s\n", worst(res.call),
                    worst(res.call) <= 1.2 ? "ok" : "MISS");
    if (res.changeBusy.change.n > 0) {
        const auto& b = res.changeBusy;
        const auto& i = res.changeIdle;
        std::printf(
            "  value change -> callback: %.1f µs, %.2f × raw TCP RTT paced alike  %s"
            "  (CPUs idle between changes: %.1f µs, %.2f ×, information)\n",
            b.change.median, b.change.median / b.raw.median,
            b.change.median <= 1.2 * b.raw.median ? "ok" : "MISS", i.change.median,
            i.change.median / i.raw.median);
    }
    if (res.haveStart)
        std::printf("  first Read: %.0f µs in-process, %.0f µs from spawn  %s / %s\n",
                    res.inproc.median, res.exec.median, res.inproc.median <= 1000 ? "ok" : "MISS",
                    res.exec.median <= 1000 ? "ok" : "MISS");
    for (const auto& i : res.idle)
        std::printf("  %s: RSS %.0f kB (%.2f MiB) %s, accepting after %.1f ms %s\n",
                    i.label.c_str(), i.rssKb.median, i.rssKb.median / 1024,
                    i.rssKb.median <= 8192 ? "ok" : "MISS", i.listen.median,
                    i.listen.median <= 100 ? "ok" : "MISS");
    std::printf("  load average before / after: %s / %s\n", loadBefore.c_str(), loadAvg().c_str());

    std::string j = "{\"benchmark\":\"pnp\",\"version\":1,\"unit_rtt\":\"us\"";
    j += ",\"machine\":{\"cpus\":" + std::to_string(::sysconf(_SC_NPROCESSORS_ONLN)) +
         ",\"cpu\":" + jstr(cpuModel()) + ",\"kernel\":" + jstr(u.release) +
         ",\"loadavg_before\":" + jstr(loadBefore) + ",\"loadavg_after\":" + jstr(loadAvg()) + "}";
    j += ",\"placement\":{\"server_cpu\":" + std::to_string(o.serverCpu) +
         ",\"client_cpu\":" + std::to_string(o.clientCpu) +
         ",\"same_core\":" + (o.serverCpu >= 0 && o.serverCpu == o.clientCpu ? "true" : "false") +
         ",\"realtime\":" + (o.realtime ? "true" : "false") +
         ",\"scheduling\":" + jstr(schedReason) + "}";
    j += ",\"rtt_server\":" + jstr(res.rttServer) +
         ",\"iterations\":" + std::to_string(o.iterations) +
         ",\"warmup\":" + std::to_string(o.warmup);
    if (!res.write.empty()) j += ",\"write\":" + rttJson(res.write);
    if (!res.call.empty()) j += ",\"call\":" + rttJson(res.call);
    if (res.haveStart) {
        j += ",\"first_read_us\":{\"in_process\":" + summaryJson(res.inproc) +
             ",\"spawn\":" + summaryJson(res.exec) +
             ",\"spawn_to_main\":" + summaryJson(res.premain) +
             ",\"empty_program_spawn_to_main\":" + summaryJson(res.floorMain) +
             ",\"connect\":" + summaryJson(res.connect) + ",\"read\":" + summaryJson(res.read);
        if (res.haveCli) j += ",\"pnp_ua_read_cli_spawn_to_exit\":" + summaryJson(res.cli);
        if (res.dynamicCxx.n) j += ",\"spawn_shared_libstdcxx\":" + summaryJson(res.dynamicCxx);
        if (res.staticAll.n) j += ",\"spawn_fully_static\":" + summaryJson(res.staticAll);
        j += "}";
    }
    if (!res.idle.empty()) {
        j += ",\"idle_server\":[";
        for (std::size_t i = 0; i < res.idle.size(); ++i) {
            const auto& d = res.idle[i];
            if (i) j += ',';
            j += "{\"server\":" + jstr(d.label) + ",\"accepting_ms\":" + summaryJson(d.listen) +
                 ",\"listening_line_ms\":" + summaryJson(d.listenLine) +
                 ",\"vmrss_kb\":" + summaryJson(d.rssKb, 0) +
                 ",\"vmhwm_kb\":" + summaryJson(d.hwmKb, 0) +
                 ",\"rss_anon_kb\":" + summaryJson(d.anonKb, 0) +
                 ",\"rss_file_kb\":" + summaryJson(d.fileKb, 0) +
                 ",\"threads\":" + std::to_string(d.threads) + "}";
        }
        j += "]";
    }
    if (res.changeBusy.change.n > 0) {
        auto run = [](const ValueChangeRun& r) {
            return "{\"change_us\":" + summaryJson(r.change) +
                   ",\"raw_rtt_us\":" + summaryJson(r.raw) +
                   ",\"raw_tick_us\":" + summaryJson(r.rawTick) +
                   ",\"raw_back_to_back_rtt_us\":" + summaryJson(r.rawBackToBack) +
                   ",\"server_set_value_us\":" + std::to_string(r.serverSetValueUs) + "}";
        };
        j += ",\"value_change\":{\"tick_ms\":" + std::to_string(o.tickMs) +
             ",\"cpus_busy\":" + run(res.changeBusy) + ",\"cpus_idle\":" + run(res.changeIdle) +
             "}";
    }
    j += ",\"targets\":{\"rtt_ratio_max\":1.2,\"first_read_us_max\":1000,\"idle_rss_kb_max\":8192,"
         "\"accepting_ms_max\":100}}";
    std::printf("\nJSON: %s\n", j.c_str());
    if (!o.jsonPath.empty()) {
        std::ofstream f(o.jsonPath);
        f << j << "\n";
        std::printf("(also written to %s)\n", o.jsonPath.c_str());
    }
    return 0;
}

std::vector<std::size_t> parseSizes(const std::string& s) {
    std::vector<std::size_t> r;
    std::stringstream ss(s);
    std::string item;
    while (std::getline(ss, item, ','))
        if (!item.empty()) r.push_back(std::stoul(item));
    return r;
}

}  // namespace
}  // namespace pnp::bench

int main(int argc, char** argv) {
    using namespace pnp::bench;
    Options o;
#ifdef PNP_BENCH_PNP_EXE
    o.pnpExe = PNP_BENCH_PNP_EXE;
#endif
    std::string placement;
    bool explicitCpu = false;
    try {
        for (int i = 1; i < argc; ++i) {
            std::string a = argv[i];
            auto next = [&]() -> std::string {
                if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
                return argv[++i];
            };
            if (a == "--help" || a == "-h") {
                usage();
                return 0;
            } else if (a == "--placement") {
                placement = next();
            } else if (a == "--server-cpu") {
                o.serverCpu = std::stoi(next());
                explicitCpu = true;
            } else if (a == "--client-cpu") {
                o.clientCpu = std::stoi(next());
                explicitCpu = true;
            } else if (a == "--server") {
                o.server = next();
            } else if (a == "--iterations") {
                o.iterations = std::stoul(next());
            } else if (a == "--warmup") {
                o.warmup = std::stoul(next());
            } else if (a == "--sizes") {
                o.sizes = parseSizes(next());
            } else if (a == "--start-runs") {
                o.startRuns = std::stoul(next());
            } else if (a == "--listen-runs") {
                o.listenRuns = std::stoul(next());
            } else if (a == "--tick-ms") {
                o.tickMs = std::clamp(std::stoi(next()), 2, 1000);
            } else if (a == "--only") {
                o.sections = next();
            } else if (a == "--realtime") {
                o.realtimeMode = 1;
            } else if (a == "--no-realtime") {
                o.realtimeMode = 0;
            } else if (a == "--json") {
                o.jsonPath = next();
            } else if (a == "--pnp") {
                o.pnpExe = next();
            } else if (a == "--skip-raw") {
                o.skipRaw = true;
            } else if (a == "--quiet") {
                o.quiet = true;
            } else {
                throw std::invalid_argument("unknown option " + a);
            }
        }
        if (placement == "split") {
            if (!explicitCpu) {
                o.serverCpu = 0;
                o.clientCpu = 1;
            }
        } else if (!placement.empty() && placement != "same") {
            throw std::invalid_argument("--placement same|split");
        }
        if (o.iterations < 100) throw std::invalid_argument("--iterations must be >= 100");
        if (o.server != "auto" && o.server != "pnp" && o.server != "bench")
            throw std::invalid_argument("--server auto|pnp|bench");
        long cpus = ::sysconf(_SC_NPROCESSORS_ONLN);
        if (o.serverCpu >= cpus || o.clientCpu >= cpus)
            throw std::invalid_argument("CPU index beyond the " + std::to_string(cpus) + " CPUs");
    } catch (const std::exception& e) {
        std::fprintf(stderr, "pnp_bench: %s\n", e.what());
        usage();
        return 2;
    }
    for (int sig : {SIGINT, SIGTERM, SIGHUP}) ::signal(sig, onSignal);
    ::signal(SIGPIPE, SIG_IGN);
    try {
        return run(o);
    } catch (const std::exception& e) {
        std::fprintf(stderr, "pnp_bench: error: %s\n", e.what());
        return 1;
    }
}
