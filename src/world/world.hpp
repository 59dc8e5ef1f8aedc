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
#include <string_view>
#include <vector>

#include "kinematics/robot_model.hpp"
#include "world/cell_description.hpp"

namespace pnp::world {

using kinematics::Joints;

// The Kelvin tool changer on a robot's flange (cell.md §2): passive, locked by the robot's
// motion in a dock — in the dock's frame, a turn of the flange about its z axis by
// WorldConfig::lockAngle locks, the turn back opens. Its state voltage (24 V scale) says
// what it is: open ("ready") 0 V, turning 2.1 V, locked without a tool 4.9 V, locked with
// tool 1…10 5.7 … 14.1 V.
enum class ChangerLock { kOpen, kIntermediate, kLocked };

struct RobotState {
    std::string name;
    Joints q{};                                                // rad
    Joints qd{};                                               // rad/s
    Eigen::Isometry3d flange = Eigen::Isometry3d::Identity();  // world frame
    Eigen::Isometry3d tcp = Eigen::Isometry3d::Identity();     // flange * tool TCP (world)
    std::optional<std::string> tool;                           // locked on the flange
    Eigen::Vector3d tcpForce = Eigen::Vector3d::Zero();        // on the TCP, world frame, N
    ChangerLock changer = ChangerLock::kOpen;
    std::optional<std::string> dock;  // the dock the changer sits in (within tolerance)
    double changerVoltage = 0.0;      // V, the state voltage of the changer
};

struct ObjectState {
    std::string name;
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // centre, world frame
    std::string holder;  // what it rests on or is held by: a table, an object, a tool
};

struct ToolState {
    std::string name;
    std::optional<std::string> dock;   // parked there, or
    std::optional<std::string> robot;  // locked on that robot's flange; neither: on the shelf
    bool powered = false;              // only while locked on a flange (its power pins)
    std::optional<std::string> held;   // the object it holds
};

// An object's holder when it was taken out of the cell (removeObject).
inline constexpr std::string_view kRemoved = "removed";
// ... and when it fell beside every table.
inline constexpr std::string_view kFloor = "floor";

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
    // The tool changer: the turn that locks (about the flange's z axis, in the dock's frame),
    // and how close the changer must be to a dock's frame for the dock to turn its ring.
    double lockAngle = 0.5235987755982988;  // rad (30°)
    double dockPositionTolerance = 0.003;   // m
    double dockTiltTolerance = 0.05;        // rad between the flange's and the dock's z axes
    double lockBand = 0.035;                // rad: within this of 0 = open, of lockAngle = locked
    // Grip: how far the grip point may be from where it should be on an object.
    // A parallel gripper's grip point is at its finger tips; its pads reach `fingerPad` back
    // from there, and must overlap an object by `minFingerOverlap` to hold it.
    double fingerPad = 0.035;         // m
    double minFingerOverlap = 0.005;  // m
    double fingerClearance = 0.001;   // m an object may stick out beyond the open fingers
    double cupSealDistance = 0.004;   // m: cup within this above or (pressed) below a face
    double cupTiltTolerance = 0.087;  // rad (5°) between the cup's axis and the face normal
    double restTolerance = 0.002;     // m: a support up to this above an object's bottom
    // A point this close to a side face of a body touches the face, it is not inside (a finger
    // tip closed onto a part's side, up to rounding): no contact force.
    double touchTolerance = 1e-6;  // m
};

// The object between a parallel gripper's fingers and its width across them.
struct FingerContact {
    std::size_t object = 0;  // index in objects()
    double width = 0.0;      // m, the object's extent along the fingers' axis
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

    // --- What a tool's device simulator may ask the world and tell it (tool: an index in
    // description().tools). Never for adapters or components.
    // Power reaches a tool only while it is locked on a flange.
    bool toolPowered(std::size_t tool) const;
    // The tool's grip point (world frame): on a flange, in a dock, or none on the shelf.
    std::optional<Eigen::Isometry3d> gripPoint(std::size_t tool) const;
    // Parallel gripper open to `opening` (m): the object between its fingers (the grip
    // frame's x axis is the fingers' axis, z points out of the tool): its centre within the
    // fingers' depth around the grip point, its width across them below the opening.
    std::optional<FingerContact> objectBetweenFingers(std::size_t tool, double opening) const;
    // Vacuum gripper: the object whose flat top face seals the cup at the grip point (the
    // cup's axis along the face normal, its whole rim on the face, touching it).
    std::optional<std::size_t> objectUnderCup(std::size_t tool) const;
    // The tool takes hold of the object (it follows the grip point from now on; a parallel
    // gripper's jaws hold it centred between them); false when the tool already holds another
    // one, or the object is held by another tool.
    bool hold(std::size_t tool, std::size_t object);
    // It lets go: the object comes to rest on what is below it (the highest top face of a
    // table or a resting object under its centre) or falls to the floor.
    void release(std::size_t tool);
    std::optional<std::size_t> held(std::size_t tool) const;
    // A parallel gripper's opening (m), told by its device simulator as the fingers move:
    // the contact force of a robot with that tool acts on its two finger tips, not on the
    // point between them (where an object sits while the fingers close around it).
    // Closing, a finger tip that meets the side face of a resting object pushes it along the
    // fingers' axis (it slides on its support), so the fingers close on it centred; a tip
    // already inside an object (the tool came down onto it) pushes nothing.
    // Default: the stroke (fully open).
    void setFingerOpening(std::size_t tool, double opening);

    // --- Operator actions (a person in the cell). Each returns an error message, or "".
    // Put a tool (from the shelf or another dock) into an empty dock.
    std::string putToolInDock(const std::string& tool, const std::string& dock);
    // Take a tool out of its dock onto the shelf (not one on a flange).
    std::string takeToolOut(const std::string& tool);
    // Lock a tool (from a dock or the shelf) on a robot's open, empty changer by hand (the
    // Kelvin changer's lock can be worked by a person too); and unlock it onto the shelf.
    std::string attachToolByHand(const std::string& robot, const std::string& tool);
    std::string detachToolByHand(const std::string& robot);
    // Place an object at a pose (its centre); it then rests on what is below it.
    std::string placeObject(const std::string& object, const Eigen::Isometry3d& pose);
    // Take an object out of the cell (its holder becomes "removed").
    std::string removeObject(const std::string& object);

    // Advances time by dt: updates flange / TCP poses, contact forces, held objects.
    // dt = 0 (or a non-finite / negative dt) only refreshes them: no time, no step counted.
    void step(double dt);
    double time() const { return time_; }
    std::uint64_t steps() const { return steps_; }

    Snapshot snapshot() const;

    // The contact force (world frame, N) on a point: the spring of the deepest top face
    // (tables, objects resting somewhere, not held ones) whose footprint holds the point (on
    // a side face, within touchTolerance, it only touches) and below which it lies, within
    // the body's height; zero otherwise. step() applies it to each robot's TCP point (a
    // parallel gripper's: its two finger tips).
    Eigen::Vector3d contactForceAt(const Eigen::Vector3d& point) const;

    // The Kelvin state voltage for a changer state (24 V scale).
    static double changerVoltage(ChangerLock lock, int toolChangerId);

  private:
    void update(std::size_t robot);
    void updateChanger(std::size_t robot);
    void updateHeld();
    void settle(std::size_t object);
    void pushBetweenFingers(std::size_t tool, double before, double after);
    std::optional<Eigen::Isometry3d> toolFrame(std::size_t tool) const;
    std::optional<std::size_t> toolIndex(const std::string& name) const;
    std::optional<std::size_t> objectIndex(const std::string& name) const;
    bool resting(std::size_t object) const;  // in the cell and not held by a tool

    std::vector<Eigen::Isometry3d> heldOffsets_;  // per tool: grip point -> held object
    std::vector<double> fingerOpenings_;          // per tool (parallel grippers), m

    CellDescription cell_;
    WorldConfig config_;
    std::vector<RobotState> robots_;
    std::vector<ObjectState> objects_;
    std::vector<ToolState> tools_;
    double time_ = 0.0;
    std::uint64_t steps_ = 0;
};

}  // namespace pnp::world
