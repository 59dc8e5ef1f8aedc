// The Pick-and-Place component (cell.md §3; the thesis's composite skill): PickAndPlace
// (models/Pnp.Skills.Composite.NodeSet2.xml, PickAndPlaceSkillType: ObjectId,
// ToolSkillControllerEndpoint, MoveSkillControllerEndpoint, PlacePosition) on
// DeviceSet/<name>. It looks the object up in the knowledge base (pose, size), reads the
// attached tool's grip point through IGripperType (type, offset, span), plans (plan.hpp) and
// runs the robot's CartesianLinearMove and the tool's Grasp / Release skills, found by type
// with the skill detector, step by step:
//   Init, MovePickApproachBefore, MovePick, Grasp, MovePickApproachAfter,
//   MovePlaceApproachBefore, MovePlace, Release, MovePlaceApproachAfter, Idle
// (SkillStep and IntermediateResult). The next lower skill is prepared while the previous
// one runs (locked for the whole run, its parameters written right after the previous
// Start: a run takes its parameters at Start), so that its Start follows the previous one's
// end event within a round trip. Halt / Suspend / Resume go to the lower skill running; a
// failed lower skill fails the run ("Grasp on <component> failed: <its message>") after the
// robot went back up to the approach pose. After a completed run the object's pose in the
// knowledge base is the placed one.
//
//   ua::server::Server server(config);
//   PickPlaceComponent pp(server, {.knowledge = kb}, &mdns);
//   server.start();
//   pp.start();
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "component/pickplace/plan.hpp"
#include "kb/knowledge_base.hpp"
#include "mdns/mdns.hpp"
#include "skill/detector/skill_detector.hpp"
#include "skill/server/controller.hpp"
#include "ua/server/server.hpp"

namespace pnp::component::pickplace {

// The step names (SkillStep, FinalResultData/Steps).
namespace steps {
inline constexpr const char* Init = "Init";
inline constexpr const char* MovePickApproachBefore = "MovePickApproachBefore";
inline constexpr const char* MovePick = "MovePick";
inline constexpr const char* Grasp = "Grasp";
inline constexpr const char* MovePickApproachAfter = "MovePickApproachAfter";
inline constexpr const char* MovePlaceApproachBefore = "MovePlaceApproachBefore";
inline constexpr const char* MovePlace = "MovePlace";
inline constexpr const char* Release = "Release";
inline constexpr const char* MovePlaceApproachAfter = "MovePlaceApproachAfter";
inline constexpr const char* Idle = "Idle";
}  // namespace steps

struct PickPlaceOptions {
    std::string name = "PickAndPlace";  // DeviceSet/<name>; the skill is Skills/PickAndPlace
    // The world model. Shared: the caller may load more into it (or read it) meanwhile.
    std::shared_ptr<kb::KnowledgeBase> knowledge;
    // Discovery of the skill detector (mDNS when given one, LDS-MEs in watcher.ldsUrls;
    // useDiscovery = false: only the endpoints given as parameters and detector()'s URLs).
    skill::detector::DetectorConfig detector;
    PlanOptions plan;
    std::vector<double> travelVelocity = {
        0.25, 1.0};  // m/s, rad/s: between the approaches (the robot's default maximum)
    std::vector<double> nearVelocity = {0.1, 1.0};  // m/s, rad/s: approach <-> object

    std::chrono::milliseconds moveTimeout{30000};     // per robot move
    std::chrono::milliseconds gripperTimeout{15000};  // per Grasp / Release
    std::chrono::milliseconds findTimeout{5000};      // robot / tool not detected yet
    std::chrono::milliseconds requestTimeout{2000};   // per OPC UA request / KB query
    // Lines for people (each run's steps, failures, halts); default: stderr.
    std::function<void(const std::string&)> log;
};

// One lower skill's run within a PickAndPlace (FinalResultData/Steps ... and lastSteps()).
struct StepRecord {
    std::string step;                     // MovePick, Grasp, ...
    std::string skill;                    // "<skill name>@<endpoint>"
    double startUnixS = 0, endUnixS = 0;  // its Running / end transition events (server clock)
    double overheadMs = -1;               // previous step's end -> this Start (-1: first)
    std::string result;                   // Completed, Failed, Aborted
};

class PickPlaceComponent {
  public:
    // Loads the composite skill model and builds DeviceSet/<name> with Skills/PickAndPlace;
    // call before Server::start(). mdns may be null. Throws skill::server::SkillError /
    // ua::server::NodeSetError / std::invalid_argument (no knowledge base).
    PickPlaceComponent(ua::server::Server& server, PickPlaceOptions options,
                       mdns::Mdns* mdns = nullptr);
    ~PickPlaceComponent();  // stop()
    PickPlaceComponent(const PickPlaceComponent&) = delete;
    PickPlaceComponent& operator=(const PickPlaceComponent&) = delete;

    void start();  // the skill detector
    void stop();   // halts a running PickAndPlace, stops the detector

    skill::detector::SkillDetector& detector();
    const ua::NodeId& node() const;       // DeviceSet/<name>
    const ua::NodeId& skillNode() const;  // .../Skills/PickAndPlace
    std::vector<StepRecord> lastSteps() const;

    struct Impl;

  private:
    std::shared_ptr<Impl> impl_;
};

}  // namespace pnp::component::pickplace
