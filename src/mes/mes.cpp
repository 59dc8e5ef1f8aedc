#include "mes/mes.hpp"

#include <atomic>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "mes/kb_feed.hpp"
#include "mes/process.hpp"
#include "mes/skill_type_graph.hpp"
#include "skill/client/generic_client.hpp"
#include "skill/model/model.hpp"
#include "skill/server/skill.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::mes {

namespace {

using Clock = std::chrono::steady_clock;
using json = nlohmann::json;
using skill::client::GenericSkillClient;

double msSince(Clock::time_point t) {
    return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}

std::string localName(const std::string& iri) {
    const auto p = iri.find_last_of("#/:");
    return p == std::string::npos ? iri : iri.substr(p + 1);
}

// A step's chosen skill.
struct Choice {
    std::string skillIri;
    skill::detector::DetectedSkill skill;
};

}  // namespace

struct Mes::Impl {
    ua::server::Server& server;
    std::shared_ptr<SharedKb> kb;
    MesOptions options;
    std::unique_ptr<skill::server::SkillController> controller;
    std::unique_ptr<skill::detector::SkillDetector> detector;
    std::unique_ptr<KbFeed> feed;
    ua::NodeId node;

    mutable std::mutex mutex;
    std::string lastRecord;
    std::shared_ptr<GenericSkillClient> running;  // the step's skill, for Suspend / Resume
    std::map<std::string, std::shared_ptr<ua::client::Client>> connections;  // by endpoint
    std::map<std::string, std::shared_ptr<GenericSkillClient>> clients;      // by skill IRI
    std::atomic<std::uint64_t> executions{0};
    // The run as it goes, for clients (ExecuteProcess/CurrentStep and /Progress).
    ua::NodeId currentStepNode, progressNode;

    Impl(ua::server::Server& s, std::shared_ptr<SharedKb> k, MesOptions o)
        : server(s), kb(std::move(k)), options(std::move(o)) {
        if (!options.log)
            options.log = [](const std::string& l) { std::cerr << "mes: " << l << std::endl; };
    }

    kb::Deadline deadline() const { return Clock::now() + options.requestTimeout; }

    // An available skill of the step's type (or a subtype), as the knowledge base knows it
    // and the detector still sees it; nullopt when none.
    std::optional<Choice> choose(const Step& step) {
        const auto r = kb->select(
            std::string(kPrefixes) +
                "SELECT ?skill WHERE { ?skill a pnp:Skill ; pnp:skillType/rdfs:subClassOf* " +
                kb::iri(step.skillType) + " . ?c pnp:offers ?skill } ORDER BY ?skill",
            deadline());
        for (std::size_t i = 0; i < r.rows.size(); ++i) {
            const kb::Term* t = r.get(i, "skill");
            if (!t) continue;
            if (auto s = feed->skill(t->value)) return Choice{t->value, *s};
        }
        return std::nullopt;
    }

    // The whole process before anything runs: every step has an available skill (waiting up
    // to findTimeout for late ones), every binding resolves.
    std::vector<std::string> check(const Process& p) {
        std::vector<std::string> problems;
        const auto until = Clock::now() + options.findTimeout;
        for (const Step& s : p.steps) {
            const std::string what = "step " + std::to_string(s.index) + " (" +
                                     (s.label.empty() ? localName(s.iri) : s.label) + ")";
            std::optional<Choice> c = choose(s);
            for (int i = 0; !c && Clock::now() < until && i < 10000; ++i) {
                std::this_thread::sleep_for(std::chrono::milliseconds(20));
                c = choose(s);
            }
            if (!c)
                problems.push_back(what + ": no available skill of type " + localName(s.skillType));
            for (const Binding& b : s.bindings) {
                try {
                    resolveBinding(*kb, b, deadline());
                } catch (const std::exception& e) {
                    problems.push_back(what + ": parameter " + e.what());
                }
            }
        }
        return problems;
    }

    std::shared_ptr<GenericSkillClient> clientFor(const Choice& c) {
        std::lock_guard l(mutex);
        if (auto it = clients.find(c.skillIri); it != clients.end()) return it->second;
        auto& conn = connections[c.skill.endpointUrl];
        if (!conn || !conn->isConnected()) {
            ua::client::ClientConfig cc;
            cc.applicationName = "pnp MES";
            cc.applicationUri = "urn:pnp:component:mes:client";
            cc.requestTimeout = options.requestTimeout;
            cc.connectTimeout = options.requestTimeout;
            conn = std::make_shared<ua::client::Client>(cc);
            conn->connect(c.skill.endpointUrl);
        }
        auto client = std::make_shared<GenericSkillClient>(conn, c.skill.node, deadline());
        client->subscribeTransitions(deadline());
        clients[c.skillIri] = client;
        return client;
    }

    void forget(const Choice& c) {
        std::lock_guard l(mutex);
        clients.erase(c.skillIri);
        if (auto it = connections.find(c.skill.endpointUrl); it != connections.end()) {
            for (auto k = clients.begin(); k != clients.end();)
                k = k->second->uaClient() == it->second ? clients.erase(k) : std::next(k);
            connections.erase(it);
        }
    }

    void recordStepInKb(const std::string& execIri, const Step& step, const json& s) {
        const std::string E = kb::iri(execIri);
        std::string u = std::string(kPrefixes) + "INSERT DATA { GRAPH " +
                        kb::iri(kExecutionsGraph) + " {\n" + E +
                        " a pnp:StepExecution ; pnp:ofStep " + kb::iri(step.iri) +
                        " ; pnp:result " + kb::literal(s.value("result", "")) + " ; pnp:message " +
                        kb::literal(s.value("message", "")) + " ; pnp:component " +
                        kb::literal(s.value("component", "")) + " ; pnp:skill " +
                        kb::literal(s.value("skill", "")) + " ; pnp:start " +
                        kb::literal(s.value("start", "")) + " ; pnp:end " +
                        kb::literal(s.value("end", "")) + " .\n";
        int n = 0;
        for (const auto& a : s["arguments"]) {
            const std::string A = kb::iri(execIri + "/argument/" + std::to_string(++n));
            u += E + " pnp:argument " + A + " .\n" + A + " pnp:name " +
                 kb::literal(a.value("name", "")) + " ; pnp:value " +
                 kb::literal(a.value("value", "")) + " .\n";
            if (!a.value("source", "").empty())
                u += A + " pnp:source " + kb::iri(a.value("source", "")) + " .\n";
        }
        n = 0;
        for (const auto& [name, value] : s["outputs"].items()) {
            const std::string O = kb::iri(execIri + "/output/" + std::to_string(++n));
            u += E + " pnp:output " + O + " .\n" + O + " pnp:name " + kb::literal(name) +
                 " ; pnp:value " + kb::literal(value.get<std::string>()) + " .\n";
        }
        kb->update(u + "} }", deadline());
        // The rules: what the cell learns from this execution.
        const auto rules = kb->select(
            std::string(kPrefixes) + "SELECT ?rule ?u WHERE { ?rule a pnp:Rule ; pnp:update ?u }",
            deadline());
        for (std::size_t i = 0; i < rules.rows.size(); ++i) {
            std::string text = rules.get(i, "u") ? rules.get(i, "u")->value : "";
            for (std::size_t p = text.find("$execution"); p != std::string::npos;
                 p = text.find("$execution", p + E.size()))
                text.replace(p, 10, E);
            try {
                kb->update(text, deadline());
            } catch (const std::exception& e) {
                options.log("rule " + (rules.get(i, "rule") ? rules.get(i, "rule")->value : "?") +
                            " failed: " + e.what());
            }
        }
    }

    // ExecuteProcess/CurrentStep (the running step's index, 0 = none) and /Progress (the
    // run so far as JSON: every step of the process, with its result once it ended) — what a
    // client subscribes to while a process runs; the Record comes only at the end.
    void publishProgress(const json& progress) {
        if (progressNode.isNull()) return;
        const json& r = progress["running"];
        auto& space = server.addressSpace();
        space.setValue(currentStepNode, ua::DataValue(ua::Variant(ua::UInt32{
                                            r.is_number_integer() ? r.get<ua::UInt32>() : 0u})));
        space.setValue(progressNode, ua::DataValue(ua::Variant(ua::String(progress.dump()))));
    }

    void addProgressNodes(const ua::NodeId& skillNode) {
        auto& space = server.addressSpace();
        const ua::UInt16 ns = skillNode.namespaceIndex();
        const std::string base = skillNode.idType() == ua::IdType::String
                                     ? skillNode.string()
                                     : options.name + ".ExecuteProcess";
        auto variable = [&](const std::string& name, ua::UInt32 dataType, ua::Variant initial,
                            const std::string& what) {
            ua::server::VariableAttributes a;
            a.dataType = ua::NodeId(0, dataType);
            a.value = ua::DataValue(std::move(initial));
            a.accessLevel = ua::server::access_level::CurrentRead;  // the MES's, not clients'
            a.description = ua::LocalizedText("", what);
            return space.addVariable(skillNode, ua::NodeId(ns, base + "." + name),
                                     ua::QualifiedName(ns, name), a);
        };
        currentStepNode = variable("CurrentStep", ua::ns0::UInt32, ua::Variant(ua::UInt32{0}),
                                   "the index of the step running now; 0: none");
        progressNode =
            variable("Progress", ua::ns0::String, ua::Variant(ua::String("")),
                     "the process run so far (JSON: execution, process, running, steps, result); "
                     "empty before the first run");
    }

    void finishRecord(json& record) {
        const std::string text = record.dump();
        {
            std::lock_guard l(mutex);
            lastRecord = text;
        }
        if (!options.recordFile.empty()) {
            std::ofstream out(options.recordFile, std::ios::app);
            out << text << "\n";
            if (!out) options.log("cannot append the record to " + options.recordFile);
        }
    }

    skill::server::Outcome execute(skill::server::Execution& exec) {
        std::string processIri;
        if (const auto* v = exec.value("ProcessIri"))
            if (const auto* s = v->scalar<ua::String>()) processIri = *s;
        json record;
        record["process"] = processIri;
        record["start"] = ua::DateTime::now().toIso8601();
        record["steps"] = json::array();
        const std::string execIri =
            "urn:pnp:kb:execution:" + std::to_string(ua::DateTime::now().toUnixNanos()) + "-" +
            std::to_string(executions.fetch_add(1));
        record["execution"] = execIri;
        json progress = {{"execution", execIri},
                         {"process", processIri},
                         {"running", nullptr},
                         {"steps", json::array()},
                         {"result", nullptr}};
        publishProgress(progress);
        auto end = [&](const std::string& result, const std::string& reason) {
            progress["running"] = nullptr;
            progress["result"] = result;
            progress["reason"] = reason;
            publishProgress(progress);
            record["result"] = result;
            record["reason"] = reason;
            record["end"] = ua::DateTime::now().toIso8601();
            finishRecord(record);
            try {
                kb->update(std::string(kPrefixes) + "INSERT DATA { GRAPH " +
                               kb::iri(kExecutionsGraph) + " { " + kb::iri(execIri) +
                               " a pnp:ProcessExecution ; pnp:ofProcess " +
                               (processIri.empty() ? kb::literal("") : kb::iri(processIri)) +
                               " ; pnp:result " + kb::literal(result) + " ; pnp:message " +
                               kb::literal(reason) + " ; pnp:start " +
                               kb::literal(record["start"].get<std::string>()) + " ; pnp:end " +
                               kb::literal(record["end"].get<std::string>()) + " } }",
                           deadline());
            } catch (const std::exception& e) {
                options.log(std::string("recording the execution failed: ") + e.what());
            }
            options.log(processIri + ": " + result + (reason.empty() ? "" : ": " + reason));
            skill::server::Outcome o;
            o.result = result == "Completed" ? skill::SkillResult::Completed
                       : result == "Halted"  ? skill::SkillResult::Aborted
                                             : skill::SkillResult::Failed;
            o.message = reason.empty() ? result : reason;
            o.with("Record", ua::Variant(ua::String(record.dump())));
            return o;
        };

        Process process;
        try {
            if (processIri.empty()) throw ProcessError("ProcessIri is empty");
            (void)kb::iri(processIri);
            process = loadProcess(*kb, processIri, deadline());
        } catch (const std::exception& e) {
            return end("Refused", e.what());
        }
        for (const Step& step : process.steps)
            progress["steps"].push_back({{"index", step.index},
                                         {"label", step.label},
                                         {"skillType", localName(step.skillType)},
                                         {"result", nullptr}});
        publishProgress(progress);
        exec.progress(
            ua::Variant(ua::String("checking " + std::to_string(process.steps.size()) + " steps")));
        const auto problems = check(process);
        if (!problems.empty()) {
            std::string all = "refused before anything ran:";
            for (const auto& p : problems) all += "\n  " + p;
            record["missing"] = problems;
            return end("Refused", all);
        }
        ua::DateTime previousEnd{};
        for (std::size_t position = 0; position < process.steps.size(); ++position) {
            const Step& step = process.steps[position];
            json& shown = progress["steps"][position];
            // The step's end, as the Record has it.
            auto showEnd = [&](const json& s) {
                for (const char* k :
                     {"skill", "component", "componentName", "result", "message", "durationS"})
                    if (s.contains(k)) shown[k] = s[k];
                if (shown.contains("message") && shown["message"].is_string() &&
                    shown["message"].get<std::string>().size() > 1000)
                    shown["message"] = shown["message"].get<std::string>().substr(0, 1000) + "...";
                progress["running"] = nullptr;
                publishProgress(progress);
            };
            if (exec.stopRequested())
                return end("Halted", "halted before step " + std::to_string(step.index));
            const auto t0 = Clock::now();
            json s;
            s["index"] = step.index;
            s["step"] = step.iri;
            s["label"] = step.label;
            s["skillType"] = localName(step.skillType);
            const std::string what = "step " + std::to_string(step.index) + " (" +
                                     (step.label.empty() ? localName(step.iri) : step.label) + ")";
            std::optional<Choice> choice;
            std::vector<std::string> assignments;
            s["arguments"] = json::array();
            s["parameters"] = json::object();
            try {
                choice = choose(step);
                if (!choice)
                    throw ProcessError("no available skill of type " + localName(step.skillType));
                for (const Binding& b : step.bindings) {
                    const Resolved r = resolveBinding(*kb, b, deadline());
                    assignments.push_back(b.name + "=" + r.text);
                    s["arguments"].push_back(
                        {{"name", b.name}, {"value", r.text}, {"source", r.source}});
                    s["parameters"][b.name] = r.text;
                }
            } catch (const std::exception& e) {
                s["result"] = "Failed";
                s["message"] = e.what();
                record["steps"].push_back(s);
                showEnd(s);
                return end("Failed", what + ": " + e.what());
            }
            s["skill"] = choice->skill.name;
            s["skillIri"] = choice->skillIri;
            s["component"] = choice->skill.componentUri;
            s["componentName"] = choice->skill.componentName;
            s["endpoint"] = choice->skill.endpointUrl;
            const std::string on = choice->skill.name + " on " + choice->skill.componentName;
            shown["skill"] = s["skill"];
            shown["component"] = s["component"];
            shown["componentName"] = s["componentName"];
            progress["running"] = step.index;
            publishProgress(progress);
            exec.progress(ua::Variant(ua::String(what + ": " + on)));
            skill::client::RunResult rr;
            std::string error;
            for (int attempt = 0; attempt < 2; ++attempt) {
                try {
                    auto client = clientFor(*choice);
                    const auto params = client->parse(assignments);
                    if (attempt == 0) s["dispatchMs"] = msSince(t0);
                    {
                        std::lock_guard l(mutex);
                        running = client;
                    }
                    s["start"] = ua::DateTime::now().toIso8601();
                    rr = client->run(params, Clock::now() + options.stepTimeout, exec.stopToken());
                    error.clear();
                    break;
                } catch (const std::exception& e) {
                    // A dropped connection or a restarted server: connect afresh once.
                    error = e.what();
                    forget(*choice);
                    if (exec.stopRequested()) break;
                }
            }
            {
                std::lock_guard l(mutex);
                running.reset();
            }
            ua::DateTime startT{}, endT{};
            for (const auto& t : rr.transitions) {
                if (t.to == skill::ProgramState::Running && startT.ticks == 0) startT = t.time;
                if (t.from == skill::ProgramState::Running ||
                    t.from == skill::ProgramState::Suspended)
                    endT = t.time;
            }
            if (startT.ticks != 0) s["start"] = startT.toIso8601();
            s["end"] = (endT.ticks != 0 ? endT : ua::DateTime::now()).toIso8601();
            if (startT.ticks != 0 && endT.ticks != 0)
                s["durationS"] = static_cast<double>(endT.ticks - startT.ticks) / 1e7;
            if (previousEnd.ticks != 0 && startT.ticks != 0)
                s["overheadMs"] = static_cast<double>(startT.ticks - previousEnd.ticks) / 1e4;
            previousEnd = endT;
            json outputs = json::object();
            for (const auto& [name, value] : rr.finalResult.values)
                outputs[name] = skill::client::formatValue(value);
            s["outputs"] = outputs;
            // A composite skill's own record of its lower skills (PickAndPlace).
            auto find = [&](const char* n) -> const ua::Variant* {
                for (const auto& [name, value] : rr.finalResult.values)
                    if (name == n) return &value;
                return nullptr;
            };
            if (const auto* steps = find("Steps")) {
                json lower = json::array();
                const auto* names = steps->array<ua::String>();
                const auto* skills =
                    find("StepSkills") ? find("StepSkills")->array<ua::String>() : nullptr;
                const auto* starts =
                    find("StepStart") ? find("StepStart")->array<ua::DateTime>() : nullptr;
                const auto* ends =
                    find("StepEnd") ? find("StepEnd")->array<ua::DateTime>() : nullptr;
                const auto* overhead = find("CompositionOverheadMs")
                                           ? find("CompositionOverheadMs")->array<double>()
                                           : nullptr;
                for (std::size_t i = 0; names && i < names->size(); ++i) {
                    json l;
                    l["step"] = (*names)[i];
                    if (skills && i < skills->size()) l["skill"] = (*skills)[i];
                    if (starts && i < starts->size()) l["start"] = (*starts)[i].toIso8601();
                    if (ends && i < ends->size()) l["end"] = (*ends)[i].toIso8601();
                    lower.push_back(l);
                }
                s["lower"] = lower;
                if (overhead) s["compositionOverheadMs"] = *overhead;
            }
            std::string result;
            std::string message = rr.message.empty() ? rr.finalResult.message : rr.message;
            if (!error.empty()) {
                result = "Failed";
                message = error;
            } else if (rr.result == skill::SkillResult::Completed) {
                result = "Completed";
            } else if (rr.result == skill::SkillResult::Aborted || exec.stopRequested()) {
                result = "Halted";
            } else {
                result = "Failed";
            }
            s["result"] = result;
            s["message"] = message;
            record["steps"].push_back(s);
            showEnd(s);
            try {
                recordStepInKb(execIri + "/step/" + std::to_string(step.index), step, s);
            } catch (const std::exception& e) {
                options.log(std::string("recording the step in the knowledge base failed: ") +
                            e.what());
            }
            options.log(what + ": " + on + ": " + result +
                        (message.empty() ? "" : " (" + message + ")"));
            if (result == "Halted") return end("Halted", what + ": " + on + " halted");
            if (result != "Completed")
                return end("Failed",
                           what + ": " + on + " failed: " + (message.empty() ? result : message));
        }
        return end("Completed", "");
    }

    ua::StatusCode forward(bool suspend) {
        std::shared_ptr<GenericSkillClient> c;
        {
            std::lock_guard l(mutex);
            c = running;
        }
        if (!c) return {};
        try {
            if (suspend)
                c->suspend(deadline());
            else
                c->resume(deadline());
        } catch (const std::exception& e) {
            options.log(std::string(suspend ? "suspend" : "resume") +
                        " of the running step failed: " + e.what());
            return ua::StatusCode(ua::status::BadInvalidState);
        }
        return {};
    }
};

Mes::Mes(ua::server::Server& server, std::shared_ptr<SharedKb> kb, MesOptions options,
         mdns::Mdns* mdns)
    : impl_(std::make_shared<Impl>(server, std::move(kb), std::move(options))) {
    Impl& m = *impl_;
    auto& space = server.addressSpace();
    skill::server::loadSkillModels(space, {skill::kBaseUri, skill::kCompositeUri});
    m.controller = std::make_unique<skill::server::SkillController>(
        server, skill::server::SkillControllerOptions{.name = m.options.name});
    m.node = m.controller->node();
    std::weak_ptr<Impl> weak = impl_;
    skill::server::SkillCallbacks cb;
    cb.execute = [weak](skill::server::Execution& exec) {
        auto impl = weak.lock();
        if (!impl) return skill::server::Outcome::failed("the MES is shutting down");
        return impl->execute(exec);
    };
    cb.suspend = [weak]() -> ua::StatusCode {
        auto impl = weak.lock();
        return impl ? impl->forward(true) : ua::StatusCode{};
    };
    cb.resume = [weak]() -> ua::StatusCode {
        auto impl = weak.lock();
        return impl ? impl->forward(false) : ua::StatusCode{};
    };
    const auto handle = m.controller->add(
        "ExecuteProcess",
        skill::server::makeSkill(skill::types::ExecuteProcessSkillType,
                                 {skill::server::declareParameter<ua::String>("ProcessIri", "")},
                                 std::move(cb)));
    m.addProgressNodes(handle.node());
    m.feed = std::make_unique<KbFeed>(*m.kb, m.options.requestTimeout);
    m.feed->log = m.options.log;
    m.detector = std::make_unique<skill::detector::SkillDetector>(mdns, m.options.detector);
    KbFeed* feed = m.feed.get();
    m.detector->onChange(
        [feed](const skill::detector::DetectedSkill& s, bool added) { feed->changed(s, added); });
}

Mes::~Mes() { stop(); }

void Mes::start() { impl_->detector->start(); }

void Mes::stop() {
    if (impl_->controller) impl_->controller.reset();  // halts a running process, joins it
    impl_->detector->stop();
}

std::vector<std::string> Mes::check(const std::string& processIri) {
    try {
        return impl_->check(loadProcess(*impl_->kb, processIri, impl_->deadline()));
    } catch (const std::exception& e) {
        return {e.what()};
    }
}

std::string Mes::lastRecord() const {
    std::lock_guard l(impl_->mutex);
    return impl_->lastRecord;
}

skill::detector::SkillDetector& Mes::detector() { return *impl_->detector; }
const ua::NodeId& Mes::node() const { return impl_->node; }
std::vector<skill::server::SkillHandle> Mes::skills() const {
    if (!impl_->controller) return {};
    return impl_->controller->skills();
}

}  // namespace pnp::mes
