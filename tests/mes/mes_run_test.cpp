// The MES running processes against real skill servers on 127.0.0.1: the demo skills'
// Delay (a skill that waits, can fail with a message, can be halted) stands for any device;
// the process is Turtle in a temporary file, the knowledge base embedded. ExecuteProcess is
// called over OPC UA with the generic skill client, as any client would.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

#include "mes/mes.hpp"
#include "mes/process.hpp"
#include "skill/client/generic_client.hpp"
#include "skill/demo/demo_skills.hpp"
#include "skill/detector/skill_detector.hpp"
#include "skill/server/controller.hpp"
#include "support/loopback_server.hpp"
#include "ua/client/subscription.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp;
using namespace std::chrono_literals;
using json = nlohmann::json;

namespace {

kb::Deadline soon() { return std::chrono::steady_clock::now() + 10s; }

std::string tmpFile(const std::string& name, const std::string& text) {
    const std::string path =
        ::testing::TempDir() + "pnp_mesrun_" + std::to_string(::getpid()) + "_" + name;
    std::ofstream(path) << text;
    return path;
}

// Processes over the demo's Delay skill and the base model's Grasp.
const char* kProcesses = R"(
@prefix pnp: <urn:pnp:kb#> .
@prefix proc: <urn:pnp:kb:process#> .
@prefix cell: <urn:pnp:kb:cell#> .
@prefix demo: <urn:pnp:ua:skills:demo#> .
@prefix base: <urn:pnp:ua:skills#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .

cell:station a pnp:Resource ; pnp:dwell "30" .

proc:two a pnp:Process .
proc:two-1 a pnp:Step ; pnp:process proc:two ; pnp:index 1 ; pnp:skillType demo:DelaySkillType ;
    pnp:binding [ pnp:name "DurationMs" ; pnp:value "20" ] , [ pnp:name "FailWith" ; pnp:value "" ] .
proc:two-2 a pnp:Step ; pnp:process proc:two ; pnp:index 2 ; pnp:skillType demo:DelaySkillType ;
    pnp:binding [ pnp:name "DurationMs" ; pnp:from cell:station ; pnp:via pnp:dwell ] ,
                [ pnp:name "FailWith" ; pnp:query "SELECT ?value WHERE { BIND(\"\" AS ?value) }" ] .

proc:needs-grasp a pnp:Process .
proc:needs-grasp-1 a pnp:Step ; pnp:process proc:needs-grasp ; pnp:index 1 ; pnp:skillType demo:DelaySkillType .
proc:needs-grasp-2 a pnp:Step ; pnp:process proc:needs-grasp ; pnp:index 2 ; pnp:skillType base:GraspGripperSkillType .
proc:needs-grasp-3 a pnp:Step ; pnp:process proc:needs-grasp ; pnp:index 3 ; pnp:skillType demo:DelaySkillType ;
    pnp:binding [ pnp:name "DurationMs" ; pnp:from cell:nowhere ; pnp:via pnp:dwell ] .

proc:jam a pnp:Process .
proc:jam-1 a pnp:Step ; pnp:process proc:jam ; pnp:index 1 ; pnp:skillType demo:DelaySkillType ;
    pnp:binding [ pnp:name "FailWith" ; pnp:value "jammed" ] .
proc:jam-2 a pnp:Step ; pnp:process proc:jam ; pnp:index 2 ; pnp:skillType demo:DelaySkillType .

proc:slow a pnp:Process .
proc:slow-1 a pnp:Step ; pnp:process proc:slow ; pnp:index 1 ; rdfs:label "first wait" ;
    pnp:skillType demo:DelaySkillType ; pnp:binding [ pnp:name "DurationMs" ; pnp:value "400" ] .
proc:slow-2 a pnp:Step ; pnp:process proc:slow ; pnp:index 2 ; rdfs:label "second wait" ;
    pnp:skillType demo:DelaySkillType ; pnp:binding [ pnp:name "DurationMs" ; pnp:value "400" ] .

proc:long a pnp:Process .
proc:long-1 a pnp:Step ; pnp:process proc:long ; pnp:index 1 ; pnp:skillType demo:DelaySkillType ;
    pnp:binding [ pnp:name "DurationMs" ; pnp:value "20000" ] .

# A rule of this test: every completed step execution marks the station as used.
cell:markUsed a pnp:Rule ; pnp:update """
PREFIX pnp: <urn:pnp:kb#>
INSERT { GRAPH <urn:pnp:kb:learned> { <urn:pnp:kb:cell#station> pnp:usedBy ?e } }
WHERE { $execution pnp:result "Completed" . BIND($execution AS ?e) }""" .
)";

// A device: one Delay skill (the demo's) on its own server.
struct Device {
    ua::server::Server server;
    std::unique_ptr<skill::server::SkillController> controller;
    explicit Device(const std::string& uri) : server(config(uri)) {
        skill::demo::loadDemoModels(server);
        controller = std::make_unique<skill::server::SkillController>(
            server, skill::server::SkillControllerOptions{.name = "Station"});
        controller->add("Wait", demoDelay());
        server.start();
    }
    static ua::server::ServerConfig config(const std::string& uri) {
        auto c = pnp::testing::loopbackConfig();
        c.applicationUri = uri;
        c.applicationName = "station";
        return c;
    }
    static std::shared_ptr<skill::server::Skill> demoDelay() {
        // The demo model's Delay: waits DurationMs of Running time, fails with FailWith.
        using namespace skill::server;
        auto failWith = declareParameter<ua::String>("FailWith", "");
        failWith.optional = true;  // Optional in DelaySkillType
        return makeSkill(
            skill::types::DelaySkillType, {declareParameter<double>("DurationMs", 1.0), failWith},
            {.execute = [](Execution& run) {
                double ms = 0;
                std::string fail;
                if (auto* v = run.value("DurationMs")) ParamTraits<double>::fromVariant(*v, ms);
                if (auto* v = run.value("FailWith"))
                    if (auto* s = v->scalar<ua::String>()) fail = *s;
                if (!run.sleepFor(std::chrono::microseconds(static_cast<long>(ms * 1000))))
                    return Outcome::aborted("halted");
                if (!fail.empty()) return Outcome::failed(fail);
                return Outcome::completed();
            }});
    }
    std::uint64_t runs() const { return controller->skills().front().runs(); }
};

class MesRun : public ::testing::Test {
  protected:
    void SetUp() override {
        kb = std::make_shared<mes::SharedKb>(kb::open(""));
        auto files = mes::defaultKnowledgeFiles();
        files.emplace_back(tmpFile("processes.ttl", kProcesses));
        mes::loadKnowledge(*kb, files, soon());
        device = std::make_unique<Device>("urn:pnp:test:station");
        mesServer = std::make_unique<ua::server::Server>(pnp::testing::loopbackConfig());
        mes::MesOptions o;
        o.detector.useDiscovery = false;
        o.detector.healthInterval = 50ms;
        o.findTimeout = 300ms;
        o.log = [](const std::string&) {};
        theMes = std::make_unique<mes::Mes>(*mesServer, kb, o);
        mesServer->start();
        theMes->start();
        theMes->detector().addServer(pnp::testing::url(device->server));
        ASSERT_TRUE(
            theMes->detector().waitUntil([](const auto& d) { return d.all().size() == 1; }, 5s));
        // The feed has put the skill into the knowledge base.
        const auto until = std::chrono::steady_clock::now() + 5s;
        while (!liveSkills() && std::chrono::steady_clock::now() < until)
            std::this_thread::sleep_for(10ms);
        ASSERT_EQ(liveSkills(), 1u);
        connection = std::make_shared<ua::client::Client>();
        connection->connect(pnp::testing::url(*mesServer));
        execute = std::make_unique<skill::client::GenericSkillClient>(
            connection, theMes->skills().front().node(), soon());
    }
    void TearDown() override {
        execute.reset();
        if (connection) connection->disconnect();
        theMes.reset();
        mesServer.reset();
        device.reset();
    }
    std::size_t liveSkills() {
        return kb
            ->select(std::string(mes::kPrefixes) +
                         "SELECT ?s WHERE { GRAPH <urn:pnp:kb:live> { ?c pnp:offers ?s . "
                         "?s pnp:skillType ?t } }",
                     soon())
            .rows.size();
    }
    // Runs ExecuteProcess; returns the result and the record.
    std::pair<skill::client::RunResult, json> run(const std::string& process,
                                                  std::stop_token cancel = {}) {
        auto r = execute->run(execute->parse({"ProcessIri=" + process}),
                              std::chrono::steady_clock::now() + 30s, cancel);
        std::string record = theMes->lastRecord();
        return {r, json::parse(record.empty() ? "{}" : record)};
    }

    std::shared_ptr<mes::SharedKb> kb;
    std::unique_ptr<Device> device;
    std::unique_ptr<ua::server::Server> mesServer;
    std::unique_ptr<mes::Mes> theMes;
    std::shared_ptr<ua::client::Client> connection;
    std::unique_ptr<skill::client::GenericSkillClient> execute;
};

}  // namespace

TEST_F(MesRun, RunsEveryStepWithResolvedParametersAndRecordsIt) {
    auto [r, record] = run("urn:pnp:kb:process#two");
    ASSERT_EQ(r.result, skill::SkillResult::Completed) << r.message;
    EXPECT_EQ(record["result"], "Completed");
    ASSERT_EQ(record["steps"].size(), 2u);
    EXPECT_EQ(device->runs(), 2u);
    for (const auto& s : record["steps"]) {
        EXPECT_EQ(s["result"], "Completed");
        EXPECT_EQ(s["component"], "urn:pnp:test:station");
        EXPECT_EQ(s["skill"], "Wait");
        EXPECT_EQ(s["skillType"], "DelaySkillType");
        EXPECT_TRUE(s.contains("dispatchMs"));
        EXPECT_TRUE(s.contains("durationS"));
    }
    EXPECT_EQ(record["steps"][0]["parameters"]["DurationMs"], "20");
    EXPECT_EQ(record["steps"][1]["parameters"]["DurationMs"], "30");  // from the resource
    EXPECT_GE(record["steps"][1]["durationS"].get<double>(), 0.029);
    // The same execution in the knowledge base, and the rule ran for each completed step.
    const auto steps =
        kb->select(std::string(mes::kPrefixes) +
                       "SELECT ?e ?end WHERE { ?e a pnp:StepExecution ; pnp:result "
                       "\"Completed\" ; pnp:end ?end ; pnp:ofStep ?s . ?s pnp:process "
                       "proc:two }",
                   soon());
    EXPECT_EQ(steps.rows.size(), 2u);
    const auto used = kb->select(
        std::string(mes::kPrefixes) + "SELECT ?e WHERE { cell:station pnp:usedBy ?e }", soon());
    EXPECT_EQ(used.rows.size(), 2u);
}

TEST_F(MesRun, AProcessWithAMissingSkillIsRefusedBeforeAnythingRuns) {
    auto [r, record] = run("urn:pnp:kb:process#needs-grasp");
    EXPECT_EQ(r.result, skill::SkillResult::Failed);
    EXPECT_EQ(record["result"], "Refused");
    EXPECT_EQ(device->runs(), 0u);  // not even step 1 ran
    const std::string reason = record["reason"];
    EXPECT_NE(
        reason.find("step 2 (needs-grasp-2): no available skill of type GraspGripperSkillType"),
        std::string::npos)
        << reason;
    EXPECT_NE(
        reason.find("step 3 (needs-grasp-3): parameter DurationMs: urn:pnp:kb:cell#nowhere has no"),
        std::string::npos)
        << reason;
    EXPECT_EQ(record["missing"].size(), 2u);
}

TEST_F(MesRun, AFailedStepStopsTheProcessNamingStepSkillAndReason) {
    auto [r, record] = run("urn:pnp:kb:process#jam");
    EXPECT_EQ(r.result, skill::SkillResult::Failed);
    EXPECT_EQ(record["result"], "Failed");
    ASSERT_EQ(record["steps"].size(), 1u);  // step 2 never started
    EXPECT_EQ(device->runs(), 1u);
    EXPECT_EQ(record["steps"][0]["result"], "Failed");
    EXPECT_EQ(record["steps"][0]["message"], "jammed");
    const std::string reason = record["reason"];
    EXPECT_NE(reason.find("step 1 (jam-1): Wait on station failed: jammed"), std::string::npos)
        << reason;
    // After the failure the MES runs the next process normally.
    execute->reset(soon());
    EXPECT_EQ(run("urn:pnp:kb:process#two").first.result, skill::SkillResult::Completed);
}

TEST_F(MesRun, HaltOfExecuteProcessHaltsTheRunningStepsSkill) {
    std::stop_source stop;
    std::thread halter([&] {
        // Halt once the device's skill is Running.
        const auto until = std::chrono::steady_clock::now() + 10s;
        while (device->controller->skills().front().state() != skill::ProgramState::Running &&
               std::chrono::steady_clock::now() < until)
            std::this_thread::sleep_for(5ms);
        stop.request_stop();  // run() halts ExecuteProcess
    });
    const auto t0 = std::chrono::steady_clock::now();
    auto [r, record] = run("urn:pnp:kb:process#long", stop.get_token());
    halter.join();
    EXPECT_EQ(r.result, skill::SkillResult::Aborted);
    EXPECT_LT(std::chrono::steady_clock::now() - t0, 10s);  // not the 20 s of the step
    // The step's skill was halted too, within a second.
    const auto until = std::chrono::steady_clock::now() + 2s;
    while (device->controller->skills().front().state() != skill::ProgramState::Halted &&
           std::chrono::steady_clock::now() < until)
        std::this_thread::sleep_for(5ms);
    EXPECT_EQ(device->controller->skills().front().state(), skill::ProgramState::Halted);
    // The halted run's own record is in FinalResultData (written when the run ends).
    std::string recorded;
    const auto recordUntil = std::chrono::steady_clock::now() + 3s;
    while (recorded.find("\"Halted\"") == std::string::npos &&
           std::chrono::steady_clock::now() < recordUntil) {
        for (const auto& [name, v] : execute->finalResult(soon()).values)
            if (name == "Record")
                if (const auto* s = v.scalar<ua::String>()) recorded = *s;
        std::this_thread::sleep_for(20ms);
    }
    const auto halted = json::parse(recorded.empty() ? "{}" : recorded);
    EXPECT_EQ(halted.value("result", ""), "Halted") << recorded;
    EXPECT_EQ(halted.value("process", ""), "urn:pnp:kb:process#long");
}

// While a process runs, a client subscribed to ExecuteProcess/CurrentStep and /Progress sees
// which step runs and each step's result as it ends (the Record comes only at the end).
TEST_F(MesRun, PublishesTheRunningStepAndTheResultsSoFar) {
    auto watcher = std::make_shared<ua::client::Client>();
    watcher->connect(pnp::testing::url(*mesServer));
    ua::NodeId currentStep, progress;
    for (const auto& r : watcher->browse(theMes->skills().front().node(), {}, 5s)) {
        if (r.browseName.name == "CurrentStep") currentStep = r.nodeId.nodeId;
        if (r.browseName.name == "Progress") progress = r.nodeId.nodeId;
    }
    ASSERT_FALSE(currentStep.isNull());
    ASSERT_FALSE(progress.isNull());
    // Read-only for clients.
    EXPECT_EQ(watcher->writeValue(currentStep, ua::Variant(ua::UInt32{7}), 5s),
              ua::status::BadNotWritable);

    std::mutex mutex;
    std::vector<ua::UInt32> steps;
    std::vector<json> progresses;
    watcher->startBackgroundThread();
    ua::client::Subscription sub(*watcher, {.publishingInterval = 20}, {}, 5s);
    auto stepItem = sub.monitorValue(
        currentStep,
        [&](const ua::DataValue& v) {
            if (const auto* n = v.value ? v.value->scalar<ua::UInt32>() : nullptr) {
                std::lock_guard l(mutex);
                if (steps.empty() || steps.back() != *n) steps.push_back(*n);
            }
        },
        {.samplingInterval = 0, .queueSize = 20}, 5s);
    auto progressItem = sub.monitorValue(
        progress,
        [&](const ua::DataValue& v) {
            if (const auto* t = v.value ? v.value->scalar<ua::String>() : nullptr)
                if (!t->empty()) {
                    std::lock_guard l(mutex);
                    progresses.push_back(json::parse(*t));
                }
        },
        {.samplingInterval = 0, .queueSize = 20}, 5s);

    auto [r, record] = run("urn:pnp:kb:process#slow");
    ASSERT_EQ(r.result, skill::SkillResult::Completed) << r.message;
    // The end's values reach the subscriber within a few publishing intervals.
    const auto until = std::chrono::steady_clock::now() + 3s;
    for (;;) {
        {
            std::lock_guard l(mutex);
            if (!progresses.empty() && progresses.back()["result"] == "Completed") break;
        }
        if (std::chrono::steady_clock::now() > until) break;
        std::this_thread::sleep_for(10ms);
    }
    std::lock_guard l(mutex);
    // CurrentStep: 1, then 2 (with 0 between the steps), then 0 at the end.
    std::vector<ua::UInt32> nonZero;
    for (auto n : steps)
        if (n != 0) nonZero.push_back(n);
    EXPECT_EQ(nonZero, (std::vector<ua::UInt32>{1, 2}));
    ASSERT_FALSE(steps.empty());
    EXPECT_EQ(steps.back(), 0u);

    ASSERT_FALSE(progresses.empty());
    const json& last = progresses.back();
    EXPECT_EQ(last["result"], "Completed");
    EXPECT_EQ(last["execution"], record["execution"]);
    EXPECT_EQ(last["process"], "urn:pnp:kb:process#slow");
    EXPECT_TRUE(last["running"].is_null());
    ASSERT_EQ(last["steps"].size(), 2u);
    for (const auto& s : last["steps"]) {
        EXPECT_EQ(s["result"], "Completed");
        EXPECT_EQ(s["skill"], "Wait");
        EXPECT_EQ(s["skillType"], "DelaySkillType");
        EXPECT_GE(s["durationS"].get<double>(), 0.39);
    }
    EXPECT_EQ(last["steps"][0]["label"], "first wait");
    // While step 2 ran: step 1 had its result, step 2 none yet; every step was planned from
    // the start.
    const auto during = std::find_if(progresses.begin(), progresses.end(),
                                     [](const json& p) { return p["running"] == 2; });
    ASSERT_NE(during, progresses.end());
    EXPECT_TRUE((*during)["result"].is_null());
    ASSERT_EQ((*during)["steps"].size(), 2u);
    EXPECT_EQ((*during)["steps"][0]["result"], "Completed");
    EXPECT_TRUE((*during)["steps"][1]["result"].is_null());
    EXPECT_EQ((*during)["steps"][1]["label"], "second wait");
    EXPECT_TRUE(std::any_of(progresses.begin(), progresses.end(), [](const json& p) {
        return p["running"] == 1 && p["steps"].size() == 2 && p["steps"][0]["result"].is_null();
    }));
}

TEST_F(MesRun, TheLiveGraphFollowsTheDetector) {
    theMes->detector().removeServer(pnp::testing::url(device->server));
    const auto until = std::chrono::steady_clock::now() + 5s;
    while (liveSkills() != 0 && std::chrono::steady_clock::now() < until)
        std::this_thread::sleep_for(10ms);
    EXPECT_EQ(liveSkills(), 0u);
    EXPECT_FALSE(kb->ask(
        std::string(mes::kPrefixes) + "ASK { GRAPH <urn:pnp:kb:live> { ?c a pnp:Component } }",
        soon()));
    // And the process is refused for want of a skill.
    EXPECT_EQ(run("urn:pnp:kb:process#two").second["result"], "Refused");
}
