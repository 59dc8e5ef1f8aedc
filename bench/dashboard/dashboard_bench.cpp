// The dashboard's OPC UA side (src/dashboard CellView) on a synthetic cell, each figure next
// to a baseline measured in the same run. All in this process, on 127.0.0.1.
//
// The cell: --servers servers (default 50), each with --controllers demo components
// (default 3: 150 components) of 4 skills each (Delay, Grasp, Release, MoveGripper: 600
// skills).
//
// (1) Start -> every skill monitored: a CellView given the servers' URLs, from start() until
//     its snapshot lists every skill with its parameters (a SkillClient per skill on one
//     session per server, its state read, its transition events subscribed, its last result
//     read). Baseline: a SkillDetector alone on the same servers (connect, Browse, types)
//     until it reports every skill: what examination costs without monitoring.
// (2) Skill transition -> the dashboard's message: Delay (DurationMs 0) started on a server
//     picked in turn by a third client; t1 = the CellView publishes that skill's
//     `transition` to Running (JSON built and serialised, as a page gets it). Baseline, the
//     same transitions: a plain SkillClient subscribed to the same skill's events on its own
//     session -> its onTransition callback (the OPC UA event path alone). Both from the same
//     t0 (just before Start is called), 20 ms after the previous run of that server ended:
//     the CellView has one subscription per server for all its skills' events, so a
//     transition within one publishing interval (10 ms) of the previous message of that
//     server waits for the next publishing cycle (the price of one subscription and one
//     waiting Publish per server instead of one per skill).
// (3) A new page's snapshot (build + serialise) of the whole cell, and the process's RSS
//     growth per monitored skill. Baseline for the snapshot: serialising the same JSON alone.
//
// usage: pnp_bench_dashboard [--servers N] [--controllers K] [--runs R]
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "dashboard/cell_view.hpp"
#include "skill/client/generic_client.hpp"
#include "skill/demo/demo_skills.hpp"
#include "skill/detector/skill_detector.hpp"
#include "ua/client/client.hpp"
#include "ua/server/server.hpp"

namespace {

using namespace std::chrono_literals;
using json = nlohmann::json;
using Clock = std::chrono::steady_clock;
namespace ua = pnp::ua;

double median(std::vector<double> v) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    const std::size_t n = v.size();
    return n % 2 ? v[n / 2] : (v[n / 2 - 1] + v[n / 2]) / 2;
}
double p99(std::vector<double> v) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    const auto rank = static_cast<std::size_t>(std::ceil(0.99 * static_cast<double>(v.size())));
    return v[std::clamp<std::size_t>(rank, 1, v.size()) - 1];
}
double msSince(Clock::time_point t0, Clock::time_point t1) {
    return std::chrono::duration<double, std::milli>(t1 - t0).count();
}

long rssKiB() {
    std::ifstream f("/proc/self/status");
    std::string line;
    while (std::getline(f, line))
        if (line.rfind("VmRSS:", 0) == 0) return std::atol(line.c_str() + 6);
    return 0;
}

struct Component {
    std::unique_ptr<ua::server::Server> server;
    std::vector<std::unique_ptr<pnp::skill::server::SkillController>> controllers;
    std::string url;
};

}  // namespace

int main(int argc, char** argv) {
    int servers = 50, controllers = 3, runs = 200;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        auto next = [&]() -> int {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "%s needs a value\n", a.c_str());
                std::exit(2);
            }
            return std::atoi(argv[++i]);
        };
        if (a == "--servers")
            servers = std::clamp(next(), 1, 500);
        else if (a == "--controllers")
            controllers = std::clamp(next(), 1, 20);
        else if (a == "--runs")
            runs = std::clamp(next(), 1, 100000);
        else {
            std::fprintf(stderr,
                         "usage: pnp_bench_dashboard [--servers N] [--controllers K] [--runs R]\n");
            return a == "--help" ? 0 : 2;
        }
    }
    const std::size_t skillCount = static_cast<std::size_t>(servers * controllers * 4);
    std::printf("dashboard bench: %d servers x %d components x 4 skills = %zu skills\n", servers,
                controllers, skillCount);

    std::vector<Component> cell(static_cast<std::size_t>(servers));
    std::vector<std::string> urls;
    for (int s = 0; s < servers; ++s) {
        auto& c = cell[static_cast<std::size_t>(s)];
        ua::server::ServerConfig config;
        config.host = "127.0.0.1";
        config.publicHost = "127.0.0.1";
        config.port = 0;
        config.applicationUri = "urn:pnp:bench:dashboard:" + std::to_string(s);
        c.server = std::make_unique<ua::server::Server>(config);
        pnp::skill::demo::loadDemoModels(*c.server);
        for (int k = 0; k < controllers; ++k)
            c.controllers.push_back(pnp::skill::demo::addDemoSkills(
                *c.server, "Comp" + std::to_string(s) + "_" + std::to_string(k)));
        c.server->start();
        c.url = "opc.tcp://127.0.0.1:" + std::to_string(c.server->port());
        urls.push_back(c.url);
    }

    // (1) baseline: the detector alone.
    double detectMs = 0;
    {
        pnp::skill::detector::DetectorConfig dc;
        dc.useDiscovery = false;
        pnp::skill::detector::SkillDetector detector(nullptr, dc);
        const auto t0 = Clock::now();
        detector.start();
        for (const auto& u : urls) detector.addServer(u);
        const bool all =
            detector.waitUntil([&](const auto& d) { return d.all().size() >= skillCount; }, 120s);
        detectMs = msSince(t0, Clock::now());
        if (!all) std::printf("  detector saw only %zu skills\n", detector.all().size());
        detector.stop();
    }

    // (1) the CellView; (2) its transition messages.
    std::mutex m;
    std::condition_variable cv;
    std::string awaited;  // the skill id whose Running transition is awaited
    Clock::time_point viewAt{};
    const long rssBefore = rssKiB();
    pnp::dashboard::CellViewOptions options;
    options.discovery = false;
    options.urls = urls;
    options.maxSkills = skillCount + 100;
    pnp::dashboard::CellView view(nullptr, options, [&](std::string message) {
        if (message.find("\"transition\"") == std::string::npos) return;
        const auto j = json::parse(message, nullptr, false);
        if (!j.is_object() || j.value("type", "") != "transition" || j.value("to", "") != "Running")
            return;
        std::lock_guard lock(m);
        if (j.value("skill", "") == awaited && viewAt == Clock::time_point{}) {
            viewAt = Clock::now();
            cv.notify_all();
        }
    });
    const auto v0 = Clock::now();
    view.start();
    double monitorMs = -1;
    json snapshot;
    for (const auto until = v0 + 180s; Clock::now() < until;) {
        snapshot = view.snapshot();
        std::size_t ready = 0;
        for (const auto& s : snapshot["skills"])
            if (!s["parameters"].empty() && s["state"] != "Unknown") ++ready;
        if (ready >= skillCount) {
            monitorMs = msSince(v0, Clock::now());
            break;
        }
        std::this_thread::sleep_for(5ms);
    }
    const long rssAfter = rssKiB();
    std::printf("\n(1) start -> every skill (%zu) known\n", skillCount);
    std::printf("    CellView, monitored:        %9.1f ms\n", monitorMs);
    std::printf("    baseline SkillDetector:     %9.1f ms   ratio %.2f\n", detectMs,
                detectMs > 0 ? monitorMs / detectMs : 0.0);
    if (monitorMs < 0) {
        std::printf("    the CellView did not get every skill within 180 s\n");
        return 1;
    }

    // The Delay skills and their ids in the view.
    struct Target {
        std::string id;
        std::string url;
        ua::NodeId node;
    };
    std::vector<Target> targets;
    for (const auto& s : snapshot["skills"])
        if (s["name"] == "Delay") {
            const auto t = view.skill(s["id"].get<std::string>());
            if (t) targets.push_back({t->id, t->endpointUrl, t->node});
        }
    std::printf("\n(2) Delay Start -> transition to Running, %d runs over %zu skills\n", runs,
                targets.size());
    std::vector<double> viaView, viaClient;
    std::map<std::string, std::shared_ptr<ua::client::Client>> sessions;  // the runner's
    std::map<std::string, std::shared_ptr<ua::client::Client>> watchers;  // the baseline's
    for (int r = 0; r < runs && !targets.empty(); ++r) {
        const Target& t = targets[static_cast<std::size_t>(r) % targets.size()];
        auto session = [&](auto& map) {
            auto& c = map[t.url];
            if (!c) {
                c = std::make_shared<ua::client::Client>();
                c->connect(t.url);
                c->startBackgroundThread();
            }
            return c;
        };
        pnp::skill::client::GenericSkillClient runner(session(sessions), t.node, 5s);
        pnp::skill::client::GenericSkillClient watcher(session(watchers), t.node, 5s);
        Clock::time_point clientAt{};
        watcher.onTransition([&](const pnp::skill::client::Transition& tr) {
            if (tr.to != pnp::skill::ProgramState::Running) return;
            std::lock_guard lock(m);
            if (clientAt == Clock::time_point{}) clientAt = Clock::now();
            cv.notify_all();
        });
        runner.setParameter("DurationMs", ua::Variant(0.0), 5s);
        {
            std::lock_guard lock(m);
            awaited = t.id;
            viewAt = {};
        }
        // The subscriptions' Publish requests are waiting, and the last message of this
        // server's shared subscription (the previous run's end) is one publishing interval
        // (10 ms) old: a transition within 10 ms of the previous one of the same server waits
        // for the next publishing cycle, up to 10 ms (see the note printed below).
        std::this_thread::sleep_for(20ms);
        const auto t0 = Clock::now();
        runner.start(5s);
        std::unique_lock lock(m);
        const bool both = cv.wait_for(lock, 5s, [&] {
            return viewAt != Clock::time_point{} && clientAt != Clock::time_point{};
        });
        if (both) {
            viaView.push_back(msSince(t0, viewAt));
            viaClient.push_back(msSince(t0, clientAt));
        }
        awaited.clear();
        lock.unlock();
        // Until the run ended: the next Start finds it Ready.
        for (int i = 0; i < 200 && runner.state(5s) != pnp::skill::ProgramState::Ready; ++i)
            std::this_thread::sleep_for(2ms);
    }
    const double mv = median(viaView), mc = median(viaClient);
    std::printf("    samples %zu of %d\n", viaView.size(), runs);
    std::printf("    CellView message:           median %7.2f ms  p99 %7.2f ms\n", mv,
                p99(viaView));
    std::printf("    baseline SkillClient event: median %7.2f ms  p99 %7.2f ms   ratio %.2f\n", mc,
                p99(viaClient), mc > 0 ? mv / mc : 0.0);

    // (3) the snapshot of a new page, and the memory per monitored skill.
    std::vector<double> build, serialiseOnly;
    std::size_t bytes = 0;
    for (int i = 0; i < 50; ++i) {
        const auto t0 = Clock::now();
        const std::string text = view.snapshot().dump();
        const auto t1 = Clock::now();
        bytes = text.size();
        const json parsed = json::parse(text);
        const auto t2 = Clock::now();
        const std::string again = parsed.dump();
        const auto t3 = Clock::now();
        build.push_back(msSince(t0, t1));
        serialiseOnly.push_back(msSince(t2, t3));
    }
    std::printf("\n(3) a page's snapshot of the whole cell: %zu bytes\n", bytes);
    std::printf("    build + serialise:          median %7.2f ms\n", median(build));
    std::printf("    baseline serialise alone:   median %7.2f ms   ratio %.2f\n",
                median(serialiseOnly),
                median(serialiseOnly) > 0 ? median(build) / median(serialiseOnly) : 0.0);
    std::printf(
        "    RSS growth monitoring %zu skills (the CellView and, in this same process, the "
        "servers' sessions): %ld KiB (%.1f KiB per skill)\n",
        skillCount, rssAfter - rssBefore,
        static_cast<double>(rssAfter - rssBefore) / static_cast<double>(skillCount));
    view.stop();
    for (auto& [url, c] : sessions) c->disconnect();
    for (auto& [url, c] : watchers) c->disconnect();
    for (auto& c : cell) c.server->stop();
    return 0;
}
