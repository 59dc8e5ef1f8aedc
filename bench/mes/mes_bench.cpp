// The semantic MES's own cost (issue target: dispatch of a step — knowledge base queries and
// skill choice, before Start — median ≤ 5 ms). One process, all on 127.0.0.1: a device with a
// Delay skill (0 ms: the step itself costs nothing), the MES with the repository's knowledge
// base plus a process of N such steps, run R times through ExecuteProcess. Printed: the
// median dispatch per step and the median gap between one step's end and the next one's
// start (from the steps' transition events), next to the same Delay run back to back by one
// generic skill client (lock, write, start, wait, unlock: the floor any MES pays).
//   pnp_bench_mes [steps=20] [runs=10]
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "mes/mes.hpp"
#include "mes/process.hpp"
#include "skill/client/generic_client.hpp"
#include "skill/demo/demo_skills.hpp"
#include "skill/server/controller.hpp"

using namespace pnp;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

namespace {

double median(std::vector<double> v) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

ua::server::ServerConfig loopback(const std::string& uri) {
    ua::server::ServerConfig c;
    c.host = "127.0.0.1";
    c.port = 0;
    c.applicationUri = uri;
    c.applicationName = uri;
    return c;
}

std::string url(const ua::server::Server& s) {
    return "opc.tcp://127.0.0.1:" + std::to_string(s.port());
}

}  // namespace

int main(int argc, char** argv) {
    const int steps = argc > 1 ? std::max(2, std::atoi(argv[1])) : 20;
    const int runs = argc > 2 ? std::max(1, std::atoi(argv[2])) : 10;

    // The process: N Delay steps of 0 ms.
    std::string ttl =
        "@prefix pnp: <urn:pnp:kb#> .\n@prefix proc: <urn:pnp:kb:process#> .\n"
        "@prefix demo: <urn:pnp:ua:skills:demo#> .\nproc:bench a pnp:Process .\n";
    for (int i = 1; i <= steps; ++i)
        ttl += "proc:bench-" + std::to_string(i) +
               " a pnp:Step ; pnp:process proc:bench ; pnp:index " + std::to_string(i) +
               " ; pnp:skillType demo:DelaySkillType ; pnp:binding [ pnp:name \"DurationMs\" ; "
               "pnp:value \"0\" ] .\n";
    const std::string file = "/tmp/pnp_bench_mes_" + std::to_string(::getpid()) + ".ttl";
    std::ofstream(file) << ttl;
    auto kb = std::make_shared<mes::SharedKb>(kb::open(""));
    auto files = mes::defaultKnowledgeFiles();
    files.emplace_back(file);
    mes::loadKnowledge(*kb, files, Clock::now() + 30s);
    std::remove(file.c_str());

    ua::server::Server device(loopback("urn:pnp:bench:station"));
    auto demo = skill::demo::addDemoSkills(device, "Station");
    device.start();
    ua::server::Server mesServer(loopback("urn:pnp:bench:mes"));
    mes::MesOptions o;
    o.detector.useDiscovery = false;
    o.log = [](const std::string&) {};
    mes::Mes theMes(mesServer, kb, o);
    mesServer.start();
    theMes.start();
    theMes.detector().addServer(url(device));
    if (!theMes.detector().waitUntil([](const auto& d) { return !d.all().empty(); }, 5s)) {
        std::fprintf(stderr, "the MES did not detect the device\n");
        return 1;
    }
    std::this_thread::sleep_for(200ms);  // the feed's inserts

    auto connection = std::make_shared<ua::client::Client>();
    connection->connect(url(mesServer));
    skill::client::GenericSkillClient execute(connection, theMes.skills().front().node(),
                                              Clock::now() + 5s);
    std::vector<double> dispatch, gaps;
    for (int r = 0; r < runs; ++r) {
        auto res =
            execute.run(execute.parse({"ProcessIri=urn:pnp:kb:process#bench"}), Clock::now() + 60s);
        if (res.result != skill::SkillResult::Completed) {
            std::fprintf(stderr, "run %d: %s\n", r, res.message.c_str());
            return 1;
        }
        const auto record = nlohmann::json::parse(theMes.lastRecord());
        for (const auto& s : record["steps"]) {
            if (s.contains("dispatchMs")) dispatch.push_back(s["dispatchMs"].get<double>());
            if (s.contains("overheadMs")) gaps.push_back(s["overheadMs"].get<double>());
        }
    }

    // Baseline: the Delay run back to back by one client, gap between end and next start.
    auto direct = std::make_shared<ua::client::Client>();
    direct->connect(url(device));
    ua::NodeId delayNode;
    for (const auto& s : theMes.detector().all())
        if (s.name == "Delay") delayNode = s.node;
    skill::client::GenericSkillClient delay(direct, delayNode, Clock::now() + 5s);
    const auto params = delay.parse({"DurationMs=0"});
    std::vector<double> directGaps, directRun;
    ua::DateTime previousEnd{};
    for (int i = 0; i < steps * runs; ++i) {
        const auto t0 = Clock::now();
        auto res = delay.run(params, Clock::now() + 10s);
        directRun.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        ua::DateTime start{}, end{};
        for (const auto& t : res.transitions) {
            if (t.to == skill::ProgramState::Running && start.ticks == 0) start = t.time;
            if (t.from == skill::ProgramState::Running) end = t.time;
        }
        if (previousEnd.ticks != 0 && start.ticks != 0)
            directGaps.push_back(static_cast<double>(start.ticks - previousEnd.ticks) / 1e4);
        previousEnd = end;
    }
    std::printf("MES, %d steps x %d runs (Delay 0 ms):\n", steps, runs);
    std::printf(
        "  dispatch of a step (KB queries + skill choice, before Start): median %.3f ms "
        "(target <= 5 ms)\n",
        median(dispatch));
    std::printf("  end of a step -> start of the next (events):               median %.3f ms\n",
                median(gaps));
    std::printf("baseline, the same skill run back to back by one client:\n");
    std::printf("  end of a run -> start of the next (events):                median %.3f ms\n",
                median(directGaps));
    std::printf("  one run() (lock, write, start, wait, unlock):              median %.3f ms\n",
                median(directRun));
    return 0;
}
