// The semantic MES on the command line (src/mes/README.md):
//   `pnp mes [--kb LOCATION] [--kb-file F.ttl]...`: the MES server with ExecuteProcess,
//     fed by the skill detector, until SIGINT / SIGTERM;
//   `pnp mes run IRI [--mes URL]`: runs a process on a running MES (ExecuteProcess) and
//     prints its execution record.
#include <signal.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <filesystem>
#include <functional>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "commands.hpp"
#include "device_commands.hpp"
#include "discovery_commands.hpp"
#include "mes/mes.hpp"
#include "mes/process.hpp"
#include "output.hpp"
#include "skill/client/generic_client.hpp"
#include "skill/detector/skill_detector.hpp"

namespace pnp::cli {

namespace {

struct MesCliOptions {
    std::string kb;                    // "" = embedded
    std::vector<std::string> kbFiles;  // empty: models/kb/*.ttl
    std::string componentName = "MES";
    std::string recordFile;
    bool noMdns = false;
    int findTimeoutMs = 5000;
    int stepTimeoutS = 600;
    ServeOptions serve;
};

struct MesRunOptions {
    std::string process;
    std::string mes = "opc.tcp://127.0.0.1:4860";
    int timeoutS = 1800;
    bool json = false;
    SecurityOptions security;
};

int runMes(MesCliOptions& o) {
    if (o.serve.discovery.name.empty()) o.serve.discovery.name = "Semantic MES";
    const sigset_t stopSignals = blockStopSignals();
    std::shared_ptr<mes::SharedKb> kb;
    try {
        kb = std::make_shared<mes::SharedKb>(kb::open(o.kb));
        std::vector<std::filesystem::path> files(o.kbFiles.begin(), o.kbFiles.end());
        if (files.empty()) files = mes::defaultKnowledgeFiles();
        mes::loadKnowledge(*kb, files, std::chrono::steady_clock::now() + std::chrono::seconds(60));
        std::cerr << "pnp mes: knowledge base " << kb->describe() << " with " << files.size()
                  << " Turtle files and the skill types of the models" << std::endl;
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        return kExitUsage;
    }
    std::unique_ptr<mdns::Mdns> mdns = componentMdns(o.noMdns, o.serve, "pnp mes");
    mes::MesOptions mopt;
    mopt.name = o.componentName;
    mopt.recordFile = o.recordFile;
    mopt.findTimeout = std::chrono::milliseconds(o.findTimeoutMs);
    mopt.stepTimeout = std::chrono::seconds(o.stepTimeoutS);
    if (!o.serve.discovery.lds.empty()) mopt.detector.watcher.ldsUrls = {o.serve.discovery.lds};
    mopt.detector.useDiscovery = mdns != nullptr || !o.serve.discovery.lds.empty();
    return serveUntilStopped(
        o.serve, stopSignals, "pnp mes",
        [&](ua::server::Server& server) {
            return std::make_unique<mes::Mes>(server, kb, mopt, mdns.get());
        },
        [&](mes::Mes&, const std::string& discoveryStatus) {
            std::cerr << "pnp mes: DeviceSet/" << o.componentName
                      << " with ExecuteProcess(ProcessIri); " << discoveryStatus
                      << "; stop with Ctrl-C or SIGTERM" << std::endl;
        });
}

int runMesProcess(const MesRunOptions& o) {
    using namespace std::chrono;
    const auto deadline = steady_clock::now() + seconds(o.timeoutS);
    secureClients(o.security);
    skill::detector::DetectorConfig config;
    config.useDiscovery = false;
    skill::detector::SkillDetector detector(nullptr, config);
    detector.start();
    detector.addServer(o.mes);
    const auto& type = skill::types::ExecuteProcessSkillType;
    detector.waitUntil(
        [&](const skill::detector::SkillDetector& d) {
            if (!d.find(type).empty()) return true;
            auto s = d.servers();
            return !s.empty() &&
                   s.front().status != skill::detector::ServerState::Status::Examining;
        },
        seconds(10));
    auto found = detector.find(type);
    auto servers = detector.servers();
    detector.stop();
    if (found.empty()) {
        std::cerr << "error: no ExecuteProcess skill on " << o.mes
                  << (servers.empty() || servers.front().error.empty()
                          ? std::string()
                          : " (" + servers.front().error + ")")
                  << "\n";
        return kExitUaError;
    }
    auto connection = std::make_shared<ua::client::Client>();
    connection->connect(found.front().endpointUrl, ua::client::Anonymous{}, deadline);
    skill::client::GenericSkillClient skill(connection, found.front().node, deadline);
    // Ctrl-C halts the process (and the MES halts the step it runs) before we go.
    static std::stop_source stop;
    ::signal(SIGINT, [](int) { stop.request_stop(); });
    ::signal(SIGTERM, [](int) { stop.request_stop(); });
    if (!o.json) std::cerr << "running " << o.process << " on " << o.mes << std::endl;
    const auto r = skill.run(skill.parse({"ProcessIri=" + o.process}), deadline, stop.get_token());
    std::string record;
    for (const auto& [name, v] : r.finalResult.values)
        if (name == "Record")
            if (const auto* s = v.scalar<ua::String>()) record = *s;
    const bool ok = r.result == skill::SkillResult::Completed && !r.timedOut;
    if (o.json) {
        std::cout << (record.empty() ? "{}" : record) << std::endl;
    } else if (!record.empty()) {
        const auto j = nlohmann::json::parse(record, nullptr, false);
        for (const auto& s : j.value("steps", nlohmann::json::array())) {
            std::cout << "  " << s.value("index", 0) << ". " << s.value("label", "") << ": "
                      << s.value("skill", "?") << " on " << s.value("componentName", "?") << " — "
                      << s.value("result", "?");
            if (s.contains("durationS"))
                std::cout << " in " << s["durationS"].get<double>() << " s";
            if (!s.value("message", "").empty() && s.value("result", "") != "Completed")
                std::cout << ": " << s.value("message", "");
            std::cout << std::endl;
        }
    }
    if (!o.json) {
        std::cout << (r.timedOut ? "TimedOut" : std::string(skill::toString(r.result)));
        if (!ok && !r.message.empty()) std::cout << ": " << r.message;
        std::cout << std::endl;
    }
    return ok ? kExitOk : kExitSkillFailed;
}

}  // namespace

std::function<int()> addMesCommands(CLI::App& app) {
    auto o = std::make_shared<MesCliOptions>();
    auto r = std::make_shared<MesRunOptions>();
    o->serve.port = 4860;
    CLI::App* cmd = app.add_subcommand(
        "mes",
        "the semantic MES: ExecuteProcess runs a process of the knowledge base with the skills "
        "the detector finds (src/mes/README.md)");
    cmd->require_subcommand(0, 1);
    cmd->add_option("--kb", o->kb,
                    "the knowledge base: embedded (default) or a SPARQL 1.1 endpoint URL "
                    "http://HOST:PORT/sparql");
    cmd->add_option("--kb-file", o->kbFiles,
                    "Turtle files to load (repeatable; default: the repository's models/kb/*.ttl)");
    cmd->add_option("--record", o->recordFile, "append each execution record (JSON) to FILE");
    cmd->add_option("--component-name", o->componentName, "BrowseName below DeviceSet")
        ->capture_default_str();
    cmd->add_flag("--no-mdns", o->noMdns, "find skills only through --lds");
    cmd->add_option("--find-timeout", o->findTimeoutMs,
                    "before a run, wait this long (ms) for a step's skill to be detected")
        ->capture_default_str();
    cmd->add_option("--step-timeout", o->stepTimeoutS, "a step running longer (s) is halted")
        ->capture_default_str();
    addServerOptions(cmd, o->serve);
    cmd->footer(
        "Prints `listening on opc.tcp://HOST:PORT` once ready.\n"
        "Example: pnp mes --lds opc.tcp://127.0.0.1:4840");
    CLI::App* run =
        cmd->add_subcommand("run", "run a process on a running MES and print its execution record");
    run->add_option("process", r->process, "the process's IRI, e.g. urn:pnp:kb:process#thesis")
        ->required();
    run->add_option("--mes", r->mes, "the MES's server")->capture_default_str();
    run->add_option("--timeout", r->timeoutS, "halt the process after S seconds")
        ->capture_default_str();
    run->add_flag("--json", r->json, "print the execution record as JSON");
    addConnectionSecurityOptions(run, r->security);
    return [o, r, cmd, run]() -> int {
        if (!*cmd) return -1;
        if (*run) return runMesProcess(*r);
        return runMes(*o);
    };
}

}  // namespace pnp::cli
