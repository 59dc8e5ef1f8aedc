// The simulated cell's physical world: the one ground truth (robot joints, the flange, the
// tool on it, object poses and holders, contact forces). Deterministic: the same calls give
// the same state, bit for bit. Not thread-safe: the simulator's stepping thread owns it and
// hands copies (snapshot()) to readers. Device simulators drive it (a robot controller sets
// its joints); adapters and components never see it.
#pragma once

#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "kinematics/robot_model.hpp"
#include "world/cell_description.hpp"

namespace pnp::world {

using kinematics::Joints;

struct RobotState {
    std::string name;
    Joints q{};                                                // rad
    Joints qd{};                                               // rad/s
    Eigen::Isometry3d flange = Eigen::Isometry3d::Identity();  // world frame
    Eigen::Isometry3d tcp = Eigen::Isometry3d::Identity();     // flange * tool TCP (world)
    std::optional<std::string> tool;                           // locked on the flange
    Eigen::Vector3d tcpForce = Eigen::Vector3d::Zero();        // on the TCP, world frame, N
};

struct ObjectState {
    std::string name;
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // centre, world frame
    std::string holder;  // what it rests on or is held by: a table, an object, a tool
};

struct ToolState {
    std::string name;
    std::optional<std::string> dock;   // parked there, or
    std::optional<std::string> robot;  // locked on that robot's flange
};

// Everything a reader may see, copied at one step.
struct Snapshot {
    double time = 0.0;  // s since start
    std::uint64_t step = 0;
    std::vector<RobotState> robots;
    std::vector<ObjectState> objects;
    std::vector<ToolState> tools;
};

struct WorldConfig {
    // Contact: a spring on the TCP point against the top faces of tables and objects.
    double contactStiffness = 20000.0;  // N/m (1 mm deep = 20 N)
    double maxContactForce = 2000.0;    // N (saturation; a real robot stops far earlier)
};

class World {
  public:
    explicit World(CellDescription cell, WorldConfig config = {});

    const CellDescription& description() const { return cell_; }

    // Robots by index in description().robots.
    std::size_t robotCount() const { return robots_.size(); }
    const RobotState& robot(std::size_t index) const { return robots_.at(index); }
    // Set by the robot's controller simulator once per step (within its joint limits).
    // Updates the robot's flange and TCP poses and its contact force at once.
    // A non-finite value rejects the whole call (returns false, nothing changes); positions
    // beyond the joint limits are clamped to them, with that joint's velocity set to 0.
    // Throws std::out_of_range for an unknown robot index, like robot().
    bool setJoints(std::size_t robot, const Joints& q, const Joints& qd);

    const std::vector<ObjectState>& objects() const { return objects_; }
    const std::vector<ToolState>& tools() const { return tools_; }

    // Advances time by dt: updates flange / TCP poses, contact forces, held objects.
    // dt = 0 (or a non-finite / negative dt) only refreshes them: no time, no step counted.
    void step(double dt);
    double time() const { return time_; }
    std::uint64_t steps() const { return steps_; }

    Snapshot snapshot() const;

    // The contact force (world frame, N) on a point: the spring of the deepest top face
    // (tables, objects resting somewhere, not held ones) whose footprint holds the point and
    // below which it lies, within the body's height; zero otherwise. step() applies it to
    // each robot's TCP point.
    Eigen::Vector3d contactForceAt(const Eigen::Vector3d& point) const;

  private:
    void update(std::size_t robot);

    CellDescription cell_;
    WorldConfig config_;
    std::vector<RobotState> robots_;
    std::vector<ObjectState> objects_;
    std::vector<ToolState> tools_;
    double time_ = 0.0;
    std::uint64_t steps_ = 0;
};

}  // namespace pnp::world
