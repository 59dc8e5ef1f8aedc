// The cell's faults, against the real processes of `pnp cell up` (one cell for the suite): a
// missing skill is refused by the MES's check before anything moves; a gripper's adapter
// killed in the middle of a process stops it with a reason that names the step and the skill,
// and once the adapter is back a Reset and a new run complete; a Halt of ExecuteProcess in
// the middle of a step halts every lower skill running under it and the robot stops.
//
// The process is a short one of the test's own (Turtle, loaded with --add-kb-file): change to
// the tool of dock 1 (the vacuum gripper), pick the green cube and place it at place B, park
// the tool. Its results are checked against the simulator's ground truth, never against what
// the components say about themselves.
//
// The tests run in order and share the cell: each leaves it as it found it (the tool parked,
// the cube at rest on the table, every process up).
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "skill/client/generic_client.hpp"
#include "skill/detector/skill_detector.hpp"
#include "skill/model/model.hpp"
#include "support/child_process.hpp"
#include "support/machine_pki.hpp"
#include "support/shell.hpp"
#include "ua/client/client.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"

#ifndef PNP_BINARY
#error "PNP_BINARY must be defined"
#endif

namespace {

using namespace std::chrono_literals;
using nlohmann::json;
using pnp::testing::ChildProcess;
using Clock = std::chrono::steady_clock;
namespace ua = pnp::ua;
namespace skill = pnp::skill;
namespace detector = pnp::skill::detector;

const std::string kPnp = PNP_BINARY;
const std::string kProcess = "urn:pnp:kb:process#faults";
// Where the process places the cube: place B (models/kb/cell-thesis.ttl) is the support point
// of its bottom face; the 4 cm cube's centre is 2 cm above it.
constexpr std::array<double, 3> kCubeAtPlaceB = {-0.05, -0.10, 0.02};

constexpr const char* kProcessTurtle = R"(
@prefix pnp:  <urn:pnp:kb#> .
@prefix cell: <urn:pnp:kb:cell#> .
@prefix proc: <urn:pnp:kb:process#> .
@prefix tc:   <urn:pnp:ua:skills:toolchanger#> .
@prefix comp: <urn:pnp:ua:skills:composite#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .

proc:faults a pnp:Process ; pnp:id "faults" ;
    rdfs:label "the fault tests: the vacuum gripper, the cube to place B, the tool parked" .

proc:faults-1 a pnp:Step ; pnp:process proc:faults ; pnp:index 1 ;
    rdfs:label "change to the tool of dock 1" ;
    pnp:skillType tc:ChangeToolSkillType ;
    pnp:binding
        [ pnp:name "ToolPosition" ; pnp:from cell:dock-1 ; pnp:via pnp:pose ] ,
        [ pnp:name "ToolAppUri" ; pnp:value "" ] .

proc:faults-2 a pnp:Step ; pnp:process proc:faults ; pnp:index 2 ;
    rdfs:label "pick the green cube and place it at place B" ;
    pnp:skillType comp:PickAndPlaceSkillType ;
    pnp:binding
        [ pnp:name "ObjectId" ; pnp:from cell:cube-green ; pnp:via pnp:id ] ,
        [ pnp:name "PlacePosition" ; pnp:from cell:place-b ; pnp:via pnp:pose ] ,
        [ pnp:name "ToolSkillControllerEndpoint" ; pnp:value "" ] ,
        [ pnp:name "MoveSkillControllerEndpoint" ; pnp:value "" ] .

proc:faults-3 a pnp:Step ; pnp:process proc:faults ; pnp:index 3 ;
    rdfs:label "park the tool in its dock" ;
    pnp:skillType tc:DropToolSkillType .
)";
constexpr const char* kPickPlaceStep = "step 2 (pick the green cube and place it at place B)";

std::string tmpPath(const std::string& name) { return pnp::testing::tmpPath("cellfaults", name); }

double secondsSince(Clock::time_point t) {
    return std::chrono::duration<double>(Clock::now() - t).count();
}

// Running (a zombie counts as gone).
bool alive(pid_t pid) {
    std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
    std::string line;
    if (!std::getline(stat, line)) return false;
    const auto close = line.rfind(')');
    return close != std::string::npos && close + 2 < line.size() && line[close + 2] != 'Z';
}

// Polls `done` every `period` until it holds or `timeout` passes; true if it held.
template <typename Pred>
bool waitFor(Pred done, std::chrono::milliseconds timeout,
             std::chrono::milliseconds period = 10ms) {
    const auto end = Clock::now() + timeout;
    for (;;) {
        if (done()) return true;
        if (Clock::now() >= end) return false;
        std::this_thread::sleep_for(period);
    }
}

// The simulator's ground truth (`pnp sim`'s world server), read as the tests' referee.
class World {
  public:
    void connect(const std::string& url) {
        client_.connect(url, ua::client::Anonymous{}, Clock::now() + 10s);
        ns_ = client_.namespaceIndex("urn:pnp:sim:world", Clock::now() + 5s);
    }
    ua::Variant value(const std::string& path) {
        return client_.readValue(ua::NodeId(ns_, path), Clock::now() + 5s);
    }
    std::string text(const std::string& path) {
        const auto v = value(path);
        const auto* s = v.scalar<ua::String>();
        return s ? std::string(*s) : std::string("<not a String>");
    }
    bool flag(const std::string& path) {
        const auto v = value(path);
        const auto* b = v.scalar<ua::Boolean>();
        return b != nullptr && *b;
    }
    std::vector<double> joints() {
        const auto v = value("Robots.ur5.Joints");
        const auto* q = v.array<double>();
        return q ? *q : std::vector<double>{};
    }
    // The centre of an object.
    std::array<double, 3> position(const std::string& object) {
        const auto v = value("Objects." + object + ".Pose");
        const auto* x = v.scalar<ua::ExtensionObject>();
        const auto f = x ? ua::fromExtensionObject<ua::ThreeDFrame>(*x) : std::nullopt;
        if (!f) return {NAN, NAN, NAN};
        return {f->cartesianCoordinates.x, f->cartesianCoordinates.y, f->cartesianCoordinates.z};
    }

  private:
    ua::client::Client client_;
    ua::UInt16 ns_ = 0;
};

double maxDifference(const std::vector<double>& a, const std::vector<double>& b) {
    if (a.size() != b.size() || a.empty()) return INFINITY;
    double d = 0;
    for (std::size_t i = 0; i < a.size(); ++i) d = std::max(d, std::abs(a[i] - b[i]));
    return d;
}

double distanceMm(const std::array<double, 3>& a, const std::array<double, 3>& b) {
    return 1e3 * std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                           (a[2] - b[2]) * (a[2] - b[2]));
}

// A skill of a server, by type, through the generic client (its own connection).
struct SkillHandle {
    std::shared_ptr<ua::client::Client> connection;
    std::unique_ptr<skill::client::GenericSkillClient> client;

    static SkillHandle on(const std::string& url, const skill::ModelNode& type) {
        detector::DetectorConfig config;
        config.useDiscovery = false;
        detector::SkillDetector d(nullptr, config);
        d.start();
        d.addServer(url);
        d.waitUntil([&](const detector::SkillDetector& x) { return !x.find(type).empty(); }, 10s);
        const auto found = d.find(type);
        d.stop();
        if (found.empty()) throw std::runtime_error("no " + std::string(type.name) + " on " + url);
        SkillHandle h;
        h.connection = std::make_shared<ua::client::Client>();
        h.connection->connect(url, ua::client::Anonymous{}, Clock::now() + 10s);
        h.client = std::make_unique<skill::client::GenericSkillClient>(
            h.connection, found.front().node, Clock::now() + 10s);
        return h;
    }
    skill::ProgramState state() { return client->state(Clock::now() + 2s); }
};

const char* name(skill::ProgramState s) {
    switch (s) {
        case skill::ProgramState::Ready:
            return "Ready";
        case skill::ProgramState::Running:
            return "Running";
        case skill::ProgramState::Suspended:
            return "Suspended";
        case skill::ProgramState::Halted:
            return "Halted";
        default:
            return "Unknown";
    }
}

class CellFaults : public ::testing::Test {
  protected:
    // ---- the cell, once for the suite ------------------------------------------------------
    static void SetUpTestSuite() {
        const std::string turtle = tmpPath("process.ttl");
        std::ofstream(turtle) << kProcessTurtle;
        up_ = std::make_unique<ChildProcess>();
        std::string error, line;
        if (!up_->start({kPnp, "cell", "up", "--log-dir", tmpPath("logs"), "--add-kb-file", turtle},
                        tmpPath("up.log"), error)) {
            setupError_ = error;
            return;
        }
        // Its one JSON line once every process is up.
        if (!up_->waitForPrefix("{", 120s, error, &line)) {
            setupError_ = "`pnp cell up` did not come up: " + error + "\n" + up_->logTail();
            return;
        }
        cell_ = json::parse(line, nullptr, false);
        if (!cell_.is_object() || !cell_.contains("children") || !cell_.contains("mes")) {
            setupError_ = "unexpected line of `pnp cell up`: " + line + "\n" + up_->logTail();
            return;
        }
        for (const auto& c : cell_.at("children")) children_[c.at("name")] = c;
        try {
            pnp::testing::useMachinePki();  // the cell's servers are secured
            world_ = std::make_unique<World>();
            world_->connect(cell_.at("world"));
            detector::DetectorConfig config;
            config.watcher.ldsUrls = {cell_.at("lds").get<std::string>()};
            config.watcher.pollInterval = 50ms;
            config.watcher.followLds = false;
            discovery_ = std::make_unique<detector::SkillDetector>(nullptr, config);
            discovery_->start();
        } catch (const std::exception& e) {
            setupError_ = std::string("the cell's ground truth / discovery: ") + e.what();
        }
    }

    static void TearDownTestSuite() {
        if (discovery_) discovery_->stop();
        discovery_.reset();
        world_.reset();
        // Ours first (the children a test started again), then the runner: it stops its own.
        restarted_.clear();
        if (up_) up_->stop(30s);
        up_.reset();
    }

    void SetUp() override { ASSERT_TRUE(setupError_.empty()) << setupError_; }

    // ---- the cell's processes ----------------------------------------------------------------
    static json child(const std::string& name) {
        const auto it = children_.find(name);
        return it == children_.end() ? json() : it->second;
    }

    // Kills a child of the cell (SIGKILL: no goodbye to anyone) and waits until it is gone.
    static void kill(const std::string& name) {
        const pid_t pid = children_.at(name).at("pid").get<pid_t>();
        ASSERT_GT(pid, 1);
        if (auto it = restarted_.find(name); it != restarted_.end()) {
            it->second->kill9();
        } else {
            ASSERT_EQ(::kill(pid, SIGKILL), 0) << name << " " << pid;
        }
        EXPECT_TRUE(waitFor([&] { return !alive(pid); }, 5s)) << name << " still alive";
    }

    // Starts a child of the cell again with its argv; waits for its first line ("listening
    // on URL" of a server, the JSON line of a tool's adapter). Returns that line.
    static std::string restart(const std::string& name, const std::string& readyPrefix) {
        auto& c = children_.at(name);
        auto p = std::make_unique<ChildProcess>();
        std::string error, line;
        const auto argv = c.at("argv").get<std::vector<std::string>>();
        const std::string log = tmpPath(name + "-" + std::to_string(++restarts_) + ".log");
        if (!p->start(argv, log, error)) {
            ADD_FAILURE() << name << ": " << error;
            return {};
        }
        if (!p->waitForPrefix(readyPrefix, 30s, error, &line)) {
            ADD_FAILURE() << name << " did not come back: " << error << "\n" << p->logTail();
            return {};
        }
        c["pid"] = p->pid();
        c["log"] = log;
        if (readyPrefix == "listening on ") c["url"] = line.substr(13);
        restarted_[name] = std::move(p);
        return line;
    }

    // Until the cell's discovery (the LDS-ME, examined like the MES's detector does) offers a
    // skill of `type` from the component with this ApplicationUri, or no longer does.
    static bool discovered(const skill::ModelNode& type, const std::string& appUri, bool present,
                           std::chrono::milliseconds timeout) {
        return discovery_->waitUntil(
            [&](const detector::SkillDetector& d) {
                bool found = false;
                for (const auto& s : d.find(type)) found |= s.componentUri == appUri;
                return found == present;
            },
            timeout);
    }

    // ---- the MES ---------------------------------------------------------------------------
    // `pnp mes run IRI --mes URL --json`, bounded; the execution record.
    static json runProcess(std::chrono::seconds timeout = 120s) {
        ChildProcess run;
        std::string error, line;
        const std::string mes = cell_.at("mes");
        if (!run.start({"/usr/bin/timeout", "-k", "5", std::to_string(timeout.count() + 10), kPnp,
                        "mes", "run", kProcess, "--mes", mes, "--json", "--timeout",
                        std::to_string(timeout.count())},
                       tmpPath("mes-run.log"), error)) {
            ADD_FAILURE() << error;
            return {};
        }
        if (!run.waitForPrefix("{", timeout + 15s, error, &line)) {
            ADD_FAILURE() << "`pnp mes run` printed no record: " << error << "\n" << run.logTail();
            return {};
        }
        return json::parse(line, nullptr, false);
    }

    // The MES's execution records so far (its --record file, one JSON line each).
    static std::vector<json> records() {
        const auto argv = child("mes").at("argv").get<std::vector<std::string>>();
        std::string file;
        for (std::size_t i = 0; i + 1 < argv.size(); ++i)
            if (argv[i] == "--record") file = argv[i + 1];
        std::vector<json> out;
        std::ifstream f(file);
        for (std::string line; std::getline(f, line);)
            out.push_back(json::parse(line, nullptr, false));
        return out;
    }

    static std::string logTail(const std::string& name) {
        std::ifstream f(child(name).value("log", std::string()));
        std::string s((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
        return "\n--- " + name + ":\n" + (s.size() > 3000 ? s.substr(s.size() - 3000) : s);
    }
    static std::string diagnostics() {
        return logTail("mes") + logTail("pick-place") + logTail("toolchanger") + logTail("ecbpi");
    }

    // ---- the world ---------------------------------------------------------------------------
    // At rest: no joint moves more than 1e-5 rad (5 µm at the TCP) in 0.3 s.
    static bool robotAtRest() {
        const auto a = world_->joints();
        std::this_thread::sleep_for(300ms);
        return maxDifference(a, world_->joints()) < 1e-5;
    }

    // The cell as each test leaves it: no tool on the flange (the vacuum gripper in dock 1),
    // the cube standing on the table.
    static void expectCellClean() {
        EXPECT_EQ(world_->text("Robots.ur5.Tool"), "");
        EXPECT_EQ(world_->text("Tools.vacuum-gripper.Dock"), "dock-1");
        EXPECT_EQ(world_->text("Objects.cube-green.Holder"), "table");
    }

    static inline std::unique_ptr<ChildProcess> up_;
    static inline json cell_;
    static inline std::map<std::string, json> children_;
    static inline std::map<std::string, std::unique_ptr<ChildProcess>> restarted_;
    static inline std::unique_ptr<World> world_;
    static inline std::unique_ptr<detector::SkillDetector> discovery_;
    static inline std::string setupError_;
    static inline int restarts_ = 0;
};

// `pnp cell up`'s line names every process with what a test needs to hurt it.
TEST_F(CellFaults, TheCellUpLineNamesEveryProcess) {
    for (const char* name : {"lds", "mes", "sim", "ur", "kelvin-adc", "robotiq", "ecbpi", "wsg",
                             "toolchanger", "pick-place"}) {
        const json c = child(name);
        ASSERT_TRUE(c.is_object()) << name << " missing: " << cell_.dump(2);
        EXPECT_TRUE(alive(c.at("pid").get<pid_t>())) << c.dump();
        EXPECT_TRUE(std::filesystem::exists(c.at("log").get<std::string>())) << c.dump();
        const auto argv = c.at("argv").get<std::vector<std::string>>();
        ASSERT_GE(argv.size(), 2u) << c.dump();
        EXPECT_EQ(argv[0], kPnp) << c.dump();
        EXPECT_EQ(c.value("url", std::string()).rfind("opc.tcp://", 0), 0u) << c.dump();
    }
    EXPECT_EQ(child("sim").at("url").get<std::string>(), cell_.at("world").get<std::string>());
    EXPECT_EQ(child("mes").at("url").get<std::string>(), cell_.at("mes").get<std::string>());
    EXPECT_TRUE(cell_.at("problems").empty()) << cell_.at("problems").dump();
    EXPECT_EQ(cell_.at("pid").get<pid_t>(), up_->pid());
}

// Without the Pick-and-Place component the MES's check refuses the process, naming the step
// and what is missing, and nothing moves; with the component back, it is offered again.
TEST_F(CellFaults, AMissingSkillIsRefusedBeforeAnythingMoves) {
    const std::string uri = "urn:pnp:cell:pick-place";
    ASSERT_TRUE(discovered(skill::types::PickAndPlaceSkillType, uri, true, 10s));
    kill("pick-place");
    ASSERT_TRUE(discovered(skill::types::PickAndPlaceSkillType, uri, false, 10s))
        << "the killed Pick-and-Place is still offered";

    const auto before = world_->joints();
    ASSERT_EQ(before.size(), 6u);
    const auto t0 = Clock::now();
    const json record = runProcess(60s);
    const double took = secondsSince(t0);
    ASSERT_TRUE(record.is_object()) << record.dump();
    EXPECT_EQ(record.value("result", ""), "Refused") << record.dump(2) << diagnostics();
    const std::string reason = record.value("reason", "");
    EXPECT_NE(reason.find(kPickPlaceStep), std::string::npos) << reason;
    EXPECT_NE(reason.find("no available skill of type PickAndPlaceSkillType"), std::string::npos)
        << reason;
    // Only that is missing; no step ran.
    ASSERT_TRUE(record.contains("missing")) << record.dump(2);
    EXPECT_EQ(record.at("missing").size(), 1u) << record.at("missing").dump(2);
    EXPECT_TRUE(record.value("steps", json::array()).empty()) << record.at("steps").dump(2);
    // The check waits a while for a late skill (the MES's --find-timeout, 5 s), not longer.
    EXPECT_LT(took, 20.0);
    // The world: the robot did not move, no tool was taken.
    EXPECT_LT(maxDifference(before, world_->joints()), 1e-9);
    EXPECT_EQ(world_->text("Robots.ur5.Tool"), "");

    // Back with the same command line: offered again.
    ASSERT_NE(restart("pick-place", "listening on "), "");
    EXPECT_TRUE(discovered(skill::types::PickAndPlaceSkillType, uri, true, 10s))
        << "the restarted Pick-and-Place was not detected";
}

// The vacuum gripper's adapter dies while PickAndPlace is on its way to the cube: the MES ends
// the process Failed, naming the step and the skill, without hanging. With the adapter back
// (its tool still powered on the flange), Reset and a new run complete, the cube within 1 mm
// of place B by the ground truth.
TEST_F(CellFaults, AGripperKilledMidProcessFailsItAndAfterItsReturnARunCompletes) {
    const std::string gripperUri = "urn:pnp:cell:ecbpi";
    const std::string robot = child("ur").at("url");
    auto pickPlace =
        SkillHandle::on(child("pick-place").at("url"), skill::types::PickAndPlaceSkillType);
    auto linear = SkillHandle::on(robot, skill::types::CartesianLinearMoveSkillType);

    // The process, in the background, as a user runs it.
    ChildProcess run;
    std::string error, line;
    ASSERT_TRUE(
        run.start({"/usr/bin/timeout", "-k", "5", "130", kPnp, "mes", "run", kProcess, "--mes",
                   cell_.at("mes").get<std::string>(), "--json", "--timeout", "120"},
                  tmpPath("mes-run-kill.log"), error))
        << error;
    // PickAndPlace running and the robot moving under it (the first move: the approach above
    // the cube; the gripper has not been used yet).
    bool ended = false;
    const bool moving = waitFor(
        [&] {
            ended = !run.running();
            return ended || (pickPlace.state() == skill::ProgramState::Running &&
                             linear.state() == skill::ProgramState::Running);
        },
        60s);
    ASSERT_TRUE(moving && !ended) << "PickAndPlace never ran"
                                  << (ended ? ": the process ended first" : "") << diagnostics();
    EXPECT_EQ(world_->text("Robots.ur5.Tool"), "vacuum-gripper");
    EXPECT_EQ(world_->text("Objects.cube-green.Holder"), "table");
    const auto killedAt = Clock::now();
    kill("ecbpi");

    ASSERT_TRUE(run.waitForPrefix("{", 60s, error, &line))
        << "the MES did not end the process: " << error << diagnostics();
    const double took = secondsSince(killedAt);
    const json record = json::parse(line, nullptr, false);
    ASSERT_TRUE(record.is_object()) << line;
    EXPECT_EQ(record.value("result", ""), "Failed") << record.dump(2);
    const std::string reason = record.value("reason", "");
    EXPECT_EQ(reason.rfind(std::string(kPickPlaceStep) + ": PickAndPlace on ", 0), 0u) << reason;
    // Its cause: the gripper's skill, at the endpoint that is gone.
    EXPECT_NE(reason.find("Grasp on ECBPi failed"), std::string::npos) << reason;
    EXPECT_NE(reason.find(child("ecbpi").at("url").get<std::string>()), std::string::npos)
        << reason;
    // Bounded: the rest of the approach and the descent (~3 s), then the failed grasp.
    EXPECT_LT(took, 20.0) << reason;
    RecordProperty("killToFailedS", std::to_string(took));
    ASSERT_EQ(record.at("steps").size(), 2u) << record.dump(2);
    EXPECT_EQ(record.at("steps")[0].value("result", ""), "Completed");
    EXPECT_EQ(record.at("steps")[1].value("result", ""), "Failed");
    // The world: the cube was never taken; the robot is at rest.
    EXPECT_EQ(world_->text("Objects.cube-green.Holder"), "table");
    EXPECT_TRUE(waitFor([] { return robotAtRest(); }, 10s, 0ms)) << "the robot still moves";
    EXPECT_EQ(world_->text("Robots.ur5.Tool"), "vacuum-gripper");
    EXPECT_TRUE(world_->flag("Tools.vacuum-gripper.Powered"));

    // The adapter back with its command line: powered, it serves at once, at the same URL.
    const std::string back = restart("ecbpi", "{");
    ASSERT_NE(back, "");
    EXPECT_EQ(json::parse(back, nullptr, false).value("endpointUrl", ""),
              child("ecbpi").at("url").get<std::string>());
    ASSERT_TRUE(discovered(skill::types::GraspGripperSkillType, gripperUri, true, 15s))
        << "the restarted gripper's skills were not detected" << logTail("ecbpi");

    auto execute = SkillHandle::on(cell_.at("mes"), skill::types::ExecuteProcessSkillType);
    if (execute.state() == skill::ProgramState::Halted) execute.client->reset(Clock::now() + 5s);
    EXPECT_EQ(execute.state(), skill::ProgramState::Ready);
    const json again = runProcess(120s);
    ASSERT_TRUE(again.is_object());
    EXPECT_EQ(again.value("result", ""), "Completed") << again.dump(2) << diagnostics();
    const auto cube = world_->position("cube-green");
    EXPECT_LE(distanceMm(cube, kCubeAtPlaceB), 1.0)
        << cube[0] << ", " << cube[1] << ", " << cube[2];
    expectCellClean();
}

// Halt of ExecuteProcess while PickAndPlace's robot motion runs: within 2 s ExecuteProcess,
// PickAndPlace and the robot's CartesianLinearMove are Halted and the robot is at rest. A
// Reset and a new run then complete.
TEST_F(CellFaults, HaltOfExecuteProcessMidStepHaltsEveryRunningLowerSkill) {
    auto execute = SkillHandle::on(cell_.at("mes"), skill::types::ExecuteProcessSkillType);
    auto pickPlace =
        SkillHandle::on(child("pick-place").at("url"), skill::types::PickAndPlaceSkillType);
    auto linear =
        SkillHandle::on(child("ur").at("url"), skill::types::CartesianLinearMoveSkillType);
    auto& mes = *execute.client;
    const auto deadline = [] { return Clock::now() + 5s; };
    const std::size_t recordsBefore = records().size();
    ASSERT_TRUE(mes.lock("cell faults test", deadline()));
    if (execute.state() == skill::ProgramState::Halted) mes.reset(deadline());
    mes.setParametersFromText({"ProcessIri=" + kProcess}, deadline());
    mes.start(deadline());

    bool ended = false;
    const bool moving = waitFor(
        [&] {
            ended = execute.state() != skill::ProgramState::Running;
            return ended || (pickPlace.state() == skill::ProgramState::Running &&
                             linear.state() == skill::ProgramState::Running);
        },
        60s);
    if (!moving || ended) {
        if (!ended) mes.halt(deadline());
        if (execute.state() == skill::ProgramState::Halted) mes.reset(deadline());
        mes.unlock(deadline());
        FAIL() << "PickAndPlace's motion never ran: ExecuteProcess " << name(execute.state())
               << (records().empty() ? std::string() : "; " + records().back().dump(2))
               << diagnostics();
    }
    const auto haltedAt = Clock::now();
    mes.halt(deadline());

    skill::ProgramState e{}, p{}, l{};
    const bool allHalted = waitFor(
        [&] {
            e = execute.state();
            p = pickPlace.state();
            l = linear.state();
            return e == skill::ProgramState::Halted && p == skill::ProgramState::Halted &&
                   l == skill::ProgramState::Halted;
        },
        2s);
    const double took = secondsSince(haltedAt);
    EXPECT_TRUE(allHalted) << "2 s after the Halt: ExecuteProcess " << name(e) << ", PickAndPlace "
                           << name(p) << ", CartesianLinearMove " << name(l) << diagnostics();
    bool atRest = false;
    const auto restBy = haltedAt + 2s;
    while (!atRest && Clock::now() < restBy) atRest = robotAtRest();
    EXPECT_TRUE(atRest) << "the robot still moves 2 s after the Halt";
    RecordProperty("haltToAllHaltedMs", std::to_string(took * 1e3));

    EXPECT_EQ(mes.finalResult(deadline()).result, skill::SkillResult::Aborted);
    // The execution record (the MES's --record file: a halted run's FinalResultData keeps
    // only Result and Message) says where it stopped.
    ASSERT_TRUE(waitFor([&] { return records().size() > recordsBefore; }, 5s))
        << "no record of the halted run" << diagnostics();
    const json r = records().back();
    ASSERT_TRUE(r.is_object());
    EXPECT_EQ(r.value("result", ""), "Halted") << r.dump(2);
    EXPECT_EQ(r.value("reason", ""),
              std::string(kPickPlaceStep) + ": PickAndPlace on Pick and place halted")
        << r.dump(2);
    ASSERT_EQ(r.at("steps").size(), 2u) << r.dump(2);
    EXPECT_EQ(r.at("steps")[1].value("result", ""), "Halted") << r.dump(2);
    EXPECT_EQ(world_->text("Objects.cube-green.Holder"), "table");

    mes.reset(deadline());
    mes.unlock(deadline());
    EXPECT_EQ(execute.state(), skill::ProgramState::Ready);
    const json again = runProcess(120s);
    ASSERT_TRUE(again.is_object());
    EXPECT_EQ(again.value("result", ""), "Completed") << again.dump(2) << diagnostics();
    const auto cube = world_->position("cube-green");
    EXPECT_LE(distanceMm(cube, kCubeAtPlaceB), 1.0)
        << cube[0] << ", " << cube[1] << ", " << cube[2];
    expectCellClean();
}

}  // namespace
