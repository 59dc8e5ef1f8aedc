#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "kinematics/robot_model.hpp"

namespace pnp::world {

// The static description of a cell, as read from a cell file (docs/cell-file.md): what is
// there at start. Units: m, rad, kg, s. Poses are in the world frame unless a field says
// otherwise. `line` is where the thing is defined in its file (1-based; 0 if built in code),
// so later checks (e.g. by the physics) can point at the file too.

struct ControllerEndpoint {
    std::string protocol = "rtde";  // the only one so far
    std::uint16_t port = 30004;     // 0 = ephemeral (tests run many cells in parallel)
};

struct RobotDescription {
    std::string name;
    std::string modelName;  // as in the file: ur3, ur5, ur10
    kinematics::RobotModel model;
    Eigen::Isometry3d base = Eigen::Isometry3d::Identity();  // world -> robot base
    kinematics::Joints home{};                               // rad, within model.limits
    ControllerEndpoint controller;
    std::optional<std::string> tool;  // on the flange at start
    int line = 0;
};

struct TableDescription {
    std::string name;
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // centre of the top face
    Eigen::Vector3d size = Eigen::Vector3d::Zero();          // the box hangs size.z() below
    int line = 0;
};

enum class ToolKind { kParallelGripper, kVacuumGripper };

std::string_view toString(ToolKind kind);

struct ToolDescription {
    std::string name;
    ToolKind kind = ToolKind::kParallelGripper;
    std::string device;  // which device simulator serves it, e.g. robotiq-2f85
    int changerId = 0;   // the Kelvin tool changer's tool number, 1..10
    double mass = 0.0;
    Eigen::Isometry3d tcp = Eigen::Isometry3d::Identity();  // flange -> TCP
    double stroke = 0.0;                                    // parallel gripper only
    double cupDiameter = 0.0;                               // vacuum gripper only
    int line = 0;
};

struct DockDescription {
    std::string name;
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // a parked tool's flange side
    std::optional<std::string> tool;                         // parked there at start
    int line = 0;
};

enum class Shape { kBox };

struct ObjectDescription {
    std::string name;
    Shape shape = Shape::kBox;
    Eigen::Vector3d size = Eigen::Vector3d::Zero();
    double mass = 0.0;
    std::string color;                                       // a name or #rrggbb
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // its centre
    std::optional<std::string> on;                           // a table or object
    int line = 0;
};

struct CellDescription {
    int version = 1;
    std::string name;
    std::vector<RobotDescription> robots;
    std::vector<TableDescription> tables;
    std::vector<ToolDescription> tools;
    std::vector<DockDescription> docks;
    std::vector<ObjectDescription> objects;

    // nullptr when there is none of that name.
    const RobotDescription* findRobot(std::string_view name) const;
    const TableDescription* findTable(std::string_view name) const;
    const ToolDescription* findTool(std::string_view name) const;
    const DockDescription* findDock(std::string_view name) const;
    const ObjectDescription* findObject(std::string_view name) const;
};

// URDF's convention: roll, pitch, yaw about the fixed axes X, Y, Z, i.e. R = Rz(y) Ry(p) Rx(r).
Eigen::Isometry3d poseFromXyzRpy(const Eigen::Vector3d& xyz, const Eigen::Vector3d& rpy);
// The inverse (pitch in [-π/2, π/2]; at pitch ±π/2 roll is 0 and yaw takes the rest).
Eigen::Vector3d rpyFromRotation(const Eigen::Matrix3d& rotation);

}  // namespace pnp::world
