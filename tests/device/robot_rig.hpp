// The device tests' set-up: FakeArm -> robot::Controller + Planner -> RobotDevice on a
// server at 127.0.0.1 (ephemeral port), and a connected client.
#pragma once

#include <chrono>
#include <cmath>
#include <memory>
#include <numbers>
#include <stdexcept>
#include <string>
#include <utility>

#include "device/robot/robot_device.hpp"
#include "fake_arm.hpp"
#include "kinematics/kinematics.hpp"
#include "support/loopback_server.hpp"
#include "support/wait.hpp"
#include "ua/client/client.hpp"

namespace pnp::testing {

using namespace std::chrono_literals;

inline constexpr double kPi = std::numbers::pi;
// A UR5 pose away from singularities: shoulder -90°, elbow 90°, wrists -90°.
inline const robot::Joints kHome{0.0, -kPi / 2, kPi / 2, -kPi / 2, -kPi / 2, 0.0};

inline double distance(const robot::Joints& a, const robot::Joints& b) {
    double d = 0.0;
    for (std::size_t i = 0; i < a.size(); ++i) d = std::max(d, std::abs(a[i] - b[i]));
    return d;
}

struct Rig {
    FakeArm arm;
    robot::Controller controller;
    robot::Planner planner;
    ua::server::Server server{pnp::testing::loopbackConfig()};
    std::unique_ptr<device::robot::RobotDevice> device;
    std::shared_ptr<ua::client::Client> ua = std::make_shared<ua::client::Client>();

    static robot::ControllerConfig controllerConfig(const kinematics::RobotModel& m) {
        robot::ControllerConfig c;
        c.limits = device::robot::defaultLimits(m).joint;
        return c;
    }
    static robot::PlannerConfig plannerConfig(const kinematics::RobotModel& m) {
        robot::PlannerConfig c;
        c.model = m;
        c.defaults = device::robot::defaultLimits(m);
        return c;
    }

    explicit Rig(robot::Joints start = kHome)
        : arm(start),
          controller(arm, controllerConfig(arm.model())),
          planner(plannerConfig(arm.model())) {
        auto started = controller.start(robot::Clock::now() + 5s);
        if (!started) throw std::runtime_error("controller: " + started.error().message);
        device = std::make_unique<device::robot::RobotDevice>(
            server, controller, planner,
            device::robot::RobotDeviceOptions{.name = "Arm",
                                              .identity = device::robot::identityOf(arm)});
        server.start();
        ua->connect(pnp::testing::url(server));
        // The controller has samples (a move plans from the current joints).
        waitUntil([&] { return controller.state().has_value(); }, 3000ms);
    }
    ~Rig() {
        ua->disconnect();
        device.reset();
        server.stop();
        controller.stop();
    }

    ua::NodeId skill(const char* name) const { return device->skillNode(name); }

    // Namespace indexes as the client sees them, and a browse path of (index, name) steps.
    ua::UInt16 di() { return ua->namespaceIndex("http://opcfoundation.org/UA/DI/", 5s); }
    ua::UInt16 rob() { return ua->namespaceIndex("http://opcfoundation.org/UA/Robotics/", 5s); }
    ua::UInt16 skr() { return ua->namespaceIndex("urn:pnp:ua:skills:robotics", 5s); }
    ua::NodeId at(const ua::NodeId& start,
                  std::initializer_list<std::pair<ua::UInt16, std::string>> path) {
        std::string text;
        for (const auto& [ns, name] : path) text += "/" + std::to_string(ns) + ":" + name;
        return ua->resolve(start, text, 5s);
    }

    // The flange pose in the world frame at q (no tool).
    Eigen::Isometry3d flangeAt(const robot::Joints& q) const {
        return planner.worldToBase() * kinematics::forward(arm.model(), q);
    }
};

}  // namespace pnp::testing
