// Skills on loopback (server and client in this process, real sockets between them):
//   (a) Start call -> the Running transition event at the client (the event item on the skill
//       node, a Publish request waiting in the server), next to
//   (b) the raw TCP round trip of a 64-byte frame to an in-process blocking echo thread,
//       measured interleaved with (a) so that both see the same machine;
//   (c) a no-op skill's full SkillClient::run(): InitLock, Write, Start, both events, Read of
//       FinalResultData, ExitLock.
// Prints medians and p99 and the ratio (a)/(b). Targets (issue 5): (a) <= 2 x (b); (c) <= 1 ms.
//
// usage: pnp_bench_skills [--runs N]
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <string>
#include <thread>

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
                if (n < 0 || !bench::sendAll(fd, buf.data(), static_cast<std::size_t>(n) + 4)) break;
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

int main(int argc, char** argv) {
    int runs = 2000;
    for (int i = 1; i + 1 < argc; ++i)
        if (std::string(argv[i]) == "--runs") runs = std::max(10, std::atoi(argv[i + 1]));

    ua::server::ServerConfig config;
    config.host = "127.0.0.1";
    config.publicHost = "127.0.0.1";
    config.port = 0;
    ua::server::Server server(config);
    auto controller = skill::demo::addDemoSkills(server);
    server.start();
    EchoThread echo;
    int fd = bench::connectLoopback(echo.port());
    if (fd < 0) bench::fail("connect echo");

    auto c = std::make_shared<ua::client::Client>();
    c->connect(server.endpointUrl());
    c->startBackgroundThread();
    const ua::NodeId delay(1, "DemoGripper.Delay");
    skill::client::SkillClient skill(c, delay);
    skill.setParameter("DurationMs", ua::Variant(0.0));

    // (a) Start -> Running event, interleaved with (b).
    std::mutex m;
    std::condition_variable cv;
    std::uint32_t lastTo = 0;
    std::uint64_t seen = 0;
    Clock::time_point runningAt{};
    skill.onTransition([&](const skill::client::Transition& t) {
        const auto now = Clock::now();
        std::lock_guard l(m);
        lastTo = static_cast<std::uint32_t>(t.to);
        if (t.to == skill::ProgramState::Running) runningAt = now;
        ++seen;
        cv.notify_all();
    });
    std::vector<double> startToRunning, raw;
    for (int i = 0; i < runs; ++i) {
        raw.push_back(rawRoundTripUs(fd));
        std::uint64_t before;
        {
            std::lock_guard l(m);
            before = seen;
        }
        const auto t0 = Clock::now();
        skill.start();
        std::unique_lock l(m);
        if (!cv.wait_for(l, 5s, [&] { return seen >= before + 2; })) bench::fail("no events");
        startToRunning.push_back(std::chrono::duration<double, std::micro>(runningAt - t0).count());
    }
    auto a = bench::summarize(startToRunning);
    auto b = bench::summarize(raw);
    std::printf("Start call -> Running event at the client: median %.1f us, p99 %.1f us (%d runs)\n",
                a.median, a.p99, runs);
    std::printf("raw TCP round trip (64 B, same run):      median %.1f us, p99 %.1f us\n",
                b.median, b.p99);
    std::printf("ratio (median): %.2f  (target <= 2)\n", a.median / b.median);

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
    b = bench::summarize(raw);
    std::printf("no-op skill run() (lock, write, start, events, result, unlock): median %.1f us, "
                "p99 %.1f us (%d runs; target <= 1000 us)\n",
                f.median, f.p99, runs);
    std::printf("raw TCP round trip (same run):            median %.1f us  (run() = %.1f x)\n",
                b.median, f.median / b.median);
    ::close(fd);
    c.reset();
    controller.reset();
    server.stop();
    return 0;
}
