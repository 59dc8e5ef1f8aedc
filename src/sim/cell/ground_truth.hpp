// The world's ground truth as a read-only OPC UA view (namespace urn:pnp:sim:world), for
// tests, the dashboard and users — never for adapters or components:
//
//   Objects/World                 Time (Double, s), Step (UInt64), CellName (String)
//     Robots/<robot>              Model (String: ur3, ur5, ur10), Base (ThreeDFrame,
//                                 world -> robot base), Joints, JointVelocities (Double[6]: rad,
//                                 rad/s), FlangePose, TcpPose (ThreeDFrame, world), TcpForce
//                                 (ThreeDVector, N, world), Tool (String, "" = none),
//                                 Changer (String: Open, Intermediate, Locked),
//                                 ChangerVoltage (Double, V), Dock (String: the dock the
//                                 changer sits in, "" = none)
//     Tables/<table>              Pose (ThreeDFrame: centre of the top face), Size
//                                 (ThreeDVector, m: the box hangs Size.z below the top)
//     Docks/<dock>                Pose (ThreeDFrame: a parked tool's flange-side frame)
//     Objects/<object>            Pose (ThreeDFrame), Holder (String), Size (ThreeDVector,
//                                 m), Color (String: a name or #rrggbb, when the cell has one)
//     Tools/<tool>                Dock (String), Robot (String), Powered (Boolean),
//                                 Held (String: the object it holds), Tcp (ThreeDFrame:
//                                 flange -> TCP)
//   and the operator's hands, methods of World (each returns Error: String, "" = done):
//     PutToolInDock(Tool, Dock), TakeToolOut(Tool), AttachToolByHand(Robot, Tool),
//     DetachToolByHand(Robot), PlaceObject(Object, Pose: ThreeDFrame), RemoveObject(Object)
//
// Poses use pnp's convention (ua/spatial/spatial.hpp). The cell file's static facts (Model,
// Base, Tables, Docks' Pose, Size, Color, Tcp) are written once; the other values are
// updated from the simulator's snapshots at `rate` by a thread of its own, only when they
// changed.
#pragma once

#include <memory>
#include <string_view>

#include "sim/cell/simulator.hpp"
#include "ua/server/server.hpp"

namespace pnp::sim::cell {

inline constexpr std::string_view kWorldNamespaceUri = "urn:pnp:sim:world";

struct GroundTruthOptions {
    double rate = 125.0;  // updates per second
};

class GroundTruth {
  public:
    // Adds the nodes (before server.start()); start() begins the updates.
    GroundTruth(ua::server::Server& server, Simulator& simulator, GroundTruthOptions options = {});
    ~GroundTruth();  // stop()
    GroundTruth(const GroundTruth&) = delete;
    GroundTruth& operator=(const GroundTruth&) = delete;

    void start();
    void stop();
    ua::UInt16 namespaceIndex() const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::sim::cell
