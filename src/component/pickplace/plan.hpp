// The geometry of one pick-and-place (no OPC UA, no knowledge base): from the object's pose
// and size, the tool's grip point and the place position, the four grip-point poses the robot
// moves through, or the reason why the object cannot be taken with this tool.
//
// Frames (world, metres, radians; the robot's active tool frame is the grip point, so every
// pose below is a grip-point pose):
//   object pose     = its centre (the knowledge base's pnp:pose), size = its box extents;
//   PlacePosition   = the pose of the object's bottom-face centre where it shall stand
//                     (z 0 = on the table): its centre ends at PlacePosition · (0, 0, size.z/2);
//   tool orientation= tool z pointing down (a rotation of π about y, as the docks hold the
//                     tools), turned with the object's yaw.
// Vacuum: the cup on the centre of the top face. Parallel fingers (closing along the grip
// frame's x axis): around the object at its centre's height, across its x extent (or across
// y, turned by 90°, when only that fits); an object wider than the span's high limit (less a
// clearance) is refused. Approaches: `approachHeight` straight above pick and place.
#pragma once

#include <Eigen/Geometry>
#include <optional>
#include <string>

namespace pnp::component::pickplace {

enum class GripKind { Parallel, Vacuum };

// A tool's grip point as its IGripperType shows it (GripPoints/GripPoint_1).
struct GripPoint {
    GripKind kind = GripKind::Parallel;
    Eigen::Isometry3d offset = Eigen::Isometry3d::Identity();  // flange -> grip point
    double spanLow = 0.0;                                      // m (parallel only)
    double spanHigh = 0.0;
    std::string name;  // its DisplayName ("Tip")
};

// An object of the world model.
struct ObjectInfo {
    std::string id;
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // its centre, world frame
    Eigen::Vector3d size = Eigen::Vector3d::Zero();          // box extents, m
};

struct PlanOptions {
    double approachHeight = 0.05;     // m above pick and place, along world z
    double fingerClearance = 0.002;   // m the open fingers need beyond the object's width
    double uprightTolerance = 0.087;  // rad (5°): the object's z axis against world z
};

// Grip-point poses (world frame) in the order they are reached.
struct Plan {
    Eigen::Isometry3d pickApproach, pick, placeApproach, place;
    Eigen::Isometry3d objectAtPlace;  // the object's centre after the place
    double gripWidth = 0.0;           // m across the fingers (parallel); 0 for vacuum
};

// The plan, or nullopt with the reason in `error` (nothing may move then).
std::optional<Plan> planPickAndPlace(const ObjectInfo& object, const GripPoint& grip,
                                     const Eigen::Isometry3d& placePosition,
                                     const PlanOptions& options, std::string& error);

std::string toString(GripKind kind);

}  // namespace pnp::component::pickplace
