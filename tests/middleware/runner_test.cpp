// `pnp bench middleware` (src/bench/runner): a --quick run over every adapter that is built,
// the network load's namespaces set up and removed, a SIGINT in the middle of a network-load
// run cleans up, and the package overhead of raw TCP comes out as its framing says.
#include <arpa/inet.h>
#include <dirent.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sched.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <thread>

#include "bench/runner/netns.hpp"
#include "bench/runner/process.hpp"
#include "support/child_process.hpp"

namespace fs = std::filesystem;
using Json = nlohmann::json;
using namespace std::chrono_literals;
namespace runner = pnp::bench::runner;

namespace {

const std::string kPnp = PNP_BINARY;
const std::string kAdapterDir = PNP_MW_ADAPTER_DIR_TEST;

struct PnpRun {
    pid_t pid = -1;
    int exitCode = -1;
    std::string log;
};

fs::path freshDir(const std::string& name) {
    const fs::path d =
        fs::temp_directory_path() / ("test_mw_runner_" + name + "_" + std::to_string(::getpid()));
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}

std::string readFile(const fs::path& p) {
    std::ifstream f(p);
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

pid_t startPnp(const std::vector<std::string>& args, const std::string& log) {
    std::vector<std::string> argv = {kPnp};
    argv.insert(argv.end(), args.begin(), args.end());
    std::vector<char*> c;
    for (auto& a : argv) c.push_back(a.data());
    c.push_back(nullptr);
    const pid_t pid = ::fork();
    if (pid == 0) {
        const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        if (fd >= 0) {
            ::dup2(fd, STDOUT_FILENO);
            ::dup2(fd, STDERR_FILENO);
        }
        ::execv(c[0], c.data());
        ::_exit(127);
    }
    return pid;
}

// Waits for the runner; past the limit it gets SIGTERM (and cleans up), then SIGKILL.
int waitPnp(pid_t pid, std::chrono::seconds limit) {
    const auto end = std::chrono::steady_clock::now() + limit;
    int status = 0;
    bool termSent = false;
    for (;;) {
        const pid_t r = ::waitpid(pid, &status, WNOHANG);
        if (r == pid) return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
        if (r < 0) return -1;
        const auto now = std::chrono::steady_clock::now();
        if (now >= end && !termSent) {
            ::kill(pid, SIGTERM);
            termSent = true;
        } else if (now >= end + 30s) {
            ::kill(pid, SIGKILL);
        }
        std::this_thread::sleep_for(100ms);
    }
}

PnpRun runPnp(const std::vector<std::string>& args, const fs::path& dir,
              std::chrono::seconds limit) {
    PnpRun r;
    const std::string log = (dir / "pnp.log").string();
    r.pid = startPnp(args, log);
    r.exitCode = waitPnp(r.pid, limit);
    r.log = readFile(log);
    return r;
}

// Processes that carry the runner's marker (PNP_MW_RUNNER=<pid>) in their environment.
std::vector<std::string> leftovers(pid_t runner) {
    const std::string marker = "PNP_MW_RUNNER=" + std::to_string(runner);
    std::vector<std::string> found;
    for (int attempt = 0; attempt < 20; ++attempt) {  // a killed group may take a moment
        found.clear();
        DIR* d = ::opendir("/proc");
        while (dirent* e = d ? ::readdir(d) : nullptr) {
            const std::string name = e->d_name;
            if (name.find_first_not_of("0123456789") != std::string::npos) continue;
            const std::string env = readFile("/proc/" + name + "/environ");
            std::size_t pos = 0;
            while (pos < env.size()) {
                const auto end = env.find('\0', pos);
                const std::string kv = env.substr(pos, end - pos);
                if (kv == marker) found.push_back(name + " " + readFile("/proc/" + name + "/comm"));
                if (end == std::string::npos) break;
                pos = end + 1;
            }
        }
        if (d) ::closedir(d);
        if (found.empty()) break;
        std::this_thread::sleep_for(100ms);
    }
    return found;
}

std::vector<std::string> namespacesOf(pid_t runner) {
    std::vector<std::string> out;
    for (const auto& n : runner::listNamespaces())
        if (n.rfind("pnpmw" + std::to_string(runner), 0) == 0) out.push_back(n);
    return out;
}

bool installed(const std::string& adapter) {
    return ::access((kAdapterDir + "/pnp-mw-" + adapter).c_str(), X_OK) == 0;
}

const Json* findRun(const Json& s, const std::string& adapter, const std::string& variant,
                    const std::string& mode, const std::string& load) {
    for (const auto& r : s["runs"])
        if (r["adapter"] == adapter && r["variant"] == variant && r["mode"] == mode &&
            r["load"] == load)
            return &r;
    return nullptr;
}

void expectNothingLeft(pid_t runner) {
    EXPECT_TRUE(leftovers(runner).empty())
        << "processes left: " << testing::PrintToString(leftovers(runner));
    EXPECT_TRUE(namespacesOf(runner).empty())
        << "namespaces left: " << testing::PrintToString(namespacesOf(runner));
}

}  // namespace

TEST(MiddlewareRunner, QuickRunCoversEveryInstalledAdapter) {
    ASSERT_TRUE(installed("tcp")) << "pnp-mw-tcp is always built";
    const fs::path dir = freshDir("quick");
    const auto t0 = std::chrono::steady_clock::now();
    const PnpRun r = runPnp({"bench", "middleware", "--quick", "--out", (dir / "out").string(),
                             "--adapters", kAdapterDir},
                            dir, 300s);
    const double secs =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ASSERT_TRUE(r.exitCode == 0 || r.exitCode == 3) << r.log;
    EXPECT_LT(secs, 120) << "--quick must finish in under 2 minutes";
    const Json s = Json::parse(readFile(dir / "out" / "summary.json"));
    EXPECT_TRUE(fs::exists(dir / "out" / "report.md"));
    EXPECT_EQ(s["version"], 1);
    EXPECT_EQ(s["quick"], true);
    const auto sizes = s["settings"]["sizes"].get<std::vector<std::size_t>>();
    ASSERT_FALSE(sizes.empty());
    int checked = 0;
    for (const auto& a : s["adapters"]) {
        const std::string name = a["name"];
        if (!installed(name)) {
            EXPECT_EQ(a["status"], "skipped") << name;
            EXPECT_NE(a["reason"].get<std::string>().find("not built"), std::string::npos);
            continue;
        }
        ASSERT_EQ(a["status"], "ok") << name << ": " << a["reason"];
        for (const auto& v : a["variants"])
            for (const std::string mode : {"ack", "echo"}) {
                const Json* run = findRun(s, name, v, mode, "idle");
                ASSERT_NE(run, nullptr) << name << "/" << v << " " << mode;
                EXPECT_EQ((*run)["status"], "ok")
                    << name << "/" << v << " " << mode << ": " << (*run)["reason"];
                std::set<std::size_t> seen;
                for (const auto& sz : (*run)["sizes"]) {
                    EXPECT_GT(sz["n"].get<int>(), 0) << name << "/" << v << " " << mode;
                    EXPECT_GT(sz["median_us"].get<double>(), 0);
                    seen.insert(sz["payload"].get<std::size_t>());
                }
                EXPECT_EQ(seen, std::set<std::size_t>(sizes.begin(), sizes.end()))
                    << name << "/" << v << " " << mode;
                EXPECT_TRUE(fs::exists(dir / "out" / (*run)["csv"].get<std::string>()));
                EXPECT_GT((*run)["resources"]["client"]["rss_kib_max"].get<long>(), 0);
                EXPECT_GT((*run)["resources"]["server"]["rss_kib_max"].get<long>(), 0);
                ++checked;
            }
    }
    EXPECT_GE(checked, 2);
    bool tcpChain = false;
    for (const auto& c : s["chain"])
        if (c["adapter"] == "tcp") {
            EXPECT_EQ(c["status"], "ok") << c["reason"];
            EXPECT_GT(c["summary"]["n"].get<int>(), 0);
            EXPECT_GT(c["rss_kib_total"].get<long>(), 0);
            tcpChain = true;
        }
    EXPECT_TRUE(tcpChain);
    expectNothingLeft(r.pid);
}

TEST(MiddlewareRunner, NetPairIsSetUpShapedAndRemoved) {
    if (::geteuid() != 0) GTEST_SKIP() << "network namespaces need root";
    const fs::path dir = freshDir("netpair");
    runner::NetPairConfig c;
    c.name = "pnpmw" + std::to_string(::getpid());
    c.log = (dir / "netns.log").string();
    std::string clientNs, serverNs;
    {
        runner::NetPair net(c);
        clientNs = net.clientNs();
        serverNs = net.serverNs();
        const auto names = runner::listNamespaces();
        EXPECT_NE(std::find(names.begin(), names.end(), clientNs), names.end());
        EXPECT_NE(std::find(names.begin(), names.end(), serverNs), names.end());
        for (const auto& ns : {clientNs, serverNs}) {
            std::string out;
            ASSERT_EQ(
                runner::runCommandOutput({"tc", "-n", ns, "qdisc", "show", "dev", ns}, out, c.log),
                0);
            EXPECT_NE(out.find("tbf"), std::string::npos) << out;
        }
        // The client side reaches a listener on the server side over the veth pair.
        int port = 0;
        std::atomic<bool> listening{false}, done{false};
        std::thread server([&] {
            const int fd = ::open(("/var/run/netns/" + serverNs).c_str(), O_RDONLY);
            ASSERT_GE(fd, 0);
            ASSERT_EQ(::setns(fd, CLONE_NEWNET), 0);
            ::close(fd);
            const int l = ::socket(AF_INET, SOCK_STREAM, 0);
            sockaddr_in a{};
            a.sin_family = AF_INET;
            ::inet_pton(AF_INET, runner::NetPair::kServerAddr, &a.sin_addr);
            ASSERT_EQ(::bind(l, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
            socklen_t len = sizeof a;
            ::getsockname(l, reinterpret_cast<sockaddr*>(&a), &len);
            port = ntohs(a.sin_port);
            ::listen(l, 4);
            listening = true;
            while (!done) std::this_thread::sleep_for(10ms);
            ::close(l);
        });
        for (int i = 0; i < 500 && !listening; ++i) std::this_thread::sleep_for(10ms);
        ASSERT_TRUE(listening);
        EXPECT_TRUE(runner::waitForPort(clientNs, runner::NetPair::kServerAddr, port, 5s));
        // ... and not from the runner's own namespace.
        EXPECT_FALSE(runner::waitForPort("", runner::NetPair::kServerAddr, port, 200ms));
        done = true;
        server.join();
    }
    const auto names = runner::listNamespaces();
    EXPECT_EQ(std::find(names.begin(), names.end(), clientNs), names.end());
    EXPECT_EQ(std::find(names.begin(), names.end(), serverNs), names.end());
    EXPECT_NE(runner::runCommand({"ip", "link", "show", clientNs}, c.log), 0);
    EXPECT_NE(runner::runCommand({"ip", "link", "show", serverNs}, c.log), 0);
}

TEST(MiddlewareRunner, NetworkLoadRunMeasuresAcrossTheVethAndCleansUp) {
    if (::geteuid() != 0) GTEST_SKIP() << "network namespaces need root";
    const fs::path dir = freshDir("net");
    const PnpRun r = runPnp({"bench",      "middleware",
                             "--only",     "tcp",
                             "--loads",    "net",
                             "--modes",    "ack,echo",
                             "--reps",     "30",
                             "--warmup",   "2",
                             "--sizes",    "2,1024,32768",
                             "--no-chain", "--no-overhead",
                             "--out",      (dir / "out").string(),
                             "--adapters", kAdapterDir},
                            dir, 300s);
    ASSERT_EQ(r.exitCode, 0) << r.log;
    const Json s = Json::parse(readFile(dir / "out" / "summary.json"));
    EXPECT_NE(s["settings"]["net_load"].get<std::string>().find("tbf"), std::string::npos);
    for (const std::string mode : {"ack", "echo"}) {
        const Json* run = findRun(s, "tcp", "tcp", mode, "net");
        ASSERT_NE(run, nullptr);
        EXPECT_EQ((*run)["status"], "ok") << (*run)["reason"];
        EXPECT_EQ((*run)["sizes"].size(), 3u);
    }
    // The iperf3 flood ran in the namespaces for the whole scenario.
    EXPECT_NE(readFile(dir / "out" / "logs" / "net-iperf3-client.log").find("Connecting to host"),
              std::string::npos);
    expectNothingLeft(r.pid);
}

TEST(MiddlewareRunner, SigintDuringNetworkLoadRemovesEverything) {
    if (::geteuid() != 0) GTEST_SKIP() << "network namespaces need root";
    const fs::path dir = freshDir("sigint");
    const std::string log = (dir / "pnp.log").string();
    const pid_t pid =
        startPnp({"bench", "middleware", "--only", "tcp", "--loads", "net", "--modes", "echo",
                  "--reps", "1000000", "--sizes", "32768", "--no-chain", "--no-overhead", "--out",
                  (dir / "out").string(), "--adapters", kAdapterDir},
                 log);
    // Wait until the scenario is set up and a client runs.
    const auto end = std::chrono::steady_clock::now() + 60s;
    while (std::chrono::steady_clock::now() < end &&
           readFile(dir / "out" / "logs" / "net" / "tcp-tcp-echo-client.log").empty() &&
           !fs::exists(dir / "out" / "samples" / "net" / "tcp-tcp-echo.csv"))
        std::this_thread::sleep_for(100ms);
    std::this_thread::sleep_for(1s);
    EXPECT_FALSE(namespacesOf(pid).empty()) << readFile(log);
    EXPECT_FALSE(leftovers(pid).empty());
    ::kill(pid, SIGINT);
    const auto t0 = std::chrono::steady_clock::now();
    const int rc = waitPnp(pid, 60s);
    EXPECT_EQ(rc, 130) << readFile(log);
    EXPECT_LT(std::chrono::steady_clock::now() - t0, 30s);
    expectNothingLeft(pid);
    const Json s = Json::parse(readFile(dir / "out" / "summary.json"));
    EXPECT_EQ(s.value("interrupted", false), true);
}

TEST(MiddlewareRunner, TcpPackageOverheadIsItsFourByteFrame) {
    if (::geteuid() != 0) GTEST_SKIP() << "the capture runs in network namespaces: needs root";
    if (pnp::testing::findInPath("dumpcap").empty()) GTEST_SKIP() << "no dumpcap (tshark)";
    const fs::path dir = freshDir("overhead");
    const PnpRun r = runPnp({"bench", "middleware", "--only", "tcp", "--loads", "idle", "--modes",
                             "ack", "--reps", "10", "--sizes", "2", "--no-chain", "--out",
                             (dir / "out").string(), "--adapters", kAdapterDir},
                            dir, 300s);
    ASSERT_EQ(r.exitCode, 0) << r.log;
    const Json s = Json::parse(readFile(dir / "out" / "summary.json"));
    ASSERT_EQ(s["overhead"].size(), 1u);
    const Json& o = s["overhead"][0];
    ASSERT_EQ(o["status"], "ok") << o["reason"];
    ASSERT_EQ(o["per_message"].size(), 4u);
    for (const auto& m : o["per_message"]) {
        // A request is a 4-byte length and the payload; the ACK a 4-byte length and 1 byte.
        EXPECT_DOUBLE_EQ(m["request_bytes"].get<double>(), m["payload"].get<double>() + 4);
        EXPECT_DOUBLE_EQ(m["response_bytes"].get<double>(), 5);
    }
    EXPECT_EQ(o["connection_bytes"], 0);  // TCP's handshake carries no payload
    expectNothingLeft(r.pid);
}
