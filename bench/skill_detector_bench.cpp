// Skill detector: plug-in of a skill server -> its skill visible in the detector. Each run
// starts a server (the demo component of skill/demo: models loaded from models/, a
// SkillController with Delay, Grasp, Release, MoveGripper), registers it with an LDS (Registrar,
// configured URL) and measures until the detector's change callback reports the Delay skill. Next
// to it, in the same run, a bare DiscoveryWatcher polling the same LDS at the same interval: the
// discovery floor, so the difference is the detector's own examination. All on 127.0.0.1, one
// process.
//
// usage: pnp_bench_skill_detector [--runs R] [--poll MS]
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "skill/demo/demo_skills.hpp"
#include "skill/detector/skill_detector.hpp"
#include "ua/discovery/registrar.hpp"
#include "ua/discovery/watcher.hpp"
#include "ua/server/server.hpp"

using namespace pnp;
using namespace pnp::skill;
using Clock = std::chrono::steady_clock;

namespace {

ua::server::ServerConfig loopback() {
    ua::server::ServerConfig c;
    c.host = c.publicHost = "127.0.0.1";
    c.port = 0;
    return c;
}

struct Stats {
    double median = 0, p95 = 0, max = 0;
};
Stats stats(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    if (v.empty()) return {};
    return {v[v.size() / 2], v[std::min(v.size() - 1, v.size() * 95 / 100)], v.back()};
}

double since(Clock::time_point t0, const std::atomic<Clock::rep>& at) {
    return std::chrono::duration<double, std::milli>(Clock::duration(at.load()) -
                                                     t0.time_since_epoch())
        .count();
}

}  // namespace

int main(int argc, char** argv) {
    int runs = 30, pollMs = 10;
    for (int i = 1; i + 1 < argc; i += 2) {
        std::string a = argv[i];
        if (a == "--runs") runs = std::max(1, std::atoi(argv[i + 1]));
        if (a == "--poll") pollMs = std::max(1, std::atoi(argv[i + 1]));
    }

    auto ldsCfg = loopback();
    ldsCfg.applicationUri = "urn:pnp:bench:lds";
    ldsCfg.discovery.localDiscoveryServer = true;
    ua::server::Server lds(ldsCfg);
    lds.start();
    const std::string ldsUrl = "opc.tcp://127.0.0.1:" + std::to_string(lds.port());

    ua::discovery::WatcherConfig wc;
    wc.ldsUrls = {ldsUrl};
    wc.pollInterval = std::chrono::milliseconds(pollMs);

    std::atomic<Clock::rep> skillAt{0}, watcherAt{0};
    std::atomic<bool> armed{false};
    detector::DetectorConfig dc;
    dc.watcher = wc;
    dc.healthInterval = std::chrono::milliseconds(50);
    detector::SkillDetector det(nullptr, dc);
    det.onChange([&](const detector::DetectedSkill& s, bool added) {
        if (added && armed && s.isA(types::DelaySkillType))
            skillAt = Clock::now().time_since_epoch().count();
    });
    det.start();
    // The floor: discovery alone (poll + GetEndpoints), same LDS, same interval.
    ua::discovery::DiscoveryWatcher bare(
        nullptr, wc, [&](const ua::discovery::DiscoveredServer& s, bool up) {
            if (up && armed && s.discoveryUrl != ldsUrl)
                watcherAt = Clock::now().time_since_epoch().count();
        });
    bare.start();

    std::vector<double> visible, floor, examine;
    for (int r = 0; r < runs; ++r) {
        auto cfg = loopback();
        cfg.applicationUri = "urn:pnp:bench:gripper" + std::to_string(r);
        ua::server::Server srv(cfg);
        demo::loadDemoModels(srv);
        auto component = demo::addDemoSkills(srv, "Gripper");
        skillAt = watcherAt = 0;
        armed = true;
        auto t0 = Clock::now();
        srv.start();
        ua::discovery::RegistrarConfig rc;
        rc.ldsUrl = ldsUrl;
        ua::discovery::Registrar reg(srv, nullptr, rc);
        reg.start();
        auto limit = t0 + std::chrono::seconds(5);
        while ((skillAt == 0 || watcherAt == 0) && Clock::now() < limit)
            std::this_thread::sleep_for(std::chrono::microseconds(200));
        armed = false;
        if (skillAt == 0 || watcherAt == 0) {
            std::fprintf(stderr, "run %d: not visible within 5 s\n", r);
            return 1;
        }
        visible.push_back(since(t0, skillAt));
        floor.push_back(since(t0, watcherAt));
        for (const auto& s : det.servers())
            if (s.applicationUri == cfg.applicationUri) examine.push_back(s.examineMs);
        reg.stop();
        srv.stop();
        component.reset();  // before the server
        // Unplugged: wait until the detector dropped it, so runs do not overlap.
        det.waitUntil([](const detector::SkillDetector& d) { return d.all().empty(); },
                      std::chrono::seconds(5));
    }
    bare.stop();
    det.stop();
    lds.stop();

    auto v = stats(visible), f = stats(floor), e = stats(examine);
    std::printf("pnp_bench_skill_detector: %d plug-ins, LDS poll %d ms, 127.0.0.1\n", runs, pollMs);
    std::printf("%-52s %10s %10s %10s\n", "", "median ms", "p95 ms", "max ms");
    auto row = [](const char* name, const Stats& s) {
        std::printf("%-52s %10.2f %10.2f %10.2f\n", name, s.median, s.p95, s.max);
    };
    row("start -> seen by a bare DiscoveryWatcher (baseline)", f);
    row("start -> skill visible in the SkillDetector", v);
    row("examination (connect + walk) per server", e);
    return 0;
}
