// The tool changer component against a fake robot (a CartesianLinearMove skill and
// SetTool / ClearTool on 127.0.0.1, recording every target) whose flange drives a small model
// of the Kelvin changer and its docks (the rules of cell.md §2), read through the real ADC
// path (KelvinAdcInput -> Modbus TCP -> KelvinAdcDevice -> OPC UA), and fake tool servers
// that the "discovery" (the detector's addServer) sees when their tool is locked.
#include "component/toolchanger/tool_changer.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "device/kelvin/changer_voltage.hpp"
#include "device/kelvin/kelvin_adc_device.hpp"
#include "sim/kelvin/kelvin_adc_input.hpp"
#include "skill/client/skill_client.hpp"
#include "skill/server/controller.hpp"
#include "support/loopback_server.hpp"
#include "support/wait.hpp"
#include "toolchanger/modbus_loopback.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_types_model.hpp"

using namespace pnp;
using namespace std::chrono_literals;
using Eigen::Isometry3d;
namespace tc = component::toolchanger;
using skill::SkillResult;

namespace {

constexpr double kLock = 0.5235987755982988;
constexpr double kTravel = 0.10;    // ToolChangerOptions::travelHeight's default
constexpr double kVacuum = 0.1868;  // the fake tools' grip points below the flange
constexpr double kParallel = 0.2028;
constexpr double kWsg = 0.1950;

Isometry3d pose(double x, double y, double z, double a = 0, double b = 0, double c = 0) {
    ua::ThreeDFrame f;
    f.cartesianCoordinates = {x, y, z};
    f.orientation = {a, b, c};
    return ua::spatial::toIsometry(f);
}
Isometry3d openPose(const Isometry3d& d) {
    return d * Eigen::AngleAxisd(-kLock, Eigen::Vector3d::UnitZ());
}
Isometry3d up(const Isometry3d& p) {
    Isometry3d q = p;
    q.translation().z() += 0.10;
    return q;
}
// `p` at the world height z.
Isometry3d atZ(const Isometry3d& p, double z) {
    Isometry3d q = p;
    q.translation().z() = z;
    return q;
}
bool near(const Isometry3d& a, const Isometry3d& b) {
    return (a.translation() - b.translation()).norm() < 1e-6 &&
           Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle() < 1e-6;
}

// The docks and the changer, by the world's rules: the ring turns only in a dock; locking
// with a tool in the dock attaches it, unlocking in an empty dock parks it.
struct ChangerModel {
    struct Dock {
        Isometry3d pose;
        int tool = 0;  // parked there (0: empty)
    };
    std::mutex m;
    std::vector<Dock> docks;
    enum Lock { Open, Intermediate, Locked } lock = Open;
    int attached = 0;
    Isometry3d flange = pose(0, 0, 0.5, M_PI, 0, 0);
    std::atomic<double> volts{0.0};
    std::function<void(int tool, bool on)> power;  // a tool's power (its server's presence)

    std::optional<std::pair<std::size_t, double>> inDock(const Isometry3d& f) {
        for (std::size_t i = 0; i < docks.size(); ++i) {
            const Isometry3d& d = docks[i].pose;
            if ((f.translation() - d.translation()).norm() > 0.003) continue;
            const double tilt =
                std::acos(std::clamp(f.linear().col(2).dot(d.linear().col(2)), -1.0, 1.0));
            if (tilt > 0.05) continue;
            const Eigen::Matrix3d r = d.linear().transpose() * f.linear();
            return std::make_pair(i, std::atan2(r(1, 0), r(0, 0)));
        }
        return std::nullopt;
    }
    // The flange arrived at `f` (end of a move); `midTurn`: halfway through a turn.
    void moveTo(const Isometry3d& f, bool midTurn = false) {
        std::function<void(int, bool)> notify;
        int changed = 0;
        bool on = false;
        {
            std::lock_guard l(m);
            flange = f;
            auto d = inDock(f);
            if (d) {
                const double phi = d->second;
                Lock next = std::abs(phi) < 0.035           ? Locked
                            : std::abs(phi + kLock) < 0.035 ? Open
                                                            : Intermediate;
                if (midTurn) next = Intermediate;
                Dock& dock = docks[d->first];
                if (next == Locked && lock != Locked && dock.tool != 0 && attached == 0) {
                    attached = dock.tool;
                    dock.tool = 0;
                    changed = attached;
                    on = true;
                } else if (next == Open && lock != Open && attached != 0 && dock.tool == 0) {
                    dock.tool = attached;
                    changed = attached;
                    attached = 0;
                    on = false;
                }
                lock = next;
            }
            volts = lock == Open           ? 0.0
                    : lock == Intermediate ? 2.1
                    : attached             ? device::kelvin::kToolVoltages[attached - 1]
                                           : 4.9;
            notify = power;
        }
        if (changed && notify) notify(changed, on);
    }
};

// The robot: DeviceSet/FakeRobot with CartesianLinearMove (targets recorded; a turn in a
// dock passes through "intermediate" halfway), SetTool and ClearTool, and ActualFlangePose
// (the model's flange) unless built without it.
struct FakeRobot {
    ChangerModel& model;
    std::unique_ptr<ua::server::Server> server;
    std::unique_ptr<skill::server::SkillController> controller;
    std::mutex m;
    std::vector<Isometry3d> targets;
    // Every line moved: from, to, and the tool on the flange meanwhile (0: none).
    struct Line {
        Isometry3d from, to;
        int tool = 0;
    };
    std::vector<Line> lines;
    std::vector<std::string> toolCalls;  // "SetTool name x,y,z" / "ClearTool name"
    std::chrono::milliseconds moveTime{15};
    std::chrono::milliseconds turnTime{15};

    explicit FakeRobot(ChangerModel& cm, bool flangePose = true) : model(cm) {
        auto cfg = pnp::testing::loopbackConfig();
        cfg.applicationUri = "urn:pnp:test:robot";
        server = std::make_unique<ua::server::Server>(cfg);
        auto& space = server->addressSpace();
        skill::server::loadSkillModels(space, {skill::kRoboticsUri});
        controller = std::make_unique<skill::server::SkillController>(
            *server, skill::server::SkillControllerOptions{.name = "FakeRobot"});
        using skill::server::declareParameter;
        skill::server::SkillCallbacks cb;
        cb.execute = [this](skill::server::Execution& run) { return move(run); };
        controller->add(
            "CartesianLinearMove",
            skill::server::makeSkill(skill::types::CartesianLinearMoveSkillType,
                                     {declareParameter<ua::ThreeDFrame>("TargetPosition"),
                                      declareParameter<std::vector<ua::Range>>("AxisBounds"),
                                      declareParameter<std::vector<double>>("MaxVelocity"),
                                      declareParameter<std::vector<double>>("MaxAcceleration"),
                                      declareParameter<ua::String>("ToolFrame")},
                                     std::move(cb)));
        const ua::UInt16 rob = *space.namespaceIndex(skill::kRoboticsUri);
        const ua::Argument name{"Name", ua::NodeId(0, ua::ns0::String), -1, {}, {}};
        const ua::Argument frame{"Frame", ua::NodeId(0, ua::ns0::ThreeDFrame), -1, {}, {}};
        space.addMethod(
            controller->node(), ua::NodeId(1, "FakeRobot.SetTool"),
            ua::QualifiedName(rob, "SetTool"), {name, frame}, {},
            ua::server::makeMethodHandler([this](const auto&, std::vector<ua::Variant>& in, auto&) {
                const auto* n = in.at(0).scalar<ua::String>();
                const auto* x = in.at(1).scalar<ua::ExtensionObject>();
                auto f = x ? ua::fromExtensionObject<ua::ThreeDFrame>(*x) : std::nullopt;
                if (!n || !f) return ua::StatusCode(0x80AB0000u);  // BadInvalidArgument
                std::lock_guard l(m);
                toolCalls.push_back("SetTool " + *n + " " +
                                    std::to_string(f->cartesianCoordinates.z));
                return ua::StatusCode{};
            }));
        space.addMethod(
            controller->node(), ua::NodeId(1, "FakeRobot.ClearTool"),
            ua::QualifiedName(rob, "ClearTool"), {name}, {},
            ua::server::makeMethodHandler([this](const auto&, std::vector<ua::Variant>& in, auto&) {
                const auto* n = in.at(0).scalar<ua::String>();
                std::lock_guard l(m);
                toolCalls.push_back("ClearTool " + (n ? *n : std::string("?")));
                return ua::StatusCode{};
            }));
        if (flangePose) {
            ua::server::VariableAttributes a;
            a.dataType = ua::NodeId(0, ua::ns0::ThreeDFrame);
            a.value = ua::DataValue(ua::Variant(ua::toExtensionObject(ua::ThreeDFrame{})));
            const ua::NodeId n =
                space.addVariable(controller->node(), ua::NodeId(1, "FakeRobot.ActualFlangePose"),
                                  ua::QualifiedName(rob, "ActualFlangePose"), a);
            space.setValueCallback(
                n, {.read =
                        [this](const ua::NodeId&) {
                            std::lock_guard l(model.m);
                            return ua::DataValue(ua::Variant(
                                ua::toExtensionObject(ua::spatial::toFrame(model.flange))));
                        },
                    .write = {}});
        }
        server->start();
    }
    ~FakeRobot() {
        controller.reset();
        server->stop();
    }
    skill::server::Outcome move(skill::server::Execution& run) {
        ua::ThreeDFrame f;
        if (!skill::server::ParamTraits<ua::ThreeDFrame>::fromVariant(*run.value("TargetPosition"),
                                                                      f))
            return skill::server::Outcome::failed("bad target");
        const Isometry3d target = ua::spatial::toIsometry(f);
        Isometry3d from;
        {
            std::lock_guard l(m);
            targets.push_back(target);
        }
        int tool = 0;
        {
            std::lock_guard l(model.m);
            from = model.flange;
            tool = model.attached;
        }
        {
            std::lock_guard l(m);
            lines.push_back({from, target, tool});
        }
        const bool turn = (from.translation() - target.translation()).norm() < 1e-6 &&
                          model.inDock(target).has_value();
        if (turn) {
            if (!run.sleepFor(turnTime / 2)) return skill::server::Outcome::aborted("halted");
            model.moveTo(target, true);  // halfway through the turn
            if (!run.sleepFor(turnTime / 2)) return skill::server::Outcome::aborted("halted");
        } else if (!run.sleepFor(moveTime)) {
            return skill::server::Outcome::aborted("halted");
        }
        model.moveTo(target);
        return skill::server::Outcome::completed();
    }
    std::string url() const { return pnp::testing::url(*server); }
    std::vector<Isometry3d> takeTargets() {
        std::lock_guard l(m);
        return std::exchange(targets, {});
    }
    std::vector<Line> takeLines() {
        std::lock_guard l(m);
        return std::exchange(lines, {});
    }
    std::vector<std::string> takeToolCalls() {
        std::lock_guard l(m);
        return std::exchange(toolCalls, {});
    }
};

// A tool's server: a Grasp skill and IGripperType's GripPoints/GripPoint_1/Offset.
struct FakeTool {
    std::unique_ptr<ua::server::Server> server;
    std::unique_ptr<skill::server::SkillController> controller;
    FakeTool(const std::string& uri, const std::string& name, double offsetZ) {
        auto cfg = pnp::testing::loopbackConfig();
        cfg.applicationUri = uri;
        cfg.applicationName = name;
        server = std::make_unique<ua::server::Server>(cfg);
        auto& space = server->addressSpace();
        skill::server::loadSkillModels(space, {skill::kBaseUri});
        controller = std::make_unique<skill::server::SkillController>(
            *server, skill::server::SkillControllerOptions{.name = name});
        controller->add(
            "Grasp", skill::server::makeSkill(
                         skill::types::GraspGripperSkillType,
                         {skill::server::declareParameter<double>("Force", 20.0, true)},
                         {.execute = [](auto&) { return skill::server::Outcome::completed(); }}));
        const ua::UInt16 base = *space.namespaceIndex(skill::kBaseUri);
        auto points = space.addObject(controller->node(), ua::NodeId(1, name + ".GripPoints"),
                                      ua::QualifiedName(base, "GripPoints"));
        auto point = space.addObject(points, ua::NodeId(1, name + ".GripPoint_1"),
                                     ua::QualifiedName(base, "GripPoint_1"));
        ua::server::VariableAttributes a;
        a.dataType = ua::NodeId(0, ua::ns0::ThreeDFrame);
        a.value = ua::DataValue(
            ua::Variant(ua::toExtensionObject(ua::spatial::toFrame(pose(0, 0, offsetZ)))));
        space.addVariable(point, ua::NodeId(1, name + ".Offset"), ua::QualifiedName(base, "Offset"),
                          a);
        server->start();
    }
    ~FakeTool() {
        controller.reset();
        server->stop();
    }
    std::string url() const { return pnp::testing::url(*server); }
};

// The ADC board on the model's voltage: KelvinAdcInput -> Modbus TCP -> KelvinAdcDevice.
struct FakeAdc {
    sim::kelvin::KelvinAdcInput input;
    modbus::TcpServer modbus;
    std::unique_ptr<ua::server::Server> server;
    std::unique_ptr<device::kelvin::KelvinAdcDevice> device;
    std::jthread stepper;
    explicit FakeAdc(ChangerModel& model)
        : input([&model] { return model.volts.load(); }),
          modbus(pnp::testing::modbusLoopback(), input) {
        modbus.start();
        auto cfg = pnp::testing::loopbackConfig();
        cfg.applicationUri = "urn:pnp:test:kelvin-adc";
        server = std::make_unique<ua::server::Server>(cfg);
        device = std::make_unique<device::kelvin::KelvinAdcDevice>(
            *server, device::kelvin::KelvinAdcDeviceOptions{.adcHost = "127.0.0.1",
                                                            .adcPort = modbus.port()});
        server->start();
        device->start();
        stepper = std::jthread([this](std::stop_token st) {
            while (!st.stop_requested()) {
                input.step(0.002);
                std::this_thread::sleep_for(2ms);
            }
        });
    }
    ~FakeAdc() {
        stepper = {};
        device.reset();
        server->stop();
    }
    std::string url() const { return pnp::testing::url(*server); }
};

struct Cell {
    ChangerModel model;
    Isometry3d dock1 = pose(-0.125, 0.513, -0.036, 0, M_PI, 0);
    Isometry3d dock2 = pose(0.125, 0.513, -0.036, 0, M_PI, 0);
    Isometry3d dock3 = pose(0.3, 0.513, -0.036, 0, M_PI, 0);  // empty
    std::unique_ptr<FakeRobot> robot;
    std::unique_ptr<FakeAdc> adc;
    std::unique_ptr<FakeTool> vacuum, parallel;
    std::unique_ptr<FakeTool> wsg;  // tool 3: on the shelf until an operator puts it in a dock
    std::unique_ptr<ua::server::Server> server;
    std::unique_ptr<tc::ToolChangerComponent> changer;
    std::shared_ptr<ua::client::Client> client;
    std::vector<std::string> log;
    std::mutex logMutex;

    explicit Cell(bool flangePose = true) {
        model.docks = {{dock1, 1}, {dock2, 2}, {dock3, 0}};
        robot = std::make_unique<FakeRobot>(model, flangePose);
        adc = std::make_unique<FakeAdc>(model);
        vacuum = std::make_unique<FakeTool>("urn:pnp:test:vacuum", "Vacuum", kVacuum);
        parallel = std::make_unique<FakeTool>("urn:pnp:test:parallel", "Parallel", kParallel);
        wsg = std::make_unique<FakeTool>("urn:pnp:test:wsg", "Wsg", kWsg);
        auto cfg = pnp::testing::loopbackConfig();
        cfg.applicationUri = "urn:pnp:test:toolchanger";
        server = std::make_unique<ua::server::Server>(cfg);
        tc::ToolChangerOptions o;
        o.robot = robot->url();
        o.adc = adc->url();
        o.detector.useDiscovery = false;
        o.detector.healthInterval = 50ms;
        o.travelVelocity = {};
        o.settleTimeout = 500ms;
        o.toolDetectTimeout = 3000ms;
        o.log = [this](const std::string& line) {
            std::lock_guard l(logMutex);
            log.push_back(line);
        };
        changer = std::make_unique<tc::ToolChangerComponent>(*server, o);
        server->start();
        changer->start();
        // Power = plug in: a locked tool's server is "discovered", an unlocked one is gone.
        // Tool 4 has no server (an adapter that never comes up).
        model.power = [this](int tool, bool on) {
            if (tool < 1 || tool > 3) return;
            const std::string url = (tool == 1 ? vacuum : tool == 2 ? parallel : wsg)->url();
            if (on)
                changer->detector().addServer(url);
            else
                changer->detector().removeServer(url);
        };
        EXPECT_EQ(changer->waitReady(5s), "");
        client = std::make_shared<ua::client::Client>();
        client->connect(pnp::testing::url(*server));
    }
    ~Cell() {
        client.reset();
        changer.reset();
        server->stop();
    }
    skill::client::SkillClient skillClient(const char* name) {
        const auto base = *server->addressSpace().namespaceIndex(skill::kBaseUri);
        const ua::NodeId skills =
            client->resolve(changer->node(), "/" + std::to_string(base) + ":Skills");
        return skill::client::SkillClient(client,
                                          client->resolve(skills, std::string("/1:") + name));
    }
    skill::client::RunResult run(const char* name, std::optional<Isometry3d> dock = std::nullopt,
                                 std::string uri = {}) {
        auto c = skillClient(name);
        skill::client::NamedValues p;
        if (dock)
            p.emplace_back("ToolPosition",
                           ua::Variant(ua::toExtensionObject(ua::spatial::toFrame(*dock))));
        if (!uri.empty()) p.emplace_back("ToolAppUri", ua::Variant(uri));
        return c.run(p, 20s);
    }
    ua::Variant value(std::initializer_list<const char*> path) {
        const ua::UInt16 ns = *server->addressSpace().namespaceIndex(skill::kToolChangerUri);
        std::string p;
        for (const char* n : path) p += "/" + std::to_string(ns) + ":" + n;
        return client->readValue(client->resolve(changer->node(), p));
    }
};

// FinalResultData/<name> of a run (empty Variant: not there).
ua::Variant resultValue(const skill::client::RunResult& r, const std::string& name) {
    for (const auto& [n, v] : r.finalResult.values)
        if (n == name) return v;
    return {};
}
std::string resultText(const skill::client::RunResult& r, const std::string& name) {
    const ua::Variant v = resultValue(r, name);
    const auto* s = v.scalar<ua::String>();
    return s ? *s : "<no " + name + ">";
}
int resultId(const skill::client::RunResult& r) {
    const ua::Variant v = resultValue(r, "ToolId");
    const auto* i = v.scalar<ua::Int32>();
    return i ? *i : -1;
}
std::optional<Isometry3d> resultDock(const skill::client::RunResult& r) {
    const ua::Variant v = resultValue(r, "ToolPosition");
    const auto* x = v.scalar<ua::ExtensionObject>();
    if (x == nullptr) return std::nullopt;
    auto f = ua::fromExtensionObject<ua::ThreeDFrame>(*x);
    if (!f) return std::nullopt;
    return ua::spatial::toIsometry(*f);
}
// Within 1e-6 m / rad (the frame goes through a ThreeDFrame's Euler angles).
bool sameDock(const std::optional<Isometry3d>& a, const Isometry3d& b) {
    return a && (a->translation() - b.translation()).norm() < 1e-6 &&
           Eigen::AngleAxisd(a->linear().transpose() * b.linear()).angle() < 1e-6;
}

// The lowest world z of what the flange carries (the flange, the tool's grip point) along a
// line (position linear, orientation slerp, 200 samples) where it is more than 5 mm
// (horizontally) from every dock; +inf when it is near a dock all along.
double lowestAwayFromDocks(const FakeRobot::Line& l, const std::vector<Isometry3d>& docks) {
    const double length = l.tool == 1   ? kVacuum
                          : l.tool == 2 ? kParallel
                          : l.tool == 3 ? kWsg
                          : l.tool != 0 ? 0.25  // a tool without a server: the assumed length
                                        : 0.0;
    const Eigen::Quaterniond qa(l.from.linear()), qb(l.to.linear());
    double lowest = std::numeric_limits<double>::infinity();
    for (int i = 0; i <= 200; ++i) {
        const double s = i / 200.0;
        Isometry3d f = Isometry3d::Identity();
        f.linear() = qa.slerp(s, qb).toRotationMatrix();
        f.translation() = (1 - s) * l.from.translation() + s * l.to.translation();
        const bool atDock = std::any_of(docks.begin(), docks.end(), [&](const Isometry3d& d) {
            return (f.translation() - d.translation()).head<2>().norm() < 0.005;
        });
        if (atDock) continue;
        lowest =
            std::min({lowest, f.translation().z(), (f * pose(0, 0, length)).translation().z()});
    }
    return lowest;
}
// Every line away from the docks stays at or above the travel height; one that starts below
// it (the arm was left there) goes straight up.
void expectAboveTravelHeight(const std::vector<FakeRobot::Line>& lines,
                             const std::vector<Isometry3d>& docks) {
    for (std::size_t i = 0; i < lines.size(); ++i) {
        const FakeRobot::Line& l = lines[i];
        const double start = lowestAwayFromDocks({l.from, l.from, l.tool}, docks);
        if (start < kTravel - 1e-9) {
            EXPECT_LT((l.to.translation() - l.from.translation()).head<2>().norm(), 1e-9)
                << "line " << i << " starts below the travel height and does not go straight up";
            EXPECT_GT(l.to.translation().z(), l.from.translation().z()) << "line " << i;
            EXPECT_TRUE(l.to.linear().isApprox(l.from.linear(), 1e-9)) << "line " << i;
            continue;
        }
        EXPECT_GE(lowestAwayFromDocks(l, docks), kTravel - 1e-9)
            << "line " << i << " to (" << l.to.translation().transpose() << ") with tool "
            << l.tool;
    }
}

std::vector<std::string> phaseNames(const skill::client::RunResult& r) {
    for (const auto& [name, v] : r.finalResult.values)
        if (name == "Phases")
            if (const auto* a = v.array<ua::String>()) return *a;
    return {};
}

}  // namespace

TEST(ToolChanger, AttachRunsTheDockingSequenceAndSetsTheTool) {
    Cell cell;
    const auto r = cell.run("AttachTool", cell.dock2, "urn:pnp:test:parallel");
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    const auto t = cell.robot->takeTargets();
    ASSERT_EQ(t.size(), 6u);
    // From z 0.5 (above the travel height): across at that height, down above the dock.
    EXPECT_TRUE(near(t[0], atZ(openPose(cell.dock2), 0.5)));
    EXPECT_TRUE(near(t[1], up(openPose(cell.dock2))));
    EXPECT_TRUE(near(t[2], openPose(cell.dock2)));
    EXPECT_TRUE(near(t[3], cell.dock2));
    EXPECT_TRUE(near(t[4], up(cell.dock2)));
    // Clear: straight up until the grip point (0.2028 m below the flange) is at 0.10 m.
    EXPECT_TRUE(near(t[5], atZ(cell.dock2, kTravel + kParallel)));
    EXPECT_EQ(cell.model.attached, 2);
    const auto calls = cell.robot->takeToolCalls();
    ASSERT_EQ(calls.size(), 2u);
    EXPECT_EQ(calls[0], "ClearTool ");
    EXPECT_EQ(calls[1].rfind("SetTool Parallel 0.2028", 0), 0u) << calls[1];
    EXPECT_EQ(phaseNames(r),
              (std::vector<std::string>{"Approach", "Lock", "Leave", "ToolDetected", "Clear"}));
    EXPECT_EQ(*cell.value({"HasTool"}).scalar<bool>(), true);
    EXPECT_EQ(*cell.value({"CurrentTool", "Id"}).scalar<ua::Int32>(), 2);
    EXPECT_EQ(*cell.value({"CurrentTool", "Description"}).scalar<ua::String>(), "Parallel");
    EXPECT_EQ(*cell.value({"CurrentTool", "Endpoint"}).scalar<ua::String>(), cell.parallel->url());
}

TEST(ToolChanger, AttachRefusesWhenAToolIsAttached) {
    Cell cell;
    ASSERT_EQ(cell.run("AttachTool", cell.dock2, "urn:pnp:test:parallel").result,
              SkillResult::Completed);
    cell.robot->takeTargets();
    const auto r = cell.run("AttachTool", cell.dock1, "urn:pnp:test:vacuum");
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_NE(r.message.find("already attached (tool 2"), std::string::npos) << r.message;
    EXPECT_TRUE(cell.robot->takeTargets().empty());
}

TEST(ToolChanger, EmptyDockFailsAndTurnsBackClear) {
    Cell cell;
    const auto r = cell.run("AttachTool", cell.dock3, "urn:pnp:test:parallel");
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_NE(r.message.find("no tool in the dock"), std::string::npos) << r.message;
    const auto t = cell.robot->takeTargets();
    ASSERT_EQ(t.size(), 6u);
    EXPECT_TRUE(near(t[3], cell.dock3));
    EXPECT_TRUE(near(t[4], openPose(cell.dock3)));      // turned back open
    EXPECT_TRUE(near(t[5], up(openPose(cell.dock3))));  // clear of the dock
    EXPECT_EQ(cell.model.lock, ChangerModel::Open);
}

TEST(ToolChanger, WrongDockPoseFailsClear) {
    Cell cell;
    const auto r = cell.run("AttachTool", pose(0.0, 0.4, 0.1, 0, M_PI, 0), "urn:pnp:test:parallel");
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_NE(r.message.find("did not turn"), std::string::npos) << r.message;
    const auto t = cell.robot->takeTargets();
    ASSERT_FALSE(t.empty());
    EXPECT_TRUE(near(t.back(), up(openPose(pose(0.0, 0.4, 0.1, 0, M_PI, 0)))));
}

TEST(ToolChanger, DetachWithoutToolFails) {
    Cell cell;
    const auto r = cell.run("DetachTool", cell.dock2);
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_NE(r.message.find("no tool attached"), std::string::npos) << r.message;
    EXPECT_TRUE(cell.robot->takeTargets().empty());
    const auto d = cell.run("DropTool");
    EXPECT_EQ(d.result, SkillResult::Failed);
}

TEST(ToolChanger, ChangeToolDetachesIntoItsDockThenAttaches) {
    Cell cell;
    ASSERT_EQ(cell.run("ChangeTool", cell.dock2, "urn:pnp:test:parallel").result,
              SkillResult::Completed);
    cell.robot->takeTargets();
    cell.robot->takeToolCalls();
    const auto r = cell.run("ChangeTool", cell.dock1, "urn:pnp:test:vacuum");
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    const auto t = cell.robot->takeTargets();
    // From the first change's Clear pose straight down to above dock 2 (the same x, y).
    ASSERT_EQ(t.size(), 11u);
    EXPECT_TRUE(near(t[0], up(cell.dock2)));
    EXPECT_TRUE(near(t[1], cell.dock2));
    EXPECT_TRUE(near(t[2], openPose(cell.dock2)));
    EXPECT_TRUE(near(t[3], up(openPose(cell.dock2))));
    // Without a tool the flange itself rises to the travel height, crosses, goes down.
    EXPECT_TRUE(near(t[4], atZ(openPose(cell.dock2), kTravel)));
    EXPECT_TRUE(near(t[5], atZ(openPose(cell.dock1), kTravel)));
    EXPECT_TRUE(near(t[6], up(openPose(cell.dock1))));
    EXPECT_TRUE(near(t[8], cell.dock1));
    EXPECT_TRUE(near(t[10], atZ(cell.dock1, kTravel + kVacuum)));
    EXPECT_EQ(cell.model.attached, 1);
    EXPECT_EQ(cell.model.docks[1].tool, 2);  // the parallel gripper back in dock 2
    const auto calls = cell.robot->takeToolCalls();
    EXPECT_NE(std::find(calls.begin(), calls.end(), "ClearTool Parallel"), calls.end());
    EXPECT_EQ(calls.back().rfind("SetTool Vacuum 0.1868", 0), 0u);
    const auto names = phaseNames(r);
    ASSERT_EQ(names.size(), 8u);
    EXPECT_EQ(names.front(), "Detach.Approach");
    EXPECT_EQ(names.back(), "Attach.Clear");
    EXPECT_EQ(*cell.value({"CurrentTool", "Id"}).scalar<ua::Int32>(), 1);

    // DropTool puts it back where it came from.
    const auto d = cell.run("DropTool");
    ASSERT_EQ(d.result, SkillResult::Completed) << d.message;
    EXPECT_EQ(cell.model.attached, 0);
    EXPECT_EQ(cell.model.docks[0].tool, 1);
    EXPECT_EQ(*cell.value({"HasTool"}).scalar<bool>(), false);
}

TEST(ToolChanger, MissingToolServerFails) {
    Cell cell;
    const auto r = cell.run("AttachTool", cell.dock2, "urn:pnp:test:nobody");
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_NE(r.message.find("no server urn:pnp:test:nobody"), std::string::npos) << r.message;
}

TEST(ToolChanger, HaltMidLockLeavesAConditionTheResetReports) {
    Cell cell;
    cell.robot->turnTime = 1200ms;
    auto c = cell.skillClient("AttachTool");
    c.setParameters(
        {{"ToolPosition", ua::Variant(ua::toExtensionObject(ua::spatial::toFrame(cell.dock2)))},
         {"ToolAppUri", ua::Variant(ua::String("urn:pnp:test:parallel"))}});
    c.start();
    // Halfway through the turn the changer reads intermediate.
    ASSERT_TRUE(pnp::testing::waitUntil(
        [&] { return cell.model.lock == ChangerModel::Intermediate; }, 5000ms));
    c.halt();
    ASSERT_TRUE(
        pnp::testing::waitUntil([&] { return !cell.changer->condition().empty(); }, 5000ms));
    const std::string condition = cell.changer->condition();
    EXPECT_NE(condition.find("intermediate"), std::string::npos) << condition;
    EXPECT_NE(condition.find("half locked"), std::string::npos) << condition;
    EXPECT_NE(condition.find("Lock"), std::string::npos) << condition;
    c.reset();
    const auto f = c.finalResult();
    EXPECT_EQ(f.result, SkillResult::Aborted);
    EXPECT_EQ(f.message, condition);
    EXPECT_EQ(*cell.value({"Condition"}).scalar<ua::String>(), condition);
    // The robot's move was halted: no target after the turn.
    const auto t = cell.robot->takeTargets();
    ASSERT_EQ(t.size(), 4u);
    EXPECT_TRUE(near(t.back(), cell.dock2));
    // The next attach sees the half-locked changer and refuses, saying so.
    cell.robot->turnTime = 15ms;
    const auto r = cell.run("AttachTool", cell.dock2, "urn:pnp:test:parallel");
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_NE(r.message.find("intermediate"), std::string::npos) << r.message;
}

// A process names the dock, not the device: with no ToolAppUri the component takes the
// server that appeared after the lock as the tool, sets its grip point and reports it.
TEST(ToolChanger, AttachWithoutToolAppUriLearnsTheToolFromDiscovery) {
    Cell cell;
    const auto r = cell.run("AttachTool", cell.dock2);
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_EQ(cell.model.attached, 2);
    const auto calls = cell.robot->takeToolCalls();
    ASSERT_EQ(calls.size(), 2u);
    EXPECT_EQ(calls[1].rfind("SetTool Parallel 0.2028", 0), 0u) << calls[1];
    EXPECT_EQ(phaseNames(r),
              (std::vector<std::string>{"Approach", "Lock", "Leave", "ToolDetected", "Clear"}));
    EXPECT_EQ(resultText(r, "ToolAppUri"), "urn:pnp:test:parallel");
    EXPECT_EQ(resultText(r, "ToolName"), "Parallel");
    EXPECT_EQ(resultText(r, "ToolEndpoint"), cell.parallel->url());
    EXPECT_EQ(resultId(r), 2);
    EXPECT_TRUE(sameDock(resultDock(r), cell.dock2));
    EXPECT_EQ(*cell.value({"CurrentTool", "ApplicationUri"}).scalar<ua::String>(),
              "urn:pnp:test:parallel");
    EXPECT_EQ(*cell.value({"CurrentTool", "Description"}).scalar<ua::String>(), "Parallel");
    EXPECT_EQ(*cell.value({"CurrentTool", "Endpoint"}).scalar<ua::String>(), cell.parallel->url());

    // The same dock again: its tool is on the flange already (nothing moves).
    cell.robot->takeTargets();
    const auto again = cell.run("ChangeTool", cell.dock2);
    ASSERT_EQ(again.result, SkillResult::Completed) << again.message;
    EXPECT_NE(again.message.find("already attached"), std::string::npos) << again.message;
    EXPECT_TRUE(cell.robot->takeTargets().empty());
    EXPECT_EQ(resultText(again, "ToolAppUri"), "urn:pnp:test:parallel");
    EXPECT_TRUE(sameDock(resultDock(again), cell.dock2));
}

// An operator swaps the tool in dock 2 (the parallel gripper out, another tool in): the next
// ChangeTool to dock 2 attaches and reports the tool really there; DetachTool / DropTool
// report the tool they parked.
TEST(ToolChanger, ASwappedToolInADockIsLearnedAnew) {
    Cell cell;
    auto r = cell.run("ChangeTool", cell.dock2);
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_EQ(resultText(r, "ToolAppUri"), "urn:pnp:test:parallel");
    r = cell.run("ChangeTool", cell.dock1);
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_EQ(resultText(r, "ToolAppUri"), "urn:pnp:test:vacuum");
    EXPECT_EQ(resultId(r), 1);
    EXPECT_TRUE(sameDock(resultDock(r), cell.dock1));
    EXPECT_EQ(cell.model.docks[1].tool, 2);

    // The operator: the parallel gripper onto the shelf, tool 3 into dock 2.
    {
        std::lock_guard l(cell.model.m);
        cell.model.docks[1].tool = 3;
    }
    cell.robot->takeToolCalls();
    r = cell.run("ChangeTool", cell.dock2);
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_EQ(cell.model.attached, 3);
    EXPECT_EQ(cell.model.docks[0].tool, 1);  // the vacuum gripper back in dock 1
    EXPECT_EQ(resultText(r, "ToolAppUri"), "urn:pnp:test:wsg");
    EXPECT_EQ(resultText(r, "ToolName"), "Wsg");
    EXPECT_EQ(resultText(r, "ToolEndpoint"), cell.wsg->url());
    EXPECT_EQ(resultId(r), 3);
    EXPECT_TRUE(sameDock(resultDock(r), cell.dock2));
    EXPECT_EQ(cell.robot->takeToolCalls().back().rfind("SetTool Wsg 0.195", 0), 0u);
    EXPECT_EQ(*cell.value({"CurrentTool", "ApplicationUri"}).scalar<ua::String>(),
              "urn:pnp:test:wsg");
    EXPECT_EQ(*cell.value({"CurrentTool", "Id"}).scalar<ua::Int32>(), 3);

    // DropTool parks it where it came from and says which tool it parked where.
    const auto d = cell.run("DropTool");
    ASSERT_EQ(d.result, SkillResult::Completed) << d.message;
    EXPECT_EQ(cell.model.docks[1].tool, 3);
    EXPECT_EQ(resultText(d, "ToolAppUri"), "urn:pnp:test:wsg");
    EXPECT_EQ(resultId(d), 3);
    EXPECT_TRUE(sameDock(resultDock(d), cell.dock2));
    EXPECT_EQ(*cell.value({"CurrentTool", "ApplicationUri"}).scalar<ua::String>(), "");

    // DetachTool too.
    ASSERT_EQ(cell.run("AttachTool", cell.dock1).result, SkillResult::Completed);
    const auto t = cell.run("DetachTool", cell.dock1);
    ASSERT_EQ(t.result, SkillResult::Completed) << t.message;
    EXPECT_EQ(resultText(t, "ToolAppUri"), "urn:pnp:test:vacuum");
    EXPECT_EQ(resultId(t), 1);
    EXPECT_TRUE(sameDock(resultDock(t), cell.dock1));
}

// A tool whose server never comes up: Failed after toolDetectTimeout, saying so; a server
// that was up before the lock (not the tool's) is not taken for it.
TEST(ToolChanger, NoToolServerAfterTheLockFails) {
    Cell cell;
    {
        std::lock_guard l(cell.model.m);
        cell.model.docks[2].tool = 4;  // dock 3: a tool without a server
    }
    cell.changer->detector().addServer(cell.wsg->url());  // up before the lock
    ASSERT_TRUE(cell.changer->detector().waitUntil(
        [](const auto& d) { return !d.find(skill::types::GripperSkillType).empty(); }, 5000ms));
    const auto started = std::chrono::steady_clock::now();
    const auto r = cell.run("AttachTool", cell.dock3);
    EXPECT_EQ(r.result, SkillResult::Failed);
    EXPECT_NE(r.message.find("tool 4 locked but no tool server appeared within 3000 ms"),
              std::string::npos)
        << r.message;
    EXPECT_GE(std::chrono::steady_clock::now() - started, 3000ms);
    EXPECT_EQ(cell.model.attached, 4);  // locked: the changer says so
    EXPECT_EQ(resultId(r), 4);
    EXPECT_EQ(resultText(r, "ToolAppUri"), "");
    EXPECT_TRUE(sameDock(resultDock(r), cell.dock3));
    EXPECT_EQ(*cell.value({"CurrentTool", "Id"}).scalar<ua::Int32>(), 4);
    EXPECT_EQ(*cell.value({"CurrentTool", "ApplicationUri"}).scalar<ua::String>(), "");
}

// Given a ToolAppUri, FinalResultData names that tool as before.
TEST(ToolChanger, NamedToolIsReportedInTheFinalResult) {
    Cell cell;
    const auto r = cell.run("ChangeTool", cell.dock1, "urn:pnp:test:vacuum");
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    EXPECT_EQ(resultText(r, "ToolAppUri"), "urn:pnp:test:vacuum");
    EXPECT_EQ(resultText(r, "ToolName"), "Vacuum");
    EXPECT_EQ(resultText(r, "ToolEndpoint"), cell.vacuum->url());
    EXPECT_EQ(resultId(r), 1);
    EXPECT_TRUE(sameDock(resultDock(r), cell.dock1));
}

// From low over the table (the flange 6 cm above it), an attach first rises to the travel
// height, crosses to above the dock, goes down, and after the lock lifts the tool until its
// grip point is at the travel height: no line away from the dock dips below it.
TEST(ToolChanger, AttachFromLowOverTheTableRisesFirstAndLeavesTheToolClear) {
    Cell cell;
    {
        std::lock_guard l(cell.model.m);
        cell.model.flange = pose(0.05, 0.10, 0.06, M_PI, 0, 0);
    }
    const auto r = cell.run("AttachTool", cell.dock2, "urn:pnp:test:parallel");
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    const auto t = cell.robot->takeTargets();
    ASSERT_EQ(t.size(), 7u);
    EXPECT_TRUE(near(t[0], pose(0.05, 0.10, kTravel, M_PI, 0, 0)));  // straight up
    EXPECT_TRUE(near(t[1], atZ(openPose(cell.dock2), kTravel)));     // across
    EXPECT_TRUE(near(t[2], up(openPose(cell.dock2))));               // down to O↑
    EXPECT_TRUE(near(t[5], up(cell.dock2)));
    EXPECT_TRUE(near(t[6], atZ(cell.dock2, kTravel + kParallel)));  // Clear
    const auto lines = cell.robot->takeLines();
    ASSERT_EQ(lines.size(), t.size());
    expectAboveTravelHeight(lines, {cell.dock1, cell.dock2, cell.dock3});
    // SetTool comes after the Clear move (its targets are flange poses).
    const auto calls = cell.robot->takeToolCalls();
    ASSERT_EQ(calls.size(), 2u);
    EXPECT_EQ(calls[1].rfind("SetTool Parallel", 0), 0u) << calls[1];
}

// Pick-and-place left the vacuum gripper's tip 5 cm above the table: ChangeTool first lifts
// it to the travel height, crosses, parks it, and brings the next tool up clear. A straight
// line to above the dock (as before) would have dipped the tool below the travel height.
TEST(ToolChanger, ChangeToolFromAboveTheTableStaysAboveTheTravelHeight) {
    Cell cell;
    ASSERT_EQ(cell.run("ChangeTool", cell.dock1, "urn:pnp:test:vacuum").result,
              SkillResult::Completed);
    cell.robot->takeTargets();
    cell.robot->takeLines();
    const Isometry3d overTable = pose(0.05, 0.10, 0.05 + kVacuum, M_PI, 0, 0);
    {
        std::lock_guard l(cell.model.m);
        cell.model.flange = overTable;
    }
    const std::vector<Isometry3d> docks = {cell.dock1, cell.dock2, cell.dock3};
    // The check is not vacuous: the direct line from there to above the dock goes below.
    EXPECT_LT(lowestAwayFromDocks({overTable, up(cell.dock1), 1}, docks), kTravel - 0.05);

    const auto r = cell.run("ChangeTool", cell.dock2, "urn:pnp:test:parallel");
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    const auto t = cell.robot->takeTargets();
    ASSERT_EQ(t.size(), 13u);
    EXPECT_TRUE(near(t[0], atZ(overTable, kTravel + kVacuum)));   // up
    EXPECT_TRUE(near(t[1], atZ(cell.dock1, kTravel + kVacuum)));  // across
    EXPECT_TRUE(near(t[2], up(cell.dock1)));                      // down to D↑
    EXPECT_TRUE(near(t[3], cell.dock1));
    EXPECT_TRUE(near(t[5], up(openPose(cell.dock1))));            // parked
    EXPECT_TRUE(near(t[6], atZ(openPose(cell.dock1), kTravel)));  // the flange up
    EXPECT_TRUE(near(t[7], atZ(openPose(cell.dock2), kTravel)));  // across
    EXPECT_TRUE(near(t[8], up(openPose(cell.dock2))));
    EXPECT_TRUE(near(t[12], atZ(cell.dock2, kTravel + kParallel)));  // Clear
    expectAboveTravelHeight(cell.robot->takeLines(), docks);
    EXPECT_EQ(cell.model.attached, 2);
    EXPECT_EQ(cell.model.docks[0].tool, 1);

    // DropTool from over the table too.
    {
        std::lock_guard l(cell.model.m);
        cell.model.flange = pose(-0.05, -0.10, 0.03 + kParallel, M_PI, 0, 0);
    }
    const auto d = cell.run("DropTool");
    ASSERT_EQ(d.result, SkillResult::Completed) << d.message;
    const auto dt = cell.robot->takeTargets();
    ASSERT_EQ(dt.size(), 6u);
    EXPECT_TRUE(near(dt[0], pose(-0.05, -0.10, kTravel + kParallel, M_PI, 0, 0)));
    expectAboveTravelHeight(cell.robot->takeLines(), docks);
    EXPECT_EQ(cell.model.docks[1].tool, 2);
}

// A robot without ActualFlangePose: where the arm is is unknown, so the approach is the one
// line to above the dock (as before), and the log says so.
TEST(ToolChanger, WithoutTheRobotsPoseTheApproachIsOneLineAndTheLogSaysSo) {
    Cell cell(false);
    const auto r = cell.run("AttachTool", cell.dock2, "urn:pnp:test:parallel");
    ASSERT_EQ(r.result, SkillResult::Completed) << r.message;
    const auto t = cell.robot->takeTargets();
    ASSERT_EQ(t.size(), 5u);
    EXPECT_TRUE(near(t[0], up(openPose(cell.dock2))));
    EXPECT_TRUE(near(t[4], atZ(cell.dock2, kTravel + kParallel)));  // Clear still
    std::lock_guard l(cell.logMutex);
    EXPECT_TRUE(std::any_of(cell.log.begin(), cell.log.end(), [](const std::string& line) {
        return line.find("where the arm is is unknown") != std::string::npos &&
               line.find("ActualFlangePose") != std::string::npos;
    }));
}
