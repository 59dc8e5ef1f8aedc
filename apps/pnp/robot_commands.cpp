// `pnp robot square`: the thesis's square test (chapter 8.1). A generic client that knows the
// robot only by its skills (found by type, on a URL or by discovery) runs PTP to the square's
// upper-left corner, LIN along the four edges and PTP back to where the robot was (read from
// its OPC 40010-1 Axes), and measures the path from the simulated world's ground truth
// (urn:pnp:sim:world): the largest distance of the TCP from the ideal square while it runs
// the edges, and the end pose error of every move.
#include <signal.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <iomanip>
#include <iostream>
#include <memory>
#include <mutex>
#include <numbers>
#include <optional>
#include <sstream>
#include <vector>

#include "commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"
#include "skill/client/typed_clients.hpp"
#include "skill/detector/skill_detector.hpp"
#include "ua/client/client.hpp"
#include "ua/client/error.hpp"
#include "ua/client/subscription.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/status_codes.hpp"
#include "value_text.hpp"

namespace pnp::cli {

namespace {

using namespace std::chrono;
using skill::detector::DetectedSkill;

struct SquareOptions {
    std::string target = "auto";  // opc.tcp://... of the robot, or auto (discovery)
    double size = 0.1;            // m
    std::vector<double> center{0.0, 0.35, 0.25};
    std::vector<double> orientation{std::numbers::pi, 0.0, 0.0};
    std::string world = "opc.tcp://127.0.0.1:4850";
    std::string worldRobot;  // robot name in the world; empty: the only / first one
    double speed = 0.1;      // m/s along the edges
    int timeoutMs = 60000;
    int discoverMs = 5000;
    std::vector<std::string> lds;
    bool noMdns = false;
    int mdnsPort = 5353;
    bool json = false;
    SecurityOptions security;
};

std::vector<double> parseNumbers(const std::string& text, std::size_t count, const char* what) {
    std::vector<double> out;
    std::stringstream ss(text);
    std::string item;
    while (std::getline(ss, item, ',')) {
        try {
            std::size_t used = 0;
            out.push_back(std::stod(item, &used));
            if (used != item.size()) throw std::invalid_argument(item);
        } catch (const std::exception&) {
            throw UsageError(std::string(what) + ": not a number: " + item);
        }
        if (!std::isfinite(out.back())) throw UsageError(std::string(what) + ": not finite");
    }
    if (out.size() != count)
        throw UsageError(std::string(what) + ": expected " + std::to_string(count) +
                         " comma-separated numbers");
    return out;
}

// Distance of p from the segment a-b.
double segmentDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                       const Eigen::Vector3d& b) {
    const Eigen::Vector3d ab = b - a;
    const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
    return (a + t * ab - p).norm();
}

struct Sample {
    double time;  // world time, s
    Eigen::Vector3d position;
};

int runSquare(SquareOptions& o) {
    const sigset_t stopSignals = blockStopSignals();
    (void)stopSignals;
    const auto deadline = steady_clock::now() + milliseconds(o.timeoutMs);
    const bool byUrl = o.target.starts_with("opc.tcp://");
    if (!byUrl && o.target != "auto") throw UsageError("TARGET is opc.tcp://HOST:PORT or auto");
    if (!(o.size > 0.0 && o.size <= 1.0)) throw UsageError("--size must be within (0, 1] m");
    if (!(o.speed > 0.0 && o.speed <= 1.0)) throw UsageError("--speed must be within (0, 1] m/s");
    secureClients(o.security);

    // 1. The robot's move skills, by type, on one component.
    std::unique_ptr<mdns::Mdns> mdns;
    if (!byUrl && !o.noMdns) {
        try {
            mdns = std::make_unique<mdns::Mdns>(mdnsConfig({}, o.mdnsPort, 120));
            mdns->start();
        } catch (const std::exception& e) {
            if (o.lds.empty()) {
                std::cerr << "error: mDNS: " << e.what() << "\n";
                return kExitUaError;
            }
            mdns.reset();
        }
    }
    if (!byUrl && !mdns && o.lds.empty()) throw UsageError("--no-mdns needs an --lds URL");
    skill::detector::DetectorConfig dc;
    dc.watcher.ldsUrls = o.lds;
    dc.useDiscovery = !byUrl;
    skill::detector::SkillDetector detector(mdns.get(), dc);
    detector.start();
    if (byUrl) detector.addServer(o.target);
    struct Found {
        DetectedSkill ptp, lin, joint;
    };
    auto pick = [](const skill::detector::SkillDetector& d) -> std::optional<Found> {
        for (const auto& lin : d.find(skill::types::CartesianLinearMoveSkillType))
            for (const auto& ptp : d.find(skill::types::CartesianPtpMoveSkillType))
                for (const auto& joint : d.find(skill::types::JointPtpMoveSkillType))
                    if (lin.endpointUrl == ptp.endpointUrl && lin.controller == ptp.controller &&
                        joint.endpointUrl == lin.endpointUrl && joint.controller == lin.controller)
                        return Found{ptp, lin, joint};
        return std::nullopt;
    };
    detector.waitUntil([&](const auto& d) { return pick(d).has_value(); },
                       milliseconds(std::min(o.discoverMs, o.timeoutMs)));
    const auto found = pick(detector);
    detector.stop();
    if (!found) {
        std::cerr << "error: no robot with CartesianPtpMove, CartesianLinearMove and JointPtpMove "
                     "skills found"
                  << (byUrl ? " on " + o.target : std::string(" by discovery")) << "\n";
        return kExitUaError;
    }
    std::cerr << "pnp robot square: robot " << found->lin.controllerName << " at "
              << found->lin.endpointUrl << std::endl;

    auto robot = std::make_shared<ua::client::Client>();
    robot->connect(found->lin.endpointUrl, ua::client::Anonymous{}, deadline);

    // 2. Where the robot is: its OPC 40010-1 axes (Axes/<axis>/ParameterSet/ActualPosition).
    // Browse paths name namespaces by index here: a URI's own '/' would end the path element.
    const std::string rob = std::to_string(robot->namespaceIndex(skill::kRoboticsCsUri, deadline));
    const std::string di = std::to_string(robot->namespaceIndex(skill::kDiUri, deadline));
    const ua::NodeId axesFolder =
        robot->resolve(found->lin.controller, "/" + rob + ":Axes", deadline);
    auto axes = robot->browse(axesFolder, {}, deadline);
    std::vector<std::pair<std::string, ua::NodeId>> axisNodes;
    for (const auto& r : axes) {
        if (r.nodeClass != ua::NodeClass::Object) continue;
        try {
            axisNodes.emplace_back(
                r.browseName.name,
                robot->resolve(robot->toNodeId(r.nodeId, deadline),
                               "/" + di + ":ParameterSet/" + rob + ":ActualPosition", deadline));
        } catch (const ua::client::Error&) {
        }
    }
    std::sort(axisNodes.begin(), axisNodes.end());
    std::vector<double> home;
    for (const auto& [name, node] : axisNodes) {
        const auto v = robot->readValue(node, deadline);
        const auto* d = v.scalar<double>();
        if (d == nullptr)
            throw ua::client::Error(ua::status::BadTypeMismatch,
                                    "axis " + name + ": ActualPosition is no Double");
        home.push_back(*d);
    }
    if (home.size() != 6) {
        std::cerr << "error: the robot has " << home.size() << " axes with ActualPosition, not 6\n";
        return kExitUaError;
    }

    // 3. The world's ground truth: the TCP position of the robot, every update.
    ua::client::Client world;
    world.connect(o.world, ua::client::Anonymous{}, deadline);
    const auto worldNs = world.namespaceIndex("urn:pnp:sim:world", deadline);
    std::string robotName = o.worldRobot;
    if (robotName.empty()) {
        auto robots = world.browse(world.resolve("/Objects/" + std::to_string(worldNs) + ":World/" +
                                                     std::to_string(worldNs) + ":Robots",
                                                 deadline),
                                   {}, deadline);
        for (const auto& r : robots)
            if (r.nodeClass == ua::NodeClass::Object) {
                robotName = r.browseName.name;
                break;
            }
        if (robotName.empty()) {
            std::cerr << "error: the world at " << o.world << " has no robot\n";
            return kExitUaError;
        }
    }
    const ua::NodeId tcpNode(worldNs, "Robots." + robotName + ".TcpPose");
    const ua::NodeId timeNode(worldNs, "World.Time");
    std::mutex mutex;
    std::vector<Sample> samples;
    bool recording = false;
    double lastTime = 0.0;
    ua::client::Subscription sub(world, {.publishingInterval = 20}, {}, deadline);
    auto items = sub.monitorValues(
        {tcpNode, timeNode},
        [&](std::size_t index, const ua::DataValue& v) {
            std::lock_guard lock(mutex);
            if (!v.value) return;
            if (index == 1) {
                if (auto* t = v.value->scalar<double>()) lastTime = *t;
                return;
            }
            const auto* x = v.value->scalar<ua::ExtensionObject>();
            if (!x) return;
            if (auto f = ua::fromExtensionObject<ua::ThreeDFrame>(*x); f && recording)
                samples.push_back(Sample{lastTime, ua::spatial::toIsometry(*f).translation()});
        },
        {.samplingInterval = 0, .queueSize = 10000}, nullptr, deadline);
    world.startBackgroundThread();
    auto worldTcp = [&]() {
        const auto v = world.readValue(tcpNode, deadline);
        const auto* x = v.scalar<ua::ExtensionObject>();
        auto f = x ? ua::fromExtensionObject<ua::ThreeDFrame>(*x) : std::nullopt;
        if (!f) throw ua::client::Error(ua::status::BadTypeMismatch, "TcpPose");
        return ua::spatial::toIsometry(*f);
    };

    // 4. The square, in the world frame.
    const Eigen::Vector3d c(o.center[0], o.center[1], o.center[2]);
    const double h = o.size / 2.0;
    const std::vector<Eigen::Vector3d> corners = {
        c + Eigen::Vector3d(-h, h, 0), c + Eigen::Vector3d(h, h, 0), c + Eigen::Vector3d(h, -h, 0),
        c + Eigen::Vector3d(-h, -h, 0)};
    auto frameAt = [&](const Eigen::Vector3d& p) {
        ua::ThreeDFrame f;
        f.cartesianCoordinates = {p.x(), p.y(), p.z()};
        f.orientation = {o.orientation[0], o.orientation[1], o.orientation[2]};
        return f;
    };
    skill::client::CartesianPtpMoveSkillClient ptp(robot, found->ptp.node, deadline);
    skill::client::CartesianLinearMoveSkillClient lin(robot, found->lin.node, deadline);
    skill::client::JointPtpMoveSkillClient joint(robot, found->joint.node, deadline);

    Json moves = Json::array();
    double maxEndError = 0.0;
    // Settled: the world's truth updates at its own rate; wait until two reads agree.
    auto settledTcp = [&]() {
        auto a = worldTcp();
        for (int i = 0; i < 50; ++i) {
            std::this_thread::sleep_for(20ms);
            auto b = worldTcp();
            if ((a.translation() - b.translation()).norm() < 1e-9) return b;
            a = b;
        }
        return a;
    };
    auto check = [&](const std::string& what, const skill::client::RunResult& r,
                     const std::optional<Eigen::Vector3d>& goal) {
        Json m = {{"move", what}, {"result", std::string(skill::toString(r.result))}};
        if (r.result != skill::SkillResult::Completed) {
            m["message"] = r.message;
            moves.push_back(m);
            throw std::runtime_error(what + " did not complete: " +
                                     std::string(skill::toString(r.result)) + " " + r.message);
        }
        if (goal) {
            const double e = (settledTcp().translation() - *goal).norm();
            maxEndError = std::max(maxEndError, e);
            m["endErrorMm"] = e * 1e3;
        }
        moves.push_back(m);
    };

    const std::vector<double> linSpeed{o.speed};
    try {
        skill::client::CartesianMove first;
        first.target = frameAt(corners[0]);
        check("PTP to the upper-left corner", ptp.run(first, deadline).run, corners[0]);
        {
            std::lock_guard lock(mutex);
            recording = true;
        }
        for (int k = 1; k <= 4; ++k) {
            skill::client::CartesianMove edge;
            edge.target = frameAt(corners[k % 4]);
            edge.maxVelocity = linSpeed;
            check("LIN edge " + std::to_string(k), lin.run(edge, deadline).run, corners[k % 4]);
        }
        {
            std::lock_guard lock(mutex);
            recording = false;
        }
        skill::client::JointMove back;
        back.targetJoints = home;
        check("PTP home", joint.run(back, deadline), std::nullopt);
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        return 3;
    }

    double deviation = 0.0;
    std::size_t n = 0;
    {
        std::lock_guard lock(mutex);
        n = samples.size();
        for (const auto& s : samples) {
            double d = std::numeric_limits<double>::infinity();
            for (int k = 0; k < 4; ++k)
                d = std::min(d, segmentDistance(s.position, corners[k], corners[(k + 1) % 4]));
            deviation = std::max(deviation, d);
        }
    }
    if (o.json) {
        Json j = {{"robot", found->lin.controllerName},
                  {"url", found->lin.endpointUrl},
                  {"size", o.size},
                  {"samples", n},
                  {"maxDeviationMm", deviation * 1e3},
                  {"maxEndErrorMm", maxEndError * 1e3},
                  {"moves", moves}};
        std::cout << j.dump() << std::endl;
    } else {
        for (const auto& m : moves) {
            std::cout << std::left << std::setw(30) << m["move"].get<std::string>() << " "
                      << m["result"].get<std::string>();
            if (m.contains("endErrorMm"))
                std::cout << "  end error " << std::fixed << std::setprecision(4)
                          << m["endErrorMm"].get<double>() << " mm";
            std::cout << "\n";
        }
        std::cout << std::fixed << std::setprecision(4)
                  << "largest deviation from the square: " << deviation * 1e3 << " mm (" << n
                  << " ground-truth samples); largest end "
                  << "error: " << maxEndError * 1e3 << " mm" << std::endl;
    }
    if (n == 0) {
        std::cerr << "error: no ground-truth samples were recorded\n";
        return kExitUaError;
    }
    return kExitOk;
}

}  // namespace

std::function<int()> addRobotCommands(CLI::App& app) {
    auto o = std::make_shared<SquareOptions>();
    auto center = std::make_shared<std::string>();
    auto orientation = std::make_shared<std::string>();
    CLI::App* robot = app.add_subcommand("robot", "robot tests that use only a robot's skills");
    robot->require_subcommand(1);
    CLI::App* square = robot->add_subcommand(
        "square",
        "the thesis's square test: PTP to a corner, LIN along four edges, PTP home; prints "
        "the largest deviation from the square, from the simulated world's ground truth");
    square->add_option("TARGET", o->target, "the robot's server (opc.tcp://HOST:PORT) or auto")
        ->capture_default_str();
    square->add_option("--size", o->size, "edge length, m")->capture_default_str();
    square->add_option("--center", *center,
                       "centre of the square in the world frame, x,y,z in m (default 0,0.35,0.25)");
    square->add_option("--orientation", *orientation,
                       "tool orientation a,b,c in rad (fixed X, Y, Z; default pi,0,0: pointing "
                       "down)");
    square->add_option("--speed", o->speed, "TCP speed along the edges, m/s")
        ->capture_default_str();
    square->add_option("--world", o->world, "the simulator's ground truth (pnp sim's \"world\")")
        ->capture_default_str();
    square->add_option("--world-robot", o->worldRobot, "the robot's name in the world");
    square->add_option("--timeout", o->timeoutMs, "deadline of the whole test, ms")
        ->capture_default_str()
        ->check(CLI::Range(1, 3600000));
    square->add_option("--discover", o->discoverMs, "auto: how long to look for the robot, ms")
        ->capture_default_str();
    square->add_option("--lds", o->lds, "auto: also poll this LDS-ME (repeatable)");
    addConnectionSecurityOptions(square, o->security);
    square->add_flag("--no-mdns", o->noMdns, "auto: no multicast, --lds only");
    square->add_option("--mdns-port", o->mdnsPort, "mDNS UDP port")->capture_default_str();
    square->add_flag("--json", o->json, "print one JSON object");
    return [square, o, center, orientation]() -> int {
        if (!*square) return -1;
        if (!center->empty()) o->center = parseNumbers(*center, 3, "--center");
        if (!orientation->empty()) o->orientation = parseNumbers(*orientation, 3, "--orientation");
        return runSquare(*o);
    };
}

}  // namespace pnp::cli
