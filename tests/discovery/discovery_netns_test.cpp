// Hierarchical discovery across simulated hosts (issue 4, point 5). The topology, made with
// network namespaces, veth pairs and bridges by the test and removed after it:
//
//   cell bus 10.10.0.0/24:  cell (pnp lds, level 0) .1   client (DiscoveryWatcher) .100
//                           ws1 .11                        ws2 .12
//   ws1's segment 10.11.0.0/24: ws1 .1 (pnp ua serve --lds-me, level 1), d11 .11, d12 .12
//   ws2's segment 10.12.0.0/24: ws2 .1,                                    d21 .11, d22 .12
//
// Devices register with their workstation, workstations with the cell bus; the client on
// the cell bus sees the workstations and, through them, the devices. Every process is a
// real `pnp` started inside its host and stopped by its PID.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "mdns/mdns.hpp"
#include "support/child_process.hpp"
#include "support/inbox.hpp"
#include "support/netns.hpp"
#include "ua/discovery/watcher.hpp"

namespace pnp::testing {
namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

struct Seen {
    std::string url;
    bool up;
    Clock::time_point at;
    std::set<std::string> sources;
};

const char* kDevices[] = {"d11", "d12", "d21", "d22"};

std::string deviceAddress(const std::string& d) {
    return "10.1" + d.substr(1, 1) + ".0.1" + d.substr(2, 1);
}
std::string deviceUrl(const std::string& d) { return "opc.tcp://" + deviceAddress(d) + ":4840"; }
std::string wsUrl(int k) { return "opc.tcp://10.10.0.1" + std::to_string(k) + ":4840"; }
const std::string kCellUrl = "opc.tcp://10.10.0.1:4840";

class Cell {
  public:
    Cell() {
        lab_.segment("bus");
        lab_.segment("ws1net");
        lab_.segment("ws2net");
        lab_.attach("cell", "bus", "eth0", "10.10.0.1/24");
        lab_.attach("client", "bus", "eth0", "10.10.0.100/24");
        for (int k : {1, 2}) {
            const std::string ws = "ws" + std::to_string(k);
            lab_.attach(ws, "bus", "eth0", "10.10.0.1" + std::to_string(k) + "/24");
            lab_.attach(ws, ws + "net", "eth1", "10.1" + std::to_string(k) + ".0.1/24");
            lab_.forwarding(ws);
            lab_.route("client", "10.1" + std::to_string(k) + ".0.0/24",
                       "10.10.0.1" + std::to_string(k));
        }
        for (const std::string d : kDevices) {
            const std::string k = d.substr(1, 1);
            lab_.attach(d, "ws" + k + "net", "eth0", deviceAddress(d) + "/24");
            lab_.route(d, "default", "10.1" + k + ".0.1");
        }
    }
    ~Cell() {
        stopWatcher();
        processes_.clear();  // stopped by PID before the namespaces go
    }

    // Starts `pnp args...` inside host; waits for its "listening on" line.
    ChildProcess& start(const std::string& host, std::vector<std::string> args) {
        args.insert(args.begin(), PNP_BINARY);
        if (insecure) args.push_back("--insecure");
        auto& p = processes_[host];
        p = std::make_unique<ChildProcess>();
        std::string error;
        const std::string log =
            "/tmp/pnp_discovery_" + std::to_string(::getpid()) + "_" + host + ".log";
        if (!p->start(args, log, error, lab_.host(host))) throw std::runtime_error(error);
        if (!p->waitForPrefix("listening on ", 10s, error))
            throw std::runtime_error(host + ": " + error + "\n" + p->logTail());
        return *p;
    }
    void startCell() { start("cell", {"lds", "--port", "4840", "--public-host", "10.10.0.1"}); }
    // SecurityPolicy None everywhere (no certificates): the discovery latency alone.
    bool insecure = false;
    void startWorkstation(int k) {
        const std::string ws = "ws" + std::to_string(k);
        start(ws, {"ua", "serve", "--port", "4840", "--public-host",
                   "10.10.0.1" + std::to_string(k), "--lds-me", "--name", ws});
    }
    void startDevice(const std::string& d) {
        start(d, {"ua", "serve", "--port", "4840", "--public-host", deviceAddress(d), "--name", d});
    }
    // The watcher, then the cell bus, the workstations and the devices (the natural order).
    void startEverything() {
        startWatcher();
        startCell();
        startWorkstation(1);
        startWorkstation(2);
        for (const std::string d : kDevices) startDevice(d);
    }
    ChildProcess* process(const std::string& host) {
        auto it = processes_.find(host);
        return it == processes_.end() ? nullptr : it->second.get();
    }
    void stop(const std::string& host) { processes_.erase(host); }
    void link(const std::string& host, const std::string& ifname, bool up) {
        lab_.link(host, ifname, up);
    }

    // The DiscoveryWatcher on the client host, on a thread of its own inside that namespace.
    void startWatcher() {
        watcherThread_ = std::thread([this] {
            EnterNetNs inside(lab_.host("client"));
            mdns::Mdns mdns;
            mdns.start();
            ua::discovery::WatcherConfig wc;
            wc.pollInterval = 200ms;
            ua::discovery::DiscoveryWatcher watcher(
                &mdns, wc, [this](const ua::discovery::DiscoveredServer& s, bool up) {
                    seen_.put({s.discoveryUrl, up, Clock::now(), s.sources});
                });
            watcher.start();
            std::unique_lock lock(stopMutex_);
            stopCv_.wait(lock, [this] { return stopWatcher_; });
            lock.unlock();
            watcher.stop();
            mdns.stop();
        });
    }
    void stopWatcher() {
        if (!watcherThread_.joinable()) return;
        {
            std::lock_guard lock(stopMutex_);
            stopWatcher_ = true;
        }
        stopCv_.notify_all();
        watcherThread_.join();
    }

    // Servers currently up, from the watcher's reports.
    std::set<std::string> upNow() {
        std::set<std::string> up;
        for (const auto& s : seen_.items()) {
            if (s.up)
                up.insert(s.url);
            else
                up.erase(s.url);
        }
        return up;
    }
    bool waitUp(const std::set<std::string>& urls, std::chrono::milliseconds timeout) {
        return seen_.waitFor(
            [&](const std::vector<Seen>& v) {
                std::set<std::string> up;
                for (const auto& s : v) s.up ? (void)up.insert(s.url) : (void)up.erase(s.url);
                return std::includes(up.begin(), up.end(), urls.begin(), urls.end());
            },
            timeout);
    }
    // The first report about url after `since` with the given state, or nullopt.
    std::optional<Clock::time_point> waitFor(const std::string& url, bool up,
                                             Clock::time_point since,
                                             std::chrono::milliseconds timeout) {
        std::optional<Clock::time_point> at;
        seen_.waitFor(
            [&](const std::vector<Seen>& v) {
                for (const auto& s : v)
                    if (s.url == url && s.up == up && s.at >= since) {
                        at = s.at;
                        return true;
                    }
                return false;
            },
            timeout);
        return at;
    }

  private:
    Lab lab_;
    std::map<std::string, std::unique_ptr<ChildProcess>> processes_;
    Inbox<Seen> seen_;
    std::thread watcherThread_;
    std::mutex stopMutex_;
    std::condition_variable stopCv_;
    bool stopWatcher_ = false;
};

std::set<std::string> everything() {
    std::set<std::string> all{kCellUrl, wsUrl(1), wsUrl(2)};
    for (const std::string d : kDevices) all.insert(deviceUrl(d));
    return all;
}

class DiscoveryNetns : public ::testing::Test {
  protected:
    void SetUp() override {
        if (!canCreateNetworkNamespaces())
            GTEST_SKIP() << "needs root and iproute2 (network namespaces); CI runs as root";
    }
};

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0 : v[v.size() / 2];
}
double percentile(std::vector<double> v, double p) {
    std::sort(v.begin(), v.end());
    if (v.empty()) return 0;
    std::size_t i = static_cast<std::size_t>(p * static_cast<double>(v.size() - 1) + 0.5);
    return v[std::min(i, v.size() - 1)];
}

TEST_F(DiscoveryNetns, ClientOnTheCellBusSeesWorkstationsAndTheirDevices) {
    Cell cell;
    cell.startEverything();
    EXPECT_TRUE(cell.waitUp(everything(), 10s)) << "up: " << cell.upNow().size();
}

TEST_F(DiscoveryNetns, StartOrderDoesNotChangeTheOutcome) {
    // Devices first, then workstations, then the cell bus; and cell bus last but one.
    const std::vector<std::vector<std::string>> orders = {
        {"d11", "d12", "d21", "d22", "ws1", "ws2", "cell"},
        {"ws2", "d21", "cell", "d11", "ws1", "d22", "d12"},
    };
    for (const auto& order : orders) {
        Cell cell;
        cell.startWatcher();
        for (const auto& h : order) {
            if (h == "cell")
                cell.startCell();
            else if (h[0] == 'w')
                cell.startWorkstation(h[2] - '0');
            else
                cell.startDevice(h);
        }
        EXPECT_TRUE(cell.waitUp(everything(), 10s)) << "up: " << cell.upNow().size();
    }
}

// Device process start -> visible on the cell bus, `kRuns` times: the times (ms) and the
// part until the device printed "listening on".
struct StartFigures {
    std::vector<double> visible, listening;
};
StartFigures measureDeviceStarts(bool insecure) {
    Cell cell;
    cell.insecure = insecure;
    cell.startWatcher();
    cell.startCell();
    cell.startWorkstation(1);
    cell.startWorkstation(2);
    StartFigures f;
    if (!cell.waitUp({kCellUrl, wsUrl(1), wsUrl(2)}, 10s)) {
        ADD_FAILURE() << "the cell bus and the workstations did not come up";
        return f;
    }
    constexpr int kRuns = 15;
    for (int i = 0; i < kRuns; ++i) {
        const std::string d = kDevices[i % 4];
        const auto t0 = Clock::now();
        cell.startDevice(d);
        f.listening.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        auto at = cell.waitFor(deviceUrl(d), true, t0, 5s);
        if (!at) {
            ADD_FAILURE() << d << " not visible within 5 s (run " << i << ")";
            return f;
        }
        f.visible.push_back(std::chrono::duration<double, std::milli>(*at - t0).count());
        const auto t1 = Clock::now();
        cell.stop(d);  // graceful: unregisters
        if (!cell.waitFor(deviceUrl(d), false, t1, 5s)) {
            ADD_FAILURE() << d << " not gone";
            return f;
        }
    }
    std::printf(
        "[ figures  ] %s: device process start -> visible on the cell bus (two segments "
        "away), %d runs: median %.1f ms, p95 %.1f ms, max %.1f ms\n",
        insecure ? "SecurityPolicy None" : "secured (the default)", kRuns, median(f.visible),
        percentile(f.visible, 0.95), *std::max_element(f.visible.begin(), f.visible.end()));
    std::printf(
        "[ figures  ]   of which process start -> \"listening on\" read by the test: "
        "median %.1f ms\n",
        median(f.listening));
    return f;
}

// The discovery chain's latency (mDNS, LDS-ME registration, the watcher) is asserted without
// security; the secured default adds the certificate's loading and a secured RegisterServer2
// (figure printed; issue 24's closing note).
TEST_F(DiscoveryNetns, DeviceStartToVisibleOnTheCellBus) {
    const StartFigures none = measureDeviceStarts(true);
    ASSERT_FALSE(none.visible.empty());
#ifndef PNP_SANITIZED_BUILD
    EXPECT_LT(median(none.visible), 50.0);
    EXPECT_LT(percentile(none.visible, 0.95), 150.0);
#endif
    const StartFigures secured = measureDeviceStarts(false);
    ASSERT_FALSE(secured.visible.empty());
#ifndef PNP_SANITIZED_BUILD
    EXPECT_LT(percentile(secured.visible, 0.95), 500.0);
#endif
}

TEST_F(DiscoveryNetns, UnpluggedDevicesDisappear) {
    Cell cell;
    cell.startEverything();
    ASSERT_TRUE(cell.waitUp(everything(), 10s));

    // Graceful stop: gone everywhere within 100 ms.
    auto t = Clock::now();
    cell.stop("d11");
    auto gone = cell.waitFor(deviceUrl("d11"), false, t, 3s);
    ASSERT_TRUE(gone);
    const double graceful = std::chrono::duration<double, std::milli>(*gone - t).count();

    // kill -9: within the registration expiry (2 s).
    t = Clock::now();
    cell.process("d12")->kill9();
    gone = cell.waitFor(deviceUrl("d12"), false, t, 5s);
    ASSERT_TRUE(gone);
    const double killed = std::chrono::duration<double, std::milli>(*gone - t).count();

    // The link goes down (veth down): likewise.
    t = Clock::now();
    cell.link("d21", "eth0", false);
    gone = cell.waitFor(deviceUrl("d21"), false, t, 5s);
    ASSERT_TRUE(gone);
    const double linkDown = std::chrono::duration<double, std::milli>(*gone - t).count();

    std::printf(
        "[ figures  ] gone on the cell bus: graceful stop %.1f ms, kill -9 %.1f ms, "
        "link down %.1f ms\n",
        graceful, killed, linkDown);
    // The targets hold in optimised builds; under the sanitizers (every process several
    // times slower) the same behaviour is checked with looser bounds.
#ifdef PNP_SANITIZED_BUILD
    constexpr double kGracefulMs = 1000, kCrashMs = 2500;
#else
    constexpr double kGracefulMs = 100, kCrashMs = 2000;
#endif
    EXPECT_LT(graceful, kGracefulMs);
    // Within 2 s: `pnp`'s registration expiry (1.8 s) after the last registration, which
    // came at most one interval (500 ms) before the crash, plus the LDS-ME's timer and the
    // goodbye (a few ms).
    EXPECT_LT(killed, kCrashMs);
    EXPECT_LT(linkDown, kCrashMs);

    // The others are still there.
    const auto up = cell.upNow();
    EXPECT_TRUE(up.count(deviceUrl("d22")));
    EXPECT_TRUE(up.count(wsUrl(1)));

    // The link comes back: the device registers again and reappears.
    t = Clock::now();
    cell.link("d21", "eth0", true);
    EXPECT_TRUE(cell.waitFor(deviceUrl("d21"), true, t, 5s));
}

}  // namespace
}  // namespace pnp::testing
