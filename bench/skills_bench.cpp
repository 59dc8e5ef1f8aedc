// Skills on loopback (a skill server, by default `pnp demo-skills` as a process of its own,
// and a client in this process, real sockets between them):
//   (a) Start call -> the Running transition event at the client (the event item on the skill
//       node, a Publish request waiting in the server), next to
//   (b) the raw TCP round trip of a 64-byte frame to a blocking echo server set up like the
//       skill server (a process of its own, pnp_bench_echo_server, when the skill server is
//       one; a thread of this process when it runs here), measured interleaved with (a) so
//       that both see the same machine;
//   (c) a no-op skill's full SkillClient::run(): InitLock, Write, Start, both events, Read of
//       FinalResultData, ExitLock.
// Prints medians and p99 and the ratio (a)/(b). Targets (issue 5): (a) <= 2 x (b); (c) <= 1 ms.
//
// usage: pnp_bench_skills [--runs N] [--server-exe PNP | -]  (default: the pnp binary of the
// build, `pnp demo-skills` in a process of its own; "-": the server in this process)
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.hpp"
#include "skill/client/skill_client.hpp"
#include "skill/demo/demo_skills.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp;
using namespace std::chrono_literals;
using bench::Clock;

namespace {

// A blocking echo server on 127.0.0.1 (one connection), the raw TCP baseline.
class EchoThread {
  public:
    EchoThread() {
        listener_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        int one = 1;
        ::setsockopt(listener_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        if (::bind(listener_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
            ::listen(listener_, 1) != 0)
            bench::fail("echo listen");
        socklen_t len = sizeof a;
        ::getsockname(listener_, reinterpret_cast<sockaddr*>(&a), &len);
        port_ = ntohs(a.sin_port);
        thread_ = std::thread([this] {
            int fd = ::accept(listener_, nullptr, nullptr);
            if (fd < 0) return;
            bench::setNoDelay(fd);
            std::vector<unsigned char> buf;
            for (;;) {
                long n = bench::recvFrame(fd, buf, 1 << 16);
                if (n < 0 || !bench::sendAll(fd, buf.data(), static_cast<std::size_t>(n) + 4))
                    break;
            }
            ::close(fd);
        });
    }
    ~EchoThread() {
        ::shutdown(listener_, SHUT_RDWR);
        ::close(listener_);
        if (thread_.joinable()) thread_.join();
    }
    std::uint16_t port() const { return port_; }

  private:
    int listener_ = -1;
    std::uint16_t port_ = 0;
    std::thread thread_;
};

double rawRoundTripUs(int fd) {
    unsigned char frame[68] = {64, 0, 0, 0};
    std::vector<unsigned char> buf;
    const auto t0 = Clock::now();
    if (!bench::sendAll(fd, frame, sizeof frame) || bench::recvFrame(fd, buf, 1 << 16) != 64)
        bench::fail("echo");
    return std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
}

}  // namespace

// A server as a process of its own (as a real skill server runs), started with `argv`; its
// first line of output says "listening on ADDRESS". Killed at exit.
struct ServerProcess {
    pid_t pid = -1;
    std::string url;  // ADDRESS
    explicit ServerProcess(const std::vector<std::string>& argv) {
        int fds[2];
        if (::pipe(fds) != 0) bench::fail("pipe");
        std::vector<char*> args;
        for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
        args.push_back(nullptr);
        pid = ::fork();
        if (pid == 0) {
            ::dup2(fds[1], 1);
            ::close(fds[0]);
            ::execv(args[0], args.data());
            ::_exit(127);
        }
        ::close(fds[1]);
        std::string line;
        char c;
        while (line.size() < 4096 && ::read(fds[0], &c, 1) == 1 && c != '\n') line += c;
        ::close(fds[0]);
        const std::string prefix = "listening on ";
        if (line.rfind(prefix, 0) != 0) bench::fail(argv[0] + " did not start: " + line);
        url = line.substr(prefix.size());
    }
    ~ServerProcess() {
        if (pid > 0) {
            ::kill(pid, SIGTERM);
            ::waitpid(pid, nullptr, 0);
        }
    }
};

int main(int argc, char** argv) {
    int runs = 2000;
    std::string serverExe;  // empty: the server runs in this process
    for (int i = 1; i + 1 < argc; ++i) {
        if (std::string(argv[i]) == "--runs") runs = std::max(10, std::atoi(argv[i + 1]));
        if (std::string(argv[i]) == "--server-exe") serverExe = argv[i + 1];
    }
#ifdef PNP_BENCH_PNP_EXE
    if (serverExe.empty()) serverExe = PNP_BENCH_PNP_EXE;
#endif
    if (serverExe == "-") serverExe.clear();

    ua::server::ServerConfig config;
    config.host = "127.0.0.1";
    config.publicHost = "127.0.0.1";
    config.port = 0;
    ua::server::Server server(config);
    std::unique_ptr<skill::server::SkillController> controller;
    std::unique_ptr<ServerProcess> process;
    std::string serverUrl;
    if (serverExe.empty()) {
        controller = skill::demo::addDemoSkills(server);
        server.start();
        serverUrl = server.endpointUrl();
        std::printf("skill server: in this process\n");
    } else {
        process = std::make_unique<ServerProcess>(std::vector<std::string>{
            serverExe, "demo-skills", "--port", "0", "--host", "127.0.0.1", "--no-register"});
        serverUrl = process->url;
        std::printf("skill server: %s demo-skills (a process of its own)\n", serverExe.c_str());
    }
    // The raw baseline's peer is set up like the skill server: a process of its own, or a
    // thread of this one.
    std::optional<EchoThread> echoThread;
    std::unique_ptr<ServerProcess> echoProcess;
    std::uint16_t echoPort = 0;
    std::string echoExe;
#ifdef PNP_BENCH_ECHO_EXE
    echoExe = PNP_BENCH_ECHO_EXE;
#endif
    if (process && !echoExe.empty()) {
        echoProcess = std::make_unique<ServerProcess>(std::vector<std::string>{echoExe});
        const auto colon = echoProcess->url.rfind(':');
        echoPort = static_cast<std::uint16_t>(std::atoi(echoProcess->url.c_str() + colon + 1));
        std::printf("raw TCP echo: %s (a process of its own)\n", echoExe.c_str());
    } else {
        echoThread.emplace();
        echoPort = echoThread->port();
        std::printf("raw TCP echo: a thread of this process\n");
    }
    int fd = bench::connectLoopback(echoPort);
    if (fd < 0) bench::fail("connect echo");

    auto c = std::make_shared<ua::client::Client>();
    c->connect(serverUrl);
    c->startBackgroundThread();
    const ua::NodeId delay(1, "DemoGripper.Delay");
    skill::client::SkillClient skill(c, delay);
    skill.setParameter("DurationMs", ua::Variant(std::getenv("PNP_BENCH_DURATION")
                                                     ? std::atof(std::getenv("PNP_BENCH_DURATION"))
                                                     : 0.0));

    // (a) Start -> Running event, interleaved with (b); twice: CPUs idle between runs
    // (information: an idle vCPU's wake-up is paid by every thread hop), then CPUs kept busy by
    // SCHED_IDLE spinners (the target: a controller core that does not sleep, as in
    // bench/README.md (e)).
    std::mutex m;
    std::condition_variable cv;
    std::uint64_t seen = 0;
    Clock::time_point runningAt{};
    skill.onTransition([&](const skill::client::Transition& t) {
        const auto now = Clock::now();
        std::lock_guard l(m);
        if (t.to == skill::ProgramState::Running) runningAt = now;
        ++seen;
        cv.notify_all();
    });
    std::vector<double> raw;
    const int startRuns = std::min(runs, 500);
    for (bool busyCores : {false, true}) {
        std::optional<bench::BusyCores> busy;
        if (busyCores) {
            std::vector<int> cpus;
            for (unsigned i = 0; i < std::max(1u, std::thread::hardware_concurrency()); ++i)
                cpus.push_back(static_cast<int>(i));
            busy.emplace(cpus);
        }
        std::vector<double> startToRunning, callReturned;
        raw.clear();
        // A Start one publishing interval (10 ms) after the previous run's last event: its
        // Running event is not held back for the interval (the server publishes at most once
        // per interval on a subscription, OPC 10000-4 §5.13.1).
        for (int i = 0; i < startRuns; ++i) {
            std::this_thread::sleep_for(12ms);
            raw.push_back(rawRoundTripUs(fd));
            std::uint64_t before;
            {
                std::lock_guard l(m);
                before = seen;
            }
            const auto t0 = Clock::now();
            skill.start();
            callReturned.push_back(
                std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
            std::unique_lock l(m);
            if (!cv.wait_for(l, 5s, [&] { return seen >= before + 2; })) bench::fail("no events");
            startToRunning.push_back(
                std::chrono::duration<double, std::micro>(runningAt - t0).count());
        }
        auto a = bench::summarize(startToRunning);
        auto b = bench::summarize(raw);
        auto cr = bench::summarize(callReturned);
        std::printf("[CPUs %s]\n",
                    busyCores ? "kept busy (target)" : "idle between runs (information)");
        std::printf(
            "Start call -> Running event at the client: median %.1f us, p99 %.1f us "
            "(%d runs; the call returned after %.1f us)\n",
            a.median, a.p99, startRuns, cr.median);
        std::printf("raw TCP round trip (64 B, same run):      median %.1f us, p99 %.1f us\n",
                    b.median, b.p99);
        std::printf("ratio (median): %.2f%s\n", a.median / b.median,
                    busyCores ? "  (target <= 2)" : "");
    }

    // (c) no-op run(), interleaved with raw round trips again.
    std::vector<double> full;
    raw.clear();
    for (int i = 0; i < runs; ++i) {
        raw.push_back(rawRoundTripUs(fd));
        const auto t0 = Clock::now();
        auto r = skill.run({{"DurationMs", ua::Variant(0.0)}}, 5s);
        full.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
        if (r.result != skill::SkillResult::Completed) bench::fail("run did not complete");
    }
    auto f = bench::summarize(full);
    auto b = bench::summarize(raw);
    std::printf(
        "no-op skill run() (lock, write, start, events, result, unlock): median %.1f us, "
        "p99 %.1f us (%d runs; target <= 1000 us)\n",
        f.median, f.p99, runs);
    std::printf("raw TCP round trip (same run):            median %.1f us  (run() = %.1f x)\n",
                b.median, f.median / b.median);

    // Where the time of a run goes: each of its requests alone.
    auto timed = [&](const char* what, auto&& op) {
        std::vector<double> v;
        for (int i = 0; i < std::min(runs, 300); ++i) {
            const auto t0 = Clock::now();
            op();
            v.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
        }
        auto x = bench::summarize(v);
        std::printf("  %-34s median %7.1f us\n", what, x.median);
    };
    std::printf("breakdown (each request alone):\n");
    {
        ua::client::Client plain;
        plain.connect(serverUrl);
        const ua::NodeId node(1, "DemoGripper.Delay.ParameterSet.DurationMs");
        timed("Read, a client without threads", [&] { (void)plain.readValue(node); });
        plain.startBackgroundThread();
        timed("Read, with its background thread", [&] { (void)plain.readValue(node); });
    }
    {
        // Start alone, by a client without a subscription, with and without an event item
        // watching (another client's) - where the Start call's time goes.
        ua::client::Client plain;
        plain.connect(serverUrl);
        const ua::NodeId start(1, "DemoGripper.Delay.Start"), halt(1, "DemoGripper.Delay.Halt"),
            reset(1, "DemoGripper.Delay.Reset");
        skill.setParameter("DurationMs", ua::Variant(1000.0));
        std::vector<double> v;
        for (int i = 0; i < 200; ++i) {
            std::this_thread::sleep_for(12ms);
            const auto t0 = Clock::now();
            plain.call(delay, start, {});
            v.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
            plain.call(delay, halt, {});
            plain.call(delay, reset, {});
        }
        std::printf("  %-34s median %7.1f us\n", "Start call (1 s skill, events watched)",
                    bench::summarize(v).median);
        skill.setParameter("DurationMs", ua::Variant(0.0));
    }
    timed("Read of a Value", [&] { (void)skill.parameter("DurationMs"); });
    timed("InitLock + ExitLock (2 calls)", [&] {
        skill.lock("bench");
        skill.unlock();
    });
    timed("Write of one parameter", [&] { skill.setParameter("DurationMs", ua::Variant(0.0)); });
    timed("Start (no-op run) + wait for Ready", [&] {
        skill.start();
        for (int k = 0; k < 100000 && skill.state() != skill::ProgramState::Ready; ++k) {
        }
    });
    ::close(fd);
    c.reset();
    if (controller) {
        controller.reset();
        server.stop();
    }
    return 0;
}
