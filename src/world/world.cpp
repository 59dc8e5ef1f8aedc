#include "world/world.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
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
// body (a point under a table is not pushed up through it). A point within `touch` of a side
// face touches it (a finger tip closed onto the side of a part, up to rounding): no depth.
double depthBelowTop(const Eigen::Isometry3d& top, const Eigen::Vector3d& size,
                     const Eigen::Vector3d& point, double touch) {
    const Eigen::Vector3d local = top.inverse() * point;
    if (std::abs(local.x()) >= 0.5 * size.x() - touch ||
        std::abs(local.y()) >= 0.5 * size.y() - touch)
        return 0.0;
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
    heldOffsets_.assign(tools_.size(), Eigen::Isometry3d::Identity());
    for (const ToolDescription& t : cell_.tools) fingerOpenings_.push_back(t.stroke);
    // A tool on a flange at start is locked there.
    for (RobotState& r : robots_)
        if (r.tool) r.changer = ChangerLock::kLocked;
    // Consistent from the start: poses and forces as after a step of length 0.
    step(0.0);
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
    // The changers turn with the flanges, tools come and go, held objects follow their grip
    // points; then the TCPs and contact forces with the tools as they are now.
    for (std::size_t i = 0; i < robots_.size(); ++i) {
        update(i);
        updateChanger(i);
    }
    updateHeld();
    for (std::size_t i = 0; i < robots_.size(); ++i) update(i);
}

Eigen::Vector3d World::contactForceAt(const Eigen::Vector3d& point) const {
    double deepest = 0.0;
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
    auto consider = [&](const Eigen::Isometry3d& top, const Eigen::Vector3d& size) {
        const double d = depthBelowTop(top, size, point, config_.touchTolerance);
        if (d > deepest) {
            deepest = d;
            normal = top.linear().col(2);
        }
    };
    for (const TableDescription& t : cell_.tables) consider(t.pose, t.size);
    for (std::size_t i = 0; i < objects_.size(); ++i) {
        const ObjectState& o = objects_[i];
        // Held objects move with their gripper; contact with them is not modelled yet.
        if (!resting(i)) continue;
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
    s.tcpForce = Eigen::Vector3d::Zero();
    const ToolDescription* tool = s.tool ? cell_.findTool(*s.tool) : nullptr;
    if (tool != nullptr && tool->kind == ToolKind::kParallelGripper) {
        // The finger tips touch things; the point between them is where objects are held.
        const std::size_t i = static_cast<std::size_t>(tool - cell_.tools.data());
        const double half = 0.5 * fingerOpenings_[i];
        s.tcpForce = contactForceAt(s.tcp * Eigen::Vector3d(half, 0.0, 0.0)) +
                     contactForceAt(s.tcp * Eigen::Vector3d(-half, 0.0, 0.0));
    } else {
        s.tcpForce = contactForceAt(s.tcp.translation());
    }
}

Snapshot World::snapshot() const { return Snapshot{time_, steps_, robots_, objects_, tools_}; }

}  // namespace pnp::world

namespace pnp::world {

namespace {

// The rotation angle about z from frame a to frame b (their z axes about parallel).
double angleAboutZ(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
    const Eigen::Matrix3d r = a.transpose() * b;
    return std::atan2(r(1, 0), r(0, 0));
}

double axisAngle(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0));
}

// Half the extent of a box (rotation `r`, edge lengths `size`) along a unit direction.
double halfExtent(const Eigen::Matrix3d& r, const Eigen::Vector3d& size,
                  const Eigen::Vector3d& direction) {
    double h = 0.0;
    for (int k = 0; k < 3; ++k) h += 0.5 * size[k] * std::abs(direction.dot(r.col(k)));
    return h;
}

// Kelvin's tool numbers 1..10 (cell.md §2), V on the 24 V scale.
constexpr double kToolVoltage[10] = {5.7, 6.7, 7.4, 8.4, 9.5, 10.8, 11.7, 12.4, 13.2, 14.1};
constexpr double kIntermediateVoltage = 2.1;
constexpr double kNoToolVoltage = 4.9;

}  // namespace

double World::changerVoltage(ChangerLock lock, int toolChangerId) {
    switch (lock) {
        case ChangerLock::kOpen:
            return 0.0;
        case ChangerLock::kIntermediate:
            return kIntermediateVoltage;
        case ChangerLock::kLocked:
            if (toolChangerId >= 1 && toolChangerId <= 10) return kToolVoltage[toolChangerId - 1];
            return kNoToolVoltage;
    }
    return 0.0;
}

std::optional<std::size_t> World::toolIndex(const std::string& name) const {
    for (std::size_t i = 0; i < cell_.tools.size(); ++i)
        if (cell_.tools[i].name == name) return i;
    return std::nullopt;
}

std::optional<std::size_t> World::objectIndex(const std::string& name) const {
    for (std::size_t i = 0; i < cell_.objects.size(); ++i)
        if (cell_.objects[i].name == name) return i;
    return std::nullopt;
}

bool World::resting(std::size_t object) const {
    const std::string& h = objects_[object].holder;
    return h != kRemoved && cell_.findTool(h) == nullptr;
}

std::optional<Eigen::Isometry3d> World::toolFrame(std::size_t tool) const {
    const ToolState& t = tools_.at(tool);
    if (t.robot) {
        for (const RobotState& r : robots_)
            if (r.name == *t.robot) return r.flange;
    }
    if (t.dock) {
        if (const DockDescription* d = cell_.findDock(*t.dock)) return d->pose;
    }
    return std::nullopt;
}

bool World::toolPowered(std::size_t tool) const { return tools_.at(tool).powered; }

std::optional<Eigen::Isometry3d> World::gripPoint(std::size_t tool) const {
    auto frame = toolFrame(tool);
    if (!frame) return std::nullopt;
    return *frame * cell_.tools.at(tool).tcp;
}

std::optional<FingerContact> World::objectBetweenFingers(std::size_t tool, double opening) const {
    const ToolDescription& d = cell_.tools.at(tool);
    if (d.kind != ToolKind::kParallelGripper) return std::nullopt;
    const auto grip = gripPoint(tool);
    if (!grip || !std::isfinite(opening) || opening <= 0.0) return std::nullopt;
    const Eigen::Vector3d across = grip->linear().col(0);  // the fingers' axis
    const Eigen::Vector3d side = grip->linear().col(1);
    const Eigen::Vector3d out = grip->linear().col(2);  // out of the tool, tips at the grip
    std::optional<FingerContact> best;
    for (std::size_t i = 0; i < objects_.size(); ++i) {
        if (!resting(i) && objects_[i].holder != d.name) continue;
        const Eigen::Isometry3d& pose = objects_[i].pose;
        const Eigen::Vector3d size = cell_.objects[i].size;
        const Eigen::Vector3d c = grip->inverse() * pose.translation();
        const double w = 2.0 * halfExtent(pose.linear(), size, across);
        const double hy = halfExtent(pose.linear(), size, side);
        const double hz = halfExtent(pose.linear(), size, out);
        // Between the open fingers, across them and along them...
        if (std::abs(c.x()) + 0.5 * w > 0.5 * opening + config_.fingerClearance) continue;
        if (std::abs(c.y()) > hy) continue;
        // ... and the pads (from the tips back by fingerPad) overlapping it enough.
        const double overlap = std::min(0.0, c.z() + hz) - std::max(-config_.fingerPad, c.z() - hz);
        if (overlap < config_.minFingerOverlap) continue;
        if (!best || w > best->width) best = FingerContact{i, w};
    }
    return best;
}

std::optional<std::size_t> World::objectUnderCup(std::size_t tool) const {
    const ToolDescription& d = cell_.tools.at(tool);
    if (d.kind != ToolKind::kVacuumGripper) return std::nullopt;
    const auto grip = gripPoint(tool);
    if (!grip) return std::nullopt;
    const Eigen::Vector3d axis = grip->linear().col(2);  // the cup faces along +z
    const double rim = 0.5 * d.cupDiameter;
    for (std::size_t i = 0; i < objects_.size(); ++i) {
        if (!resting(i) && objects_[i].holder != d.name) continue;
        const Eigen::Isometry3d& pose = objects_[i].pose;
        const Eigen::Vector3d size = cell_.objects[i].size;
        // The box face that looks at the cup: outward normal most against its axis.
        int k = 0;
        double sign = 1.0, bestDot = 2.0;
        for (int a = 0; a < 3; ++a) {
            for (double sg : {1.0, -1.0}) {
                const double dot = (sg * pose.linear().col(a)).dot(axis);
                if (dot < bestDot) {
                    bestDot = dot;
                    k = a;
                    sign = sg;
                }
            }
        }
        const Eigen::Vector3d normal = sign * pose.linear().col(k);
        if (axisAngle(-axis, normal) > config_.cupTiltTolerance) continue;
        const Eigen::Vector3d face = pose.translation() + normal * (0.5 * size[k]);
        const Eigen::Vector3d p = grip->translation() - face;
        const double height = p.dot(normal);
        if (std::abs(height) > config_.cupSealDistance) continue;
        // The whole rim on the face: flat under every point of the cup.
        const int u = (k + 1) % 3, v = (k + 2) % 3;
        if (std::abs(p.dot(pose.linear().col(u))) + rim > 0.5 * size[u]) continue;
        if (std::abs(p.dot(pose.linear().col(v))) + rim > 0.5 * size[v]) continue;
        return i;
    }
    return std::nullopt;
}

bool World::hold(std::size_t tool, std::size_t object) {
    ToolState& t = tools_.at(tool);
    ObjectState& o = objects_.at(object);
    if (t.held) return *t.held == o.name;
    if (!resting(object)) return false;
    const auto grip = gripPoint(tool);
    if (!grip) return false;
    heldOffsets_.at(tool) = grip->inverse() * o.pose;
    if (cell_.tools.at(tool).kind == ToolKind::kParallelGripper) {
        // The jaws close on both sides: the part ends up centred between them.
        heldOffsets_[tool].translation().x() = 0.0;
        o.pose = *grip * heldOffsets_[tool];
    }
    o.holder = t.name;
    t.held = o.name;
    return true;
}

void World::release(std::size_t tool) {
    ToolState& t = tools_.at(tool);
    if (!t.held) return;
    const auto object = objectIndex(*t.held);
    t.held.reset();
    if (!object) return;
    objects_[*object].holder.clear();
    settle(*object);
}

void World::setFingerOpening(std::size_t tool, double opening) {
    if (!std::isfinite(opening)) return;
    const double before = fingerOpenings_.at(tool);
    fingerOpenings_[tool] = std::clamp(opening, 0.0, cell_.tools.at(tool).stroke);
    if (fingerOpenings_[tool] < before) pushBetweenFingers(tool, before, fingerOpenings_[tool]);
}

void World::pushBetweenFingers(std::size_t tool, double before, double after) {
    const ToolDescription& d = cell_.tools.at(tool);
    if (d.kind != ToolKind::kParallelGripper) return;
    const auto grip = gripPoint(tool);
    if (!grip) return;
    const Eigen::Vector3d across = grip->linear().col(0);  // the fingers' axis
    const Eigen::Vector3d side = grip->linear().col(1);
    const Eigen::Vector3d out = grip->linear().col(2);
    const double from = 0.5 * before, to = 0.5 * after;  // each tip's travel, from the centre
    for (std::size_t i = 0; i < objects_.size(); ++i) {
        if (!resting(i)) continue;
        ObjectState& o = objects_[i];
        const Eigen::Vector3d size = cell_.objects[i].size;
        const Eigen::Vector3d c = grip->inverse() * o.pose.translation();
        const double hx = halfExtent(o.pose.linear(), size, across);
        const double hy = halfExtent(o.pose.linear(), size, side);
        const double hz = halfExtent(o.pose.linear(), size, out);
        // In the fingers' path: across their line, and within the pads' depth.
        if (std::abs(c.y()) >= hy) continue;
        if (std::min(0.0, c.z() + hz) - std::max(-config_.fingerPad, c.z() - hz) <= 0.0) continue;
        // A tip that was outside a side face and has swept past it pushes the face along; a tip
        // already inside the object (the tool came down onto it) pushes nothing: that is the
        // top-face contact.
        const double low = c.x() - hx, high = c.x() + hx;
        const bool plus = high > to && high <= from + config_.touchTolerance;
        const bool minus = low < -to && low >= -from - config_.touchTolerance;
        double shift = 0.0;
        if (plus && minus) {
            shift = -c.x();  // squeezed from both sides: wider than the opening, centred
        } else if (plus) {
            shift = to - high;
        } else if (minus) {
            shift = -to - low;
        }
        if (shift == 0.0) continue;
        // It slides on what it rests on: sideways only, at its height.
        const double z = o.pose.translation().z();
        o.pose.translation() += shift * across;
        o.pose.translation().z() = z;
    }
}

std::optional<std::size_t> World::held(std::size_t tool) const {
    const ToolState& t = tools_.at(tool);
    if (!t.held) return std::nullopt;
    return objectIndex(*t.held);
}

void World::settle(std::size_t object) {
    ObjectState& o = objects_[object];
    const Eigen::Vector3d size = cell_.objects[object].size;
    // Upright, keeping its heading: the box's x axis projected on the floor.
    const Eigen::Vector3d x = o.pose.linear().col(0);
    const double yaw = std::hypot(x.x(), x.y()) > 1e-9 ? std::atan2(x.y(), x.x()) : 0.0;
    const Eigen::Vector3d centre = o.pose.translation();
    const double bottom = centre.z() - halfExtent(o.pose.linear(), size, Eigen::Vector3d::UnitZ());
    // The highest top face below its bottom whose footprint holds its centre.
    double top = -std::numeric_limits<double>::infinity();
    std::string holder(kFloor);
    auto consider = [&](const Eigen::Isometry3d& face, const Eigen::Vector3d& extent,
                        const std::string& name) {
        const Eigen::Vector3d local = face.inverse() * centre;
        if (std::abs(local.x()) > 0.5 * extent.x() || std::abs(local.y()) > 0.5 * extent.y())
            return;
        const double z = face.translation().z();
        if (z > bottom + config_.restTolerance || z <= top) return;
        top = z;
        holder = name;
    };
    for (const TableDescription& t : cell_.tables) consider(t.pose, t.size, t.name);
    for (std::size_t i = 0; i < objects_.size(); ++i) {
        if (i == object || !resting(i)) continue;
        const Eigen::Vector3d s = cell_.objects[i].size;
        Eigen::Isometry3d face = objects_[i].pose;
        face.translate(Eigen::Vector3d(0.0, 0.0, 0.5 * s.z()));
        consider(face, s, objects_[i].name);
    }
    if (!std::isfinite(top)) {
        // Beside every table: down to the floor the tables stand on.
        top = 0.0;
        for (std::size_t i = 0; i < cell_.tables.size(); ++i) {
            const double floor = cell_.tables[i].pose.translation().z() - cell_.tables[i].size.z();
            top = i == 0 ? floor : std::min(top, floor);
        }
    }
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    pose.translation() = Eigen::Vector3d(centre.x(), centre.y(), top + 0.5 * size.z());
    o.pose = pose;
    o.holder = holder;
}

void World::updateChanger(std::size_t robot) {
    RobotState& s = robots_[robot];
    s.dock.reset();
    const DockDescription* dock = nullptr;
    double phi = 0.0;
    for (const DockDescription& d : cell_.docks) {
        if ((s.flange.translation() - d.pose.translation()).norm() > config_.dockPositionTolerance)
            continue;
        if (axisAngle(s.flange.linear().col(2), d.pose.linear().col(2)) > config_.dockTiltTolerance)
            continue;
        dock = &d;
        phi = angleAboutZ(d.pose.linear(), s.flange.linear());
        break;
    }
    if (dock != nullptr) {
        s.dock = dock->name;
        // Which band of the dock's cam the ring is in; it follows only by turning through
        // them: a changer that enters at another angle does not engage the cam.
        const double lock = config_.lockAngle;
        const bool open = std::abs(phi + lock) <= config_.lockBand;
        const bool locked = std::abs(phi) <= config_.lockBand;
        const bool between = phi > -lock && phi < 0.0 && !open && !locked;
        std::optional<std::size_t> parked;  // the tool in this dock
        for (std::size_t i = 0; i < tools_.size(); ++i)
            if (tools_[i].dock == dock->name) parked = i;
        // A tool on the flange and another in the dock cannot both be there: jammed.
        const bool jammed = s.tool && parked;
        if (!jammed) {
            switch (s.changer) {
                case ChangerLock::kOpen:
                    if (between) s.changer = ChangerLock::kIntermediate;
                    break;
                case ChangerLock::kIntermediate:
                    if (locked) {
                        s.changer = ChangerLock::kLocked;
                        if (parked) {
                            tools_[*parked].dock.reset();
                            tools_[*parked].robot = s.name;
                            s.tool = tools_[*parked].name;
                        }
                    } else if (open) {
                        s.changer = ChangerLock::kOpen;
                        if (s.tool) {
                            if (auto t = toolIndex(*s.tool)) {
                                tools_[*t].robot.reset();
                                tools_[*t].dock = dock->name;
                            }
                            s.tool.reset();
                        }
                    }
                    break;
                case ChangerLock::kLocked:
                    if (between) s.changer = ChangerLock::kIntermediate;
                    break;
            }
        }
    }
    int id = 0;
    if (s.tool) {
        if (const ToolDescription* t = cell_.findTool(*s.tool)) id = t->changerId;
    }
    s.changerVoltage = changerVoltage(s.changer, id);
}

void World::updateHeld() {
    for (std::size_t i = 0; i < tools_.size(); ++i) {
        ToolState& t = tools_[i];
        t.powered = false;
        if (t.robot) {
            for (const RobotState& r : robots_)
                if (r.name == *t.robot) t.powered = r.changer == ChangerLock::kLocked;
        }
        if (!t.held) continue;
        const auto grip = gripPoint(i);
        const auto o = objectIndex(*t.held);
        if (grip && o) objects_[*o].pose = *grip * heldOffsets_[i];
    }
}

std::string World::putToolInDock(const std::string& tool, const std::string& dock) {
    const auto t = toolIndex(tool);
    if (!t) return "no tool '" + tool + "' in the cell";
    if (cell_.findDock(dock) == nullptr) return "no dock '" + dock + "' in the cell";
    ToolState& s = tools_[*t];
    if (s.robot) return "tool '" + tool + "' is on the flange of robot '" + *s.robot + "'";
    if (s.dock == dock) return "";
    for (const ToolState& other : tools_)
        if (other.dock == dock) return "dock '" + dock + "' holds tool '" + other.name + "'";
    for (const RobotState& r : robots_)
        if (r.dock == dock) return "robot '" + r.name + "' is in dock '" + dock + "'";
    s.dock = dock;
    updateHeld();
    return "";
}

std::string World::takeToolOut(const std::string& tool) {
    const auto t = toolIndex(tool);
    if (!t) return "no tool '" + tool + "' in the cell";
    ToolState& s = tools_[*t];
    if (s.robot) return "tool '" + tool + "' is on the flange of robot '" + *s.robot + "'";
    release(*t);
    s.dock.reset();
    return "";
}

std::string World::attachToolByHand(const std::string& robot, const std::string& tool) {
    const auto t = toolIndex(tool);
    if (!t) return "no tool '" + tool + "' in the cell";
    for (RobotState& r : robots_) {
        if (r.name != robot) continue;
        if (r.tool) return "robot '" + robot + "' has tool '" + *r.tool + "' on its flange";
        if (r.changer != ChangerLock::kOpen)
            return "the changer of robot '" + robot + "' is not open";
        if (tools_[*t].robot)
            return "tool '" + tool + "' is on the flange of robot '" + *tools_[*t].robot + "'";
        tools_[*t].dock.reset();
        tools_[*t].robot = robot;
        r.tool = tool;
        r.changer = ChangerLock::kLocked;
        step(0.0);
        return "";
    }
    return "no robot '" + robot + "' in the cell";
}

std::string World::detachToolByHand(const std::string& robot) {
    for (RobotState& r : robots_) {
        if (r.name != robot) continue;
        if (!r.tool) return "robot '" + robot + "' has no tool on its flange";
        if (const auto t = toolIndex(*r.tool)) {
            release(*t);
            tools_[*t].robot.reset();
        }
        r.tool.reset();
        r.changer = ChangerLock::kOpen;
        step(0.0);
        return "";
    }
    return "no robot '" + robot + "' in the cell";
}

std::string World::placeObject(const std::string& object, const Eigen::Isometry3d& pose) {
    const auto o = objectIndex(object);
    if (!o) return "no object '" + object + "' in the cell";
    if (!pose.matrix().allFinite()) return "the pose is not finite";
    ObjectState& s = objects_[*o];
    if (cell_.findTool(s.holder) != nullptr)
        return "object '" + object + "' is held by tool '" + s.holder + "'";
    s.pose = pose;
    s.holder.clear();
    settle(*o);
    return "";
}

std::string World::removeObject(const std::string& object) {
    const auto o = objectIndex(object);
    if (!o) return "no object '" + object + "' in the cell";
    ObjectState& s = objects_[*o];
    if (const auto t = toolIndex(s.holder)) release(*t);
    s.holder = std::string(kRemoved);
    return "";
}

}  // namespace pnp::world
