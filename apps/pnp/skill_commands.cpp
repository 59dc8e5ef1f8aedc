// `pnp skills` and `pnp skill run` (docs/skills.md): the skill detector and the generic skill
// client on the command line.
#include <signal.h>
#include <time.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <iostream>
#include <map>
#include <mutex>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include "commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"
#include "skill/client/generic_client.hpp"
#include "skill/detector/skill_detector.hpp"
#include "ua/types/ns0_enums.hpp"
#include "value_text.hpp"

namespace pnp::cli {

namespace {

using skill::detector::DetectedSkill;
using skill::detector::ServerState;
using skill::detector::SkillDetector;

Json toJson(const DetectedSkill& s) {
    Json chain = Json::array();
    for (const auto& t : s.typeChain) chain.push_back(t.name);
    return {{"type", s.type.name},
            {"typeUri", s.type.uri},
            {"name", s.name},
            {"url", s.endpointUrl},
            {"node", s.nodeText},
            {"component", s.controllerName},
            {"application", s.componentName},
            {"applicationUri", s.componentUri},
            {"typeChain", chain}};
}

skill::ModelNode typeOrThrow(const std::string& name) {
    if (auto t = skill::typeByName(name)) return *t;
    std::string known;
    for (const auto& t : skill::knownTypes())
        known += (known.empty() ? "" : ", ") + std::string(t.name);
    throw UsageError("unknown skill type " + name + " (known: " + known + ")");
}

// mDNS unless --no-mdns; without it (or when it cannot start) only LDS-MEs / URLs are used.
std::unique_ptr<mdns::Mdns> startMdns(bool noMdns, const std::vector<std::string>& interfaces,
                                      int port, bool haveOtherSources, const char* who) {
    if (noMdns) return nullptr;
    try {
        auto m = std::make_unique<mdns::Mdns>(mdnsConfig(interfaces, port, 120));
        m->start();
        return m;
    } catch (const std::exception& e) {
        if (!haveOtherSources) throw;
        std::cerr << who << ": no mDNS (" << e.what() << ")" << std::endl;
        return nullptr;
    }
}

void waitForStop(const sigset_t& stopSignals, int durationMs) {
    if (durationMs > 0) {
        timespec ts{durationMs / 1000, (durationMs % 1000) * 1'000'000L};
        while (sigtimedwait(&stopSignals, nullptr, &ts) < 0 && errno == EINTR) {
        }
    } else {
        int sig = 0;
        while (sigwait(&stopSignals, &sig) != 0) {
        }
    }
}

// `pnp skills --once` without --duration: discovery has had time to list the servers (2 s)
// and none of them is still being examined — a secured connect on a loaded machine can take
// longer than the 2 s a fixed wait allowed — within 15 s at most, or until Ctrl-C.
void waitUntilSettled(const SkillDetector& detector, const sigset_t& stopSignals) {
    using namespace std::chrono;
    const auto t0 = steady_clock::now();
    const auto settled = [&] {
        if (steady_clock::now() - t0 < 2s) return false;
        const auto servers = detector.servers();
        return std::none_of(servers.begin(), servers.end(), [](const ServerState& s) {
            return s.status == ServerState::Status::Examining;
        });
    };
    for (int i = 0; i < 150 && !settled(); ++i) {
        timespec ts{0, 100'000'000L};
        if (sigtimedwait(&stopSignals, nullptr, &ts) > 0) return;
    }
}

std::string stateName(skill::ProgramState s) { return std::string(skill::toString(s)); }

}  // namespace

int runSkills(const SkillsOptions& o) {
    const sigset_t stopSignals = blockStopSignals();
    std::optional<skill::ModelNode> only;
    if (!o.type.empty()) only = typeOrThrow(o.type);
    if (o.noMdns && o.lds.empty() && o.urls.empty())
        throw UsageError("--no-mdns needs an --lds or --url");
    secureClients(o.security);
    std::unique_ptr<mdns::Mdns> mdns;
    try {
        mdns = startMdns(o.noMdns, o.mdnsInterfaces, o.mdnsPort, !o.lds.empty() || !o.urls.empty(),
                         "pnp skills");
    } catch (const std::exception& e) {
        std::cerr << "error: mDNS: " << e.what() << "\n";
        return kExitUaError;
    }
    skill::detector::DetectorConfig config;
    config.watcher.ldsUrls = o.lds;
    config.useDiscovery = mdns != nullptr || !o.lds.empty();
    SkillDetector detector(mdns.get(), config);
    std::mutex printMutex;
    const auto t0 = std::chrono::steady_clock::now();
    detector.onChange([&](const DetectedSkill& s, bool added) {
        if (o.once || (only && !s.isA(*only))) return;
        std::lock_guard lock(printMutex);
        if (o.json) {
            Json j = toJson(s);
            j["event"] = added ? "added" : "removed";
            j["ms"] =
                std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                    .count();
            std::cout << j.dump() << std::endl;
        } else {
            std::cout << (added ? "+ " : "- ") << s.type.name << "  " << s.controllerName << "/"
                      << s.name << "  " << s.endpointUrl << "  " << s.nodeText << std::endl;
        }
    });
    detector.start();
    for (const auto& url : o.urls) detector.addServer(url);
    if (o.once && o.durationMs <= 0)
        waitUntilSettled(detector, stopSignals);
    else
        waitForStop(stopSignals, o.durationMs);
    auto skills = only ? detector.find(*only) : detector.all();
    detector.stop();
    if (o.once) {
        std::sort(skills.begin(), skills.end(), [](const auto& a, const auto& b) {
            return std::tie(a.endpointUrl, a.controllerName, a.name) <
                   std::tie(b.endpointUrl, b.controllerName, b.name);
        });
        if (o.json) {
            Json arr = Json::array();
            for (const auto& s : skills) arr.push_back(toJson(s));
            std::cout << arr.dump(2) << std::endl;
        } else {
            Table t({"TYPE", "SKILL", "COMPONENT", "URL", "NODE"});
            for (const auto& s : skills)
                t.add({s.type.name, s.name, s.controllerName, s.endpointUrl, s.nodeText});
            t.print(std::cout);
        }
    }
    return kExitOk;
}

namespace {

// `pnp skill run --repeat N`: N runs in a row, each with its own deadline (the first one's is
// the command's, which also covered finding the skill), then a summary.
int repeatRuns(const SkillRunOptions& o, const DetectedSkill& target,
               skill::client::GenericSkillClient& skill, const skill::client::NamedValues& params,
               std::chrono::steady_clock::time_point firstDeadline, std::stop_token cancel) {
    using namespace std::chrono;
    std::map<std::string, int> results;  // Completed / Failed / Aborted / TimedOut / ...
    std::vector<double> ms;
    ms.reserve(static_cast<std::size_t>(o.repeat));
    std::string firstProblem;
    for (int i = 0; i < o.repeat && !cancel.stop_requested(); ++i) {
        const auto t0 = steady_clock::now();
        const auto deadline = i == 0 ? firstDeadline : t0 + milliseconds(o.timeoutMs);
        skill::client::RunResult r = skill.run(params, deadline, cancel);
        ms.push_back(duration<double, std::milli>(steady_clock::now() - t0).count());
        const std::string result = r.timedOut ? "TimedOut" : std::string(skill::toString(r.result));
        ++results[result];
        if (result != "Completed" && firstProblem.empty())
            firstProblem = "run " + std::to_string(i + 1) + ": " + result +
                           (r.message.empty() ? "" : ": " + r.message);
    }
    std::sort(ms.begin(), ms.end());
    auto rank = [&](double q) {
        const auto k = static_cast<std::size_t>(q * static_cast<double>(ms.size()) + 0.999999);
        return ms[std::min(ms.size(), std::max<std::size_t>(k, 1)) - 1];
    };
    const double median =
        ms.size() % 2 ? ms[ms.size() / 2] : (ms[ms.size() / 2 - 1] + ms[ms.size() / 2]) / 2;
    if (ms.empty()) return kExitSkillFailed;  // interrupted before the first run
    const int runs = static_cast<int>(ms.size());
    const bool ok = results["Completed"] == o.repeat;
    if (o.json) {
        Json j = toJson(target);
        j["runs"] = runs;
        Json counts = Json::object();
        for (const auto& [name, n] : results)
            if (n > 0) counts[name] = n;
        j["results"] = counts;
        j["durationMs"] = {{"median", median}, {"p99", rank(0.99)}, {"max", ms.back()}};
        if (!firstProblem.empty()) j["firstProblem"] = firstProblem;
        std::cout << j.dump(2) << std::endl;
    } else {
        std::cout << runs << " runs:";
        const char* sep = " ";
        for (const auto& [name, n] : results)
            if (n > 0) {
                std::cout << sep << n << " " << name;
                sep = ", ";
            }
        auto text = [](double x) {
            char b[32];
            std::snprintf(b, sizeof b, "%.3f ms", x);
            return std::string(b);
        };
        std::cout << "; duration median " << text(median) << ", p99 " << text(rank(0.99))
                  << ", max " << text(ms.back()) << std::endl;
        if (!firstProblem.empty()) std::cout << "first problem: " << firstProblem << std::endl;
    }
    return ok ? kExitOk : kExitSkillFailed;
}

}  // namespace

int runSkillRun(const SkillRunOptions& o) {
    using namespace std::chrono;
    // Ctrl-C (or a supervisor's SIGTERM) halts the skill and unlocks it instead of leaving
    // the robot moving under a lock nobody renews.
    StopOnSignal interrupt;
    const bool byUrl = o.target.starts_with("opc.tcp://");
    std::optional<skill::ModelNode> type;
    if (!byUrl) type = typeOrThrow(o.target);
    secureClients(o.security);
    const auto deadline = steady_clock::now() + milliseconds(o.timeoutMs);

    // Find the skill: on the given server, or by type on the network.
    std::unique_ptr<mdns::Mdns> mdns;
    if (!byUrl) {
        try {
            mdns = startMdns(o.noMdns, {}, o.mdnsPort, !o.lds.empty(), "pnp skill run");
        } catch (const std::exception& e) {
            std::cerr << "error: mDNS: " << e.what() << "\n";
            return kExitUaError;
        }
        if (!mdns && o.lds.empty()) throw UsageError("--no-mdns needs an --lds URL");
    }
    skill::detector::DetectorConfig config;
    config.watcher.ldsUrls = o.lds;
    config.useDiscovery = !byUrl;
    SkillDetector detector(mdns.get(), config);
    detector.start();
    if (byUrl) detector.addServer(o.target);
    auto matching = [&](const SkillDetector& d) {
        std::vector<DetectedSkill> out;
        for (auto& s : type ? d.find(*type) : d.all())
            if (o.skill.empty() || s.name == o.skill) out.push_back(std::move(s));
        return out;
    };
    detector.waitUntil(
        [&](const SkillDetector& d) {
            if (!matching(d).empty()) return true;
            if (!byUrl) return false;
            auto servers = d.servers();
            return !servers.empty() &&
                   servers.front().status != skill::detector::ServerState::Status::Examining;
        },
        milliseconds(byUrl ? o.timeoutMs : std::min(o.discoverMs, o.timeoutMs)));
    auto candidates = matching(detector);
    auto servers = detector.servers();
    detector.stop();
    if (candidates.empty()) {
        std::string why =
            byUrl ? "no skill" + (o.skill.empty() ? "" : " named " + o.skill) + " on " + o.target
                  : "no skill of type " + std::string(type->name) + " found";
        if (byUrl && !servers.empty() && !servers.front().error.empty())
            why += " (" + servers.front().error + ")";
        std::cerr << "error: " << why << "\n";
        return kExitUaError;
    }
    if (byUrl && candidates.size() > 1 && o.skill.empty()) {
        std::string names;
        for (const auto& s : candidates) names += (names.empty() ? "" : ", ") + s.name;
        throw UsageError("the server has several skills (" + names + "): choose one with --skill");
    }
    const DetectedSkill target = candidates.front();

    auto connection = std::make_shared<ua::client::Client>();
    connection->connect(target.endpointUrl, ua::client::Anonymous{}, deadline);
    skill::client::GenericSkillClient skill(connection, target.node, deadline);
    skill::client::NamedValues params;
    try {
        params = skill.parse(o.assignments);
    } catch (const ua::client::Error& e) {
        throw UsageError(e.what());
    }
    if (!o.json)
        std::cout << "running " << target.controllerName << "/" << target.name << " ("
                  << target.type.name << ") on " << target.endpointUrl << std::endl;
    if (o.repeat > 1) return repeatRuns(o, target, skill, params, deadline, interrupt.token());
    skill::client::RunResult r = skill.run(params, deadline, interrupt.token());

    const bool ok = r.result == skill::SkillResult::Completed && !r.timedOut;
    if (o.json) {
        Json transitions = Json::array();
        for (const auto& t : r.transitions) {
            Json j = {{"number", t.number},
                      {"name", t.name},
                      {"from", stateName(t.from)},
                      {"to", stateName(t.to)},
                      {"time", dateTimeText(t.time)}};
            if (!t.message.empty()) j["message"] = t.message;
            if (!t.intermediateResult.isEmpty())
                j["intermediateResult"] = toJson(t.intermediateResult);
            transitions.push_back(j);
        }
        Json results = Json::object();
        for (const auto& [name, v] : r.finalResult.values) results[name] = toJson(v);
        Json j = toJson(target);
        j["result"] = std::string(skill::toString(r.result));
        j["message"] = r.message;
        j["timedOut"] = r.timedOut;
        j["transitions"] = transitions;
        j["finalResultData"] = results;
        std::cout << j.dump(2) << std::endl;
    } else {
        for (const auto& t : r.transitions) {
            std::cout << "  " << dateTimeText(t.time) << "  " << stateName(t.from) << " -> "
                      << stateName(t.to) << "  (" << t.number << " " << t.name << ")";
            if (!t.intermediateResult.isEmpty())
                std::cout << "  progress " << toText(t.intermediateResult);
            if (!t.message.empty() && t.to == skill::ProgramState::Halted)
                std::cout << "  " << t.message;
            std::cout << std::endl;
        }
        std::cout << (r.timedOut ? "TimedOut" : std::string(skill::toString(r.result)));
        if (!ok && !r.message.empty()) std::cout << ": " << r.message;
        std::cout << std::endl;
        for (const auto& [name, v] : r.finalResult.values)
            std::cout << "  " << name << " = " << toText(v) << std::endl;
    }
    return ok ? kExitOk : kExitSkillFailed;
}

}  // namespace pnp::cli
