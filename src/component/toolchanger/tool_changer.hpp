// The tool changer component (cell.md §3; the thesis's Kelvin tool changer software
// component): the skills ChangeTool, AttachTool, DetachTool and DropTool
// (models/Pnp.Skills.ToolChanger.NodeSet2.xml) on a ToolChangerType object, done by moving
// the robot that carries the passive Kelvin changer through the docking sequence with the
// robot's CartesianLinearMove skill, and checking the changer's state voltage (the ADC
// board's values, `pnp device kelvin-adc`) at each stage.
//
// The docking sequence, in flange poses (world frame); D = the dock's pose (ToolPosition),
// O = D·Rz(−lockAngle) the open pose, ↑ = raised liftHeight along world z:
//   attach: LIN O↑, LIN O (ADC: ready), LIN D (turn: tool N), LIN D↑ (the tool comes along),
//           then the tool's server is waited for in the skill detector (ToolAppUri, or ""
//           = learned: the server that appeared after the lock) and the robot's SetTool gets
//           the tool's grip point (IGripperType GripPoints/GripPoint_1); FinalResultData
//           names the tool attached or parked (ToolAppUri, ToolName, ToolEndpoint, ToolId,
//           ToolPosition)
//           and the arm goes straight up until the tool's grip point is at travelHeight
//   detach: LIN D↑, LIN D (tool N), LIN O (turn: ready), LIN O↑; then ClearTool
// Each approach (to O↑ or D↑) starts from where the arm is (the robot's ActualFlangePose):
// straight up to travelHeight (for what the flange carries), across at that height, down.
// A failed check ends the run Failed with the reason, after moving the robot back clear of
// the dock (turning the ring back first when it turned). Halt halts the robot's move and
// leaves the changer where it is; the Condition variable, the skill's FinalResultData/Message
// and the log say what it left (e.g. "changer intermediate at dock …: the tool may be half
// locked"), and the next run checks the changer before it moves.
//
//   ua::server::Server server(config);
//   ToolChangerComponent changer(server, {.robot = "opc.tcp://robot:4841", .adc = "auto"}, &mdns);
//   server.start();
//   changer.start();
//   changer.waitReady(5s);  // robot and ADC found
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "mdns/mdns.hpp"
#include "skill/detector/skill_detector.hpp"
#include "skill/server/controller.hpp"
#include "ua/server/server.hpp"

namespace pnp::component::toolchanger {

// Nodes of urn:pnp:ua:skills:toolchanger beyond skill/model/model.hpp's list.
namespace types {
using skill::types::DropToolSkillType;
inline constexpr skill::ModelNode IToolChangeResultType{skill::kToolChangerUri, 1005,
                                                        "IToolChangeResultType"};
inline constexpr skill::ModelNode ToolChangerType{skill::kToolChangerUri, 1010, "ToolChangerType"};
inline constexpr skill::ModelNode ToolInfoType{skill::kToolChangerUri, 1011, "ToolInfoType"};
}  // namespace types

// The skills' BrowseNames below DeviceSet/<name>/Skills.
namespace skill_names {
inline constexpr const char* ChangeTool = "ChangeTool";
inline constexpr const char* AttachTool = "AttachTool";
inline constexpr const char* DetachTool = "DetachTool";
inline constexpr const char* DropTool = "DropTool";
}  // namespace skill_names

struct ToolChangerOptions {
    std::string name = "ToolChanger";  // DeviceSet/<name>
    // The robot carrying the changer: its server's endpoint URL, or "auto" (the only robot
    // with a CartesianLinearMove skill the detector finds).
    std::string robot = "auto";
    // The Kelvin ADC board's server, or "auto" (the discovered server with a
    // KelvinToolChangerType object).
    std::string adc = "auto";
    // Discovery of the skill detector (mDNS when given one, LDS-MEs in watcher.ldsUrls;
    // useDiscovery = false: only the URLs above and those added to detector()).
    skill::detector::DetectorConfig detector;

    double lockAngle = 0.5235987755982988;             // rad (30°): the turn from open to locked
    double liftHeight = 0.10;                          // m above the dock, along world z
    std::vector<double> travelVelocity = {0.25, 1.0};  // m/s, rad/s: to and from above the dock
    std::vector<double> dockVelocity = {0.1, 1.0};     // m/s, rad/s: down, turn, up at the dock
    // The world z that the lowest point of what the flange carries (the attached tool's grip
    // point, else the flange) stays above while the arm travels to or from a dock: docks may
    // be beyond a table's edge with the tools hanging below its top. Approach: up from where
    // the arm is (ActualFlangePose) to this height, across, then down to above the dock;
    // after an attach: straight up until the tool's grip point is this high ("Clear").
    double travelHeight = 0.10;  // m
    // The grip point assumed for a tool whose own is not known (not attached by this
    // component, or without IGripperType grip point): this far below the flange.
    double unknownToolLength = 0.25;  // m

    std::chrono::milliseconds moveTimeout{30000};  // per robot move
    // After a move, for the ADC to show the expected state (its poll, the subscription).
    std::chrono::milliseconds settleTimeout{1000};
    std::chrono::milliseconds toolDetectTimeout{15000};  // the tool's server and skills
    std::chrono::milliseconds findTimeout{5000};     // robot / ADC not found yet when a run starts
    std::chrono::milliseconds requestTimeout{2000};  // per OPC UA request
    // Lines for people (phases, halts, resets); default: stderr.
    std::function<void(const std::string&)> log;
};

// A phase of a run and how long it took.
struct PhaseTime {
    std::string name;
    double seconds = 0.0;
};

class ToolChangerComponent {
  public:
    // Loads the tool changer model and builds DeviceSet/<name> with the four skills; call
    // before Server::start(). mdns may be null. Throws skill::server::SkillError /
    // ua::server::NodeSetError.
    ToolChangerComponent(ua::server::Server& server, ToolChangerOptions options,
                         mdns::Mdns* mdns = nullptr);
    ~ToolChangerComponent();  // stop()
    ToolChangerComponent(const ToolChangerComponent&) = delete;
    ToolChangerComponent& operator=(const ToolChangerComponent&) = delete;

    void start();  // the skill detector (and the robot's / ADC's URLs when given)
    void stop();   // halts a running change, stops the detector

    // Blocks until the robot and the ADC are found and connected; "" or why not.
    std::string waitReady(std::chrono::milliseconds timeout);

    skill::detector::SkillDetector& detector();
    const ua::NodeId& node() const;  // DeviceSet/<name>
    std::vector<skill::server::SkillHandle> skills() const;
    std::string condition() const;  // what a halt left behind ("" = none)
    // The phases of the last run that got as far as moving.
    std::vector<PhaseTime> lastPhases() const;

    struct Impl;

  private:
    std::shared_ptr<Impl> impl_;
};

}  // namespace pnp::component::toolchanger
