#include "world/cell_description.hpp"

#include <algorithm>
#include <cmath>

namespace pnp::world {
namespace {

template <class T>
const T* findByName(const std::vector<T>& things, std::string_view name) {
    auto it = std::find_if(things.begin(), things.end(),
                           [name](const T& thing) { return thing.name == name; });
    return it == things.end() ? nullptr : &*it;
}

}  // namespace

std::string_view toString(ToolKind kind) {
    switch (kind) {
        case ToolKind::kParallelGripper:
            return "parallel-gripper";
        case ToolKind::kVacuumGripper:
            return "vacuum-gripper";
    }
    return "?";
}

const RobotDescription* CellDescription::findRobot(std::string_view n) const {
    return findByName(robots, n);
}
const TableDescription* CellDescription::findTable(std::string_view n) const {
    return findByName(tables, n);
}
const ToolDescription* CellDescription::findTool(std::string_view n) const {
    return findByName(tools, n);
}
const DockDescription* CellDescription::findDock(std::string_view n) const {
    return findByName(docks, n);
}
const ObjectDescription* CellDescription::findObject(std::string_view n) const {
    return findByName(objects, n);
}

Eigen::Isometry3d poseFromXyzRpy(const Eigen::Vector3d& xyz, const Eigen::Vector3d& rpy) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.linear() = (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                     Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                     Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()))
                        .toRotationMatrix();
    pose.translation() = xyz;
    return pose;
}

Eigen::Vector3d rpyFromRotation(const Eigen::Matrix3d& r) {
    // R = Rz(y) Ry(p) Rx(r): r20 = -sin p, (r21, r22) = cos p (sin r, cos r),
    // (r10, r00) = cos p (sin y, cos y). atan2 for the pitch too: asin loses half the digits
    // near ±π/2.
    const double cosPitch = std::hypot(r(2, 1), r(2, 2));
    const double pitch = std::atan2(-r(2, 0), cosPitch);
    if (cosPitch < 1e-12) {
        // Gimbal lock: only roll ∓ yaw is defined; put it all into yaw.
        return {0.0, pitch, std::atan2(-r(0, 1), r(1, 1))};
    }
    return {std::atan2(r(2, 1), r(2, 2)), pitch, std::atan2(r(1, 0), r(0, 0))};
}

}  // namespace pnp::world
