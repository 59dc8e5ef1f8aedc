#include "world/world.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>

#include "kinematics/kinematics.hpp"

namespace pnp::world {

namespace {

bool finite(const Joints& v) {
    return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
}

// Depth of `point` below the top face of a box whose top face centre is `top` (its z axis the
// face normal), or 0 when the point is outside the footprint, above the face or below the
// body (a point under a table is not pushed up through it).
double depthBelowTop(const Eigen::Isometry3d& top, const Eigen::Vector3d& size,
                     const Eigen::Vector3d& point) {
    const Eigen::Vector3d local = top.inverse() * point;
    if (std::abs(local.x()) > 0.5 * size.x() || std::abs(local.y()) > 0.5 * size.y()) return 0.0;
    const double depth = -local.z();
    if (depth <= 0.0 || depth > size.z()) return 0.0;
    return depth;
}

}  // namespace

World::World(CellDescription cell, WorldConfig config) : cell_(std::move(cell)), config_(config) {
    for (const RobotDescription& r : cell_.robots) {
        RobotState s;
        s.name = r.name;
        s.q = r.home;
        s.tool = r.tool;
        robots_.push_back(std::move(s));
    }
    for (const ToolDescription& t : cell_.tools) {
        ToolState s;
        s.name = t.name;
        for (const DockDescription& d : cell_.docks) {
            if (d.tool == t.name) s.dock = d.name;
        }
        for (const RobotDescription& r : cell_.robots) {
            if (r.tool == t.name) s.robot = r.name;
        }
        tools_.push_back(std::move(s));
    }
    for (const ObjectDescription& o : cell_.objects) {
        objects_.push_back({o.name, o.pose, o.on.value_or("")});
    }
    // Consistent from the start: poses and forces as after a step of length 0.
    for (std::size_t i = 0; i < robots_.size(); ++i) update(i);
}

bool World::setJoints(std::size_t robot, const Joints& q, const Joints& qd) {
    RobotState& s = robots_.at(robot);
    if (!finite(q) || !finite(qd)) return false;
    const auto& limits = cell_.robots[robot].model.limits;
    for (int j = 0; j < kinematics::kAxes; ++j) {
        const auto& l = limits[static_cast<std::size_t>(j)];
        const auto k = static_cast<std::size_t>(j);
        s.q[k] = std::clamp(q[k], l.minPosition, l.maxPosition);
        s.qd[k] = s.q[k] == q[k] ? qd[k] : 0.0;
    }
    update(robot);
    return true;
}

void World::step(double dt) {
    // dt = 0 only refreshes the state (poses, forces); a bad dt must not poison the clock
    // (time stays finite and monotonic) and does not count as a step either.
    if (std::isfinite(dt) && dt > 0.0) {
        time_ += dt;
        ++steps_;
    }
    for (std::size_t i = 0; i < robots_.size(); ++i) update(i);
}

Eigen::Vector3d World::contactForceAt(const Eigen::Vector3d& point) const {
    double deepest = 0.0;
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
    auto consider = [&](const Eigen::Isometry3d& top, const Eigen::Vector3d& size) {
        const double d = depthBelowTop(top, size, point);
        if (d > deepest) {
            deepest = d;
            normal = top.linear().col(2);
        }
    };
    for (const TableDescription& t : cell_.tables) consider(t.pose, t.size);
    for (std::size_t i = 0; i < objects_.size(); ++i) {
        const ObjectState& o = objects_[i];
        // Held objects move with their gripper; contact with them is not modelled yet.
        if (!o.holder.empty() && cell_.findTool(o.holder) != nullptr) continue;
        const Eigen::Vector3d size = cell_.objects[i].size;
        Eigen::Isometry3d top = o.pose;
        top.translate(Eigen::Vector3d(0.0, 0.0, 0.5 * size.z()));
        consider(top, size);
    }
    if (deepest <= 0.0) return Eigen::Vector3d::Zero();
    return normal * std::min(config_.contactStiffness * deepest, config_.maxContactForce);
}

void World::update(std::size_t robot) {
    RobotState& s = robots_[robot];
    const RobotDescription& d = cell_.robots[robot];
    s.flange = d.base * kinematics::forward(d.model, s.q);
    s.tcp = s.flange;
    if (s.tool) {
        if (const ToolDescription* tool = cell_.findTool(*s.tool)) s.tcp = s.flange * tool->tcp;
    }
    s.tcpForce = contactForceAt(s.tcp.translation());
}

Snapshot World::snapshot() const { return Snapshot{time_, steps_, robots_, objects_, tools_}; }

}  // namespace pnp::world

// ---- (being implemented: tool changer, grip, operator actions) ----
namespace pnp::world {
bool World::toolPowered(std::size_t tool) const { return tools_.at(tool).powered; }
std::optional<Eigen::Isometry3d> World::gripPoint(std::size_t) const { return std::nullopt; }
std::optional<FingerContact> World::objectBetweenFingers(std::size_t, double) const {
    return std::nullopt;
}
std::optional<std::size_t> World::objectUnderCup(std::size_t) const { return std::nullopt; }
bool World::hold(std::size_t, std::size_t) { return false; }
void World::release(std::size_t) {}
std::optional<std::size_t> World::held(std::size_t) const { return std::nullopt; }
std::string World::putToolInDock(const std::string&, const std::string&) { return "todo"; }
std::string World::takeToolOut(const std::string&) { return "todo"; }
std::string World::placeObject(const std::string&, const Eigen::Isometry3d&) { return "todo"; }
std::string World::removeObject(const std::string&) { return "todo"; }
double World::changerVoltage(ChangerLock, int) { return 0.0; }
void World::updateChanger(std::size_t) {}
void World::updateHeld() {}
void World::settle(std::size_t) {}
}  // namespace pnp::world
