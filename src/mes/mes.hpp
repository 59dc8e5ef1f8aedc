// The semantic MES (cell.md §3): the skill ExecuteProcess(ProcessIri) on DeviceSet/<name>.
// For each step of the process it asks the knowledge base for the skill type and the
// parameters, picks an available skill of that type or a subtype (the skill detector feeds
// the knowledge base live, KbFeed), resolves the bindings and runs the skill with the generic
// skill client (lock, write, start, wait, unlock). Before anything runs, the whole process is
// checked (every step has an available skill, every binding resolves) and refused with the
// list of what is missing. Halt / Suspend / Resume reach the running step's skill; a failed
// step ends the process with the step, the skill and the reason. Every execution is recorded
// in the knowledge base (graph urn:pnp:kb:executions) and as JSON (FinalResultData/Record,
// and a line in options.recordFile); after each recorded step the knowledge base's pnp:Rule
// updates run (e.g. which tool lives in which dock). While a process runs, two read-only
// variables of the ExecuteProcess skill tell clients where it is: CurrentStep (UInt32, the
// running step's index, 0 = none) and Progress (String, JSON: {execution, process, running:
// index|null, steps: [{index, label, skillType, skill?, component?, componentName?, result:
// null until the step ended, message?, durationS?}], result: null until the end, reason?}).
// Nothing process- or vendor-specific is compiled in.
//
//   auto kb = std::make_shared<SharedKb>(kb::open(""));
//   loadKnowledge(*kb, defaultKnowledgeFiles(), deadline);
//   ua::server::Server server(config);
//   Mes mes(server, kb, {.detector = {.watcher = {.ldsUrls = {lds}}}}, &mdns);
//   server.start();
//   mes.start();
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "mdns/mdns.hpp"
#include "mes/shared_kb.hpp"
#include "skill/detector/skill_detector.hpp"
#include "skill/server/controller.hpp"
#include "ua/server/server.hpp"

namespace pnp::mes {

struct MesOptions {
    std::string name = "MES";  // DeviceSet/<name>
    skill::detector::DetectorConfig detector;
    std::chrono::milliseconds requestTimeout{2000};  // per OPC UA / knowledge base request
    std::chrono::milliseconds stepTimeout{600000};   // per step: halted after this
    // A step's skill not (yet) detected when the process starts: wait this long for it.
    std::chrono::milliseconds findTimeout{5000};
    std::string recordFile;  // each execution record appended as one JSON line ("" = none)
    std::function<void(const std::string&)> log;  // lines for people; default stderr
};

class Mes {
  public:
    // Builds DeviceSet/<name> with ExecuteProcess; call before Server::start(). mdns may be
    // null. Throws skill::server::SkillError / ua::server::NodeSetError.
    Mes(ua::server::Server& server, std::shared_ptr<SharedKb> kb, MesOptions options,
        mdns::Mdns* mdns = nullptr);
    ~Mes();
    Mes(const Mes&) = delete;
    Mes& operator=(const Mes&) = delete;

    void start();  // the skill detector and its feed into the knowledge base
    void stop();   // halts a running process, stops the detector

    // The check before a run: "" = runnable, else one line per problem.
    std::vector<std::string> check(const std::string& processIri);
    std::string lastRecord() const;  // JSON of the last execution ("" = none yet)

    skill::detector::SkillDetector& detector();
    const ua::NodeId& node() const;
    std::vector<skill::server::SkillHandle> skills() const;

    struct Impl;

  private:
    std::shared_ptr<Impl> impl_;
};

}  // namespace pnp::mes
