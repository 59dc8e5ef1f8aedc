// pnp_bench_pickplace: the composition overhead of PickAndPlace (end of one lower skill ->
// Start of the next, from their transition events), next to a baseline from the same run: the
// plain round trip of a skill's Start call. Everything in one process on loopback: a robot
// server with a CartesianLinearMove that takes 20 ms, a vacuum gripper (the gripper device
// over the tests' fake hardware), the knowledge base a small in-memory answer, and the
// component on its own server; PickAndPlace is run N times with our skill client.
//
//   pnp_bench_pickplace [runs, default 20]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "component/pickplace/pick_place.hpp"
#include "device/gripper/gripper_device.hpp"
#include "device/gripper/hardware_access.hpp"
#include "gripper/fake_gripper.hpp"
#include "skill/client/skill_client.hpp"
#include "skill/server/controller.hpp"
#include "ua/client/client.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"

namespace {

using namespace std::chrono_literals;
using namespace pnp;
using Clock = std::chrono::steady_clock;

// The knowledge base's answer for the one object (the component's query and update).
class OneObject : public kb::KnowledgeBase {
  public:
    kb::Results select(std::string_view, kb::Deadline) override {
        kb::Results r;
        r.variables = {"pose", "size"};
        r.rows.push_back({kb::Term{kb::Term::Kind::Literal, "0.05,0.10,0.02,0,0,0", "", ""},
                          kb::Term{kb::Term::Kind::Literal, "0.04,0.04,0.04", "", ""}});
        return r;
    }
    bool ask(std::string_view, kb::Deadline) override { return true; }
    void update(std::string_view, kb::Deadline) override {}
    std::size_t loadTurtle(const std::filesystem::path&, const std::string&,
                           kb::Deadline) override {
        return 0;
    }
    std::string describe() const override { return "bench (one object)"; }
};

ua::server::ServerConfig config(const std::string& name) {
    ua::server::ServerConfig c;
    c.host = "127.0.0.1";
    c.publicHost = "127.0.0.1";
    c.port = 0;
    c.applicationUri = "urn:pnp:bench:pickplace:" + name;
    c.applicationName = name;
    return c;
}

double median(std::vector<double> v) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}
double percentile(std::vector<double> v, double p) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, static_cast<std::size_t>(p * v.size()))];
}

}  // namespace

int main(int argc, char** argv) {
    const int runs = argc > 1 ? std::clamp(std::atoi(argv[1]), 1, 1000) : 20;

    // The robot: a CartesianLinearMove of 20 ms.
    ua::server::Server robotServer(config("BenchRobot"));
    skill::server::loadSkillModels(robotServer.addressSpace(), {skill::kRoboticsUri});
    skill::server::SkillController robot(robotServer, {.name = "BenchRobot"});
    using skill::server::declareParameter;
    skill::server::SkillCallbacks move;
    move.execute = [](skill::server::Execution& run) {
        return run.sleepFor(20ms) ? skill::server::Outcome::completed()
                                  : skill::server::Outcome::aborted("halted");
    };
    const auto moveNode =
        robot
            .add("CartesianLinearMove",
                 skill::server::makeSkill(skill::types::CartesianLinearMoveSkillType,
                                          {declareParameter<ua::ThreeDFrame>("TargetPosition"),
                                           declareParameter<std::vector<ua::Range>>("AxisBounds"),
                                           declareParameter<std::vector<double>>("MaxVelocity"),
                                           declareParameter<std::vector<double>>("MaxAcceleration"),
                                           declareParameter<ua::String>("ToolFrame", "")},
                                          std::move(move)))
            .node();
    robotServer.start();

    // The vacuum gripper.
    pnp::testing::FakeGripper hardware(device::gripper::GripKind::kVacuum);
    hardware.timeScale = 1000.0;
    if (!hardware.connect(device::gripper::Clock::now() + 1s)) {
        std::fprintf(stderr, "the fake gripper does not connect\n");
        return 1;
    }
    device::gripper::HardwareAccess access(hardware);
    ua::server::Server gripperServer(config("BenchGripper"));
    device::gripper::GripperDevice gripper(gripperServer, access, {.name = "BenchGripper"});
    gripperServer.start();

    // The component.
    ua::server::Server ppServer(config("BenchPickPlace"));
    component::pickplace::PickPlaceOptions options;
    options.knowledge = std::make_shared<OneObject>();
    options.detector.useDiscovery = false;
    options.log = [](const std::string&) {};
    component::pickplace::PickPlaceComponent pickPlace(ppServer, options);
    ppServer.start();
    pickPlace.start();
    pickPlace.detector().addServer(robotServer.endpointUrl());
    pickPlace.detector().addServer(gripperServer.endpointUrl());
    pickPlace.detector().waitUntil(
        [](const skill::detector::SkillDetector& d) {
            return !d.find(skill::types::CartesianLinearMoveSkillType).empty() &&
                   !d.find(skill::types::GraspGripperSkillType).empty();
        },
        5s);

    auto uaClient = std::make_shared<ua::client::Client>();
    uaClient->connect(ppServer.endpointUrl());
    skill::client::SkillClient pp(uaClient, pickPlace.skillNode());
    ua::ThreeDFrame place;
    place.cartesianCoordinates = {-0.05, -0.10, 0.0};
    std::vector<double> overhead, runS;
    int completed = 0;
    for (int i = 0; i < runs; ++i) {
        const auto t0 = Clock::now();
        const auto r = pp.run({{"ObjectId", ua::Variant(ua::String("cube-green"))},
                               {"PlacePosition", ua::Variant(ua::toExtensionObject(place))}},
                              Clock::now() + 30s);
        runS.push_back(std::chrono::duration<double>(Clock::now() - t0).count());
        if (r.result == skill::SkillResult::Completed)
            ++completed;
        else
            std::fprintf(stderr, "run %d: %s\n", i, r.message.c_str());
        for (const auto& s : pickPlace.lastSteps())
            if (s.overheadMs >= 0) overhead.push_back(s.overheadMs);
    }

    // Baseline: the plain round trip of a Start call on the robot's move (then its end).
    auto robotClient = std::make_shared<ua::client::Client>();
    robotClient->connect(robotServer.endpointUrl());
    skill::client::SkillClient mv(robotClient, moveNode);
    std::vector<double> startRtt;
    for (int i = 0; i < std::max(runs, 50); ++i) {
        const auto t0 = Clock::now();
        mv.start(Clock::now() + 2s);
        startRtt.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        for (int k = 0; k < 200 && mv.state(Clock::now() + 2s) != skill::ProgramState::Ready; ++k)
            std::this_thread::sleep_for(5ms);
    }
    std::printf("PickAndPlace runs: %d (%d completed), run median %.3f s\n", runs, completed,
                median(runS));
    std::printf(
        "composition overhead (end of a lower skill -> Start of the next, %zu gaps): "
        "median %.3f ms, p90 %.3f ms, max %.3f ms\n",
        overhead.size(), median(overhead), percentile(overhead, 0.9),
        overhead.empty() ? 0.0 : *std::max_element(overhead.begin(), overhead.end()));
    std::printf("baseline: Start call round trip, median %.3f ms, p90 %.3f ms\n", median(startRtt),
                percentile(startRtt, 0.9));
    pickPlace.stop();
    return completed == runs ? 0 : 1;
}
