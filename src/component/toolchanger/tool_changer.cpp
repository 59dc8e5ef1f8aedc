#include "component/toolchanger/tool_changer.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <sstream>
#include <stop_token>
#include <thread>

#include "component/toolchanger/adc_monitor.hpp"
#include "component/toolchanger/robot_arm.hpp"
#include "ua/client/client.hpp"
#include "ua/discovery/watcher.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_model.hpp"

namespace pnp::component::toolchanger {

using namespace std::chrono_literals;
using skill::server::Execution;
using skill::server::Outcome;
using Clock = std::chrono::steady_clock;
using Eigen::Isometry3d;
namespace kelvin = device::kelvin;

namespace {

std::string formatSeconds(double s) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.3f s", s);
    return buf;
}

Isometry3d raised(const Isometry3d& pose, double height) {
    Isometry3d p = pose;
    p.translation().z() += height;
    return p;
}

// Same dock: positions within 5 mm, orientations within 0.05 rad.
bool samePose(const Isometry3d& a, const Isometry3d& b) {
    const double angle = Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
    return (a.translation() - b.translation()).norm() < 0.005 && std::abs(angle) < 0.05;
}

struct CurrentTool {
    int id = 0;
    std::string applicationUri;
    std::string name;                      // ApplicationName
    std::string endpoint;                  // the tool's server
    std::string toolFrame;                 // the name given to the robot's SetTool ("" = none set)
    std::optional<Isometry3d> gripOffset;  // flange -> the tool's grip point, when known
};

// The tool a run attached or parked, for its FinalResultData (the MES records "the dock at
// ToolPosition holds the tool with ApplicationUri ToolAppUri").
struct ToolRecord {
    int id = 0;
    std::string applicationUri, name, endpoint;
    std::optional<Isometry3d> dock;
};

// When each server's skills last appeared in the detector (its change events), keyed by
// ApplicationUri (else URL): a tool's server is one whose skills appeared after the lock,
// even when an earlier run of the same server was still listed then.
struct Appearances {
    static constexpr std::size_t kMaxServers = 4096;  // bound on what the network can make us hold
    std::mutex mutex;
    std::map<std::string, Clock::time_point> lastAdded;
    void added(const std::string& key) {
        std::lock_guard l(mutex);
        if (lastAdded.size() >= kMaxServers && !lastAdded.contains(key)) {
            auto oldest = lastAdded.begin();
            for (auto it = lastAdded.begin(); it != lastAdded.end(); ++it)
                if (it->second < oldest->second) oldest = it;
            lastAdded.erase(oldest);
        }
        lastAdded[key] = Clock::now();
    }
    std::optional<Clock::time_point> when(const std::string& key) {
        std::lock_guard l(mutex);
        auto it = lastAdded.find(key);
        if (it == lastAdded.end()) return std::nullopt;
        return it->second;
    }
};

std::string serverKey(const skill::detector::DetectedSkill& s) {
    return s.componentUri.empty() ? ua::discovery::normaliseUrl(s.endpointUrl) : s.componentUri;
}

// The outcome of a sequence step: empty = go on.
struct Stop {
    skill::SkillResult result = skill::SkillResult::Failed;
    std::string message;
};

}  // namespace

struct ToolChangerComponent::Impl : std::enable_shared_from_this<Impl> {
    ua::server::Server& server;
    ToolChangerOptions options;
    std::unique_ptr<skill::detector::SkillDetector> detector;
    std::shared_ptr<Appearances> appearances = std::make_shared<Appearances>();
    std::unique_ptr<skill::server::SkillController> controller;
    ua::NodeId hasToolNode, toolIdNode, toolDescriptionNode, toolEndpointNode, toolUriNode,
        conditionNode;
    ua::UInt16 baseNs = 0;

    std::mutex changeMutex;  // one change at a time, whichever skill runs it

    mutable std::mutex mutex;  // the members below
    std::shared_ptr<RobotArm> arm;
    std::shared_ptr<AdcMonitor> adc;
    std::map<int, Isometry3d> docks;  // tool id -> the dock it was attached from
    CurrentTool current;
    std::string conditionText;
    std::vector<PhaseTime> phases;

    Impl(ua::server::Server& s, ToolChangerOptions o) : server(s), options(std::move(o)) {
        if (!options.log)
            options.log = [](const std::string& line) {
                std::cerr << "pnp component toolchanger: " << line << std::endl;
            };
    }

    // ---- the robot, the ADC ----------------------------------------------------------
    std::string robotUrl(const std::string& override) const {
        if (!override.empty()) return override;
        return options.robot == "auto" ? std::string() : options.robot;
    }

    // The move skill of the robot at `url` ("" = the only one), within findTimeout.
    std::shared_ptr<RobotArm> robotArm(const std::string& url, std::string& error,
                                       std::stop_token stop, std::chrono::milliseconds timeout) {
        const std::string wanted = url.empty() ? "" : ua::discovery::normaliseUrl(url);
        {
            std::lock_guard l(mutex);
            if (arm &&
                (wanted.empty() || ua::discovery::normaliseUrl(arm->endpointUrl()) == wanted))
                return arm;
        }
        if (!url.empty()) detector->addServer(url);  // known already: a no-op
        const auto end = Clock::now() + timeout;
        std::optional<skill::detector::DetectedSkill> found;
        while (!stop.stop_requested()) {
            // One robot per ApplicationUri: a server found by mDNS and by an LDS shows up
            // under two URLs (host name and address), and is still one robot.
            std::map<std::string, std::string> robots;  // ApplicationUri (else URL) -> URL
            for (auto& s : detector->find(skill::types::CartesianLinearMoveSkillType)) {
                const std::string u = ua::discovery::normaliseUrl(s.endpointUrl);
                if (!wanted.empty() && u != wanted) continue;
                robots.emplace(s.componentUri.empty() ? u : s.componentUri, u);
                if (!found) found = s;
            }
            if (robots.size() > 1) {
                error = "several robots offer CartesianLinearMove (";
                for (const auto& [uri, e] : robots) error += (error.back() == '(' ? "" : ", ") + e;
                error += "): name one with --robot URL";
                return nullptr;
            }
            if (found || Clock::now() >= end) break;
            detector->waitUntil(
                [](const skill::detector::SkillDetector& d) {
                    return !d.find(skill::types::CartesianLinearMoveSkillType).empty();
                },
                50ms);
        }
        if (!found) {
            error = wanted.empty() ? "no robot with a CartesianLinearMove skill found"
                                   : "no CartesianLinearMove skill found at " + url;
            return nullptr;
        }
        try {
            auto a = std::make_shared<RobotArm>(*found, options.requestTimeout);
            std::lock_guard l(mutex);
            arm = a;
            return a;
        } catch (const std::exception& e) {
            error = "the robot at " + found->endpointUrl + ": " + e.what();
            return nullptr;
        }
    }

    std::shared_ptr<AdcMonitor> adcMonitor(std::string& error, std::stop_token stop,
                                           std::chrono::milliseconds timeout) {
        {
            std::lock_guard l(mutex);
            if (adc) return adc;
        }
        const auto end = Clock::now() + timeout;
        std::string url = options.adc == "auto" ? "" : options.adc;
        while (url.empty() && !stop.stop_requested() && Clock::now() < end) {
            for (const auto& s : detector->servers()) {
                if (s.status != skill::detector::ServerState::Status::Skills &&
                    s.status != skill::detector::ServerState::Status::NoSkills)
                    continue;
                if (AdcMonitor::isKelvinAdc(s.url, options.requestTimeout)) {
                    url = s.url;
                    break;
                }
            }
            if (url.empty()) std::this_thread::sleep_for(50ms);
        }
        if (url.empty()) {
            error =
                "no Kelvin ADC board (KelvinToolChangerType) found: start `pnp device "
                "kelvin-adc` or pass --adc URL";
            return nullptr;
        }
        try {
            auto m = std::make_shared<AdcMonitor>(url, options.requestTimeout);
            std::lock_guard l(mutex);
            adc = m;
            return m;
        } catch (const std::exception& e) {
            error = "the Kelvin ADC board at " + url + ": " + e.what();
            return nullptr;
        }
    }

    // ---- published state -----------------------------------------------------------------
    void publishTool() {
        CurrentTool t;
        std::string c;
        {
            std::lock_guard l(mutex);
            t = current;
            c = conditionText;
        }
        auto& space = server.addressSpace();
        (void)space.setValue(hasToolNode, ua::DataValue(ua::Variant(t.id != 0)));
        (void)space.setValue(toolIdNode, ua::DataValue(ua::Variant(ua::Int32{t.id})));
        (void)space.setValue(toolDescriptionNode, ua::DataValue(ua::Variant(ua::String(t.name))));
        (void)space.setValue(toolEndpointNode, ua::DataValue(ua::Variant(ua::String(t.endpoint))));
        (void)space.setValue(toolUriNode, ua::DataValue(ua::Variant(ua::String(t.applicationUri))));
        (void)space.setValue(conditionNode, ua::DataValue(ua::Variant(ua::String(c))));
    }

    // What the ADC says is on the changer now, into CurrentTool (a tool we did not attach:
    // its id only).
    void syncWithAdc(const AdcSample& s) {
        {
            std::lock_guard l(mutex);
            if (!s.valid) return;
            if (s.reading.state == ChangerState::kTool) {
                if (current.id != s.reading.toolId)
                    current = CurrentTool{s.reading.toolId, {}, {}, {}, {}, {}};
            } else if (s.reading.state == ChangerState::kReady ||
                       s.reading.state == ChangerState::kNoTool) {
                current = CurrentTool{};
            }
        }
        publishTool();
    }

    void setCondition(std::string text) {
        {
            std::lock_guard l(mutex);
            conditionText = std::move(text);
        }
        publishTool();
    }

    // ---- one run -------------------------------------------------------------------------
    struct Run {
        std::stop_token stop;
        std::shared_ptr<RobotArm> arm;
        std::shared_ptr<AdcMonitor> adc;
        std::vector<PhaseTime> phases;
        std::string phase;  // the one running
        Clock::time_point phaseStart;
        Isometry3d dock = Isometry3d::Identity();  // the dock the sequence works at
        std::string prefix;                        // "Detach." / "Attach." within ChangeTool
        bool halted = false;
        ToolRecord tool;  // attached (attach) or parked (detach) so far
        // What the flange carries now: nullopt = nothing; else flange -> the tool's lowest
        // point (its grip point, or unknownToolLength below the flange when not known).
        std::optional<Isometry3d> carried;
    };

    void beginPhase(Run& r, const std::string& name) {
        endPhase(r);
        r.phase = r.prefix + name;
        r.phaseStart = Clock::now();
    }
    void endPhase(Run& r) {
        if (r.phase.empty()) return;
        r.phases.push_back(
            {r.phase, std::chrono::duration<double>(Clock::now() - r.phaseStart).count()});
        r.phase.clear();
    }

    // A move; a Stop when it did not complete.
    std::optional<Stop> move(Run& r, const Isometry3d& target, const std::vector<double>& v) {
        if (r.stop.stop_requested()) {
            r.halted = true;
            return Stop{skill::SkillResult::Aborted, "halted"};
        }
        MoveOutcome m = r.arm->moveLinear(target, v, options.moveTimeout, r.stop);
        if (m.completed) return std::nullopt;
        if (m.aborted || r.stop.stop_requested()) {
            r.halted = true;
            return Stop{skill::SkillResult::Aborted, "halted: " + m.message};
        }
        return Stop{skill::SkillResult::Failed,
                    m.message + " (moving to " + ua::spatial::positionText(target) + ")"};
    }

    // ---- travel height -------------------------------------------------------------------
    Isometry3d unknownTool() const {
        Isometry3d t = Isometry3d::Identity();
        t.translation().z() = options.unknownToolLength;
        return t;
    }
    // The lowest flange z at `flange`'s orientation that keeps what the flange carries (the
    // flange itself, and the tool's grip point) at or above travelHeight.
    double travelFlangeZ(const Run& r, const Isometry3d& flange) const {
        double below = 0.0;  // how far the lowest point is below the flange
        if (r.carried)
            below =
                std::max(0.0, flange.translation().z() - (flange * *r.carried).translation().z());
        return options.travelHeight + below;
    }

    // To `target` (above a dock) from where the arm is: straight up to the travel height (or
    // stay at the current height when it is higher), across at that height, then straight
    // down — no line from elsewhere in the cell dips below the travel height. Without the
    // robot's actual pose (no ActualFlangePose): one line, as before, and a log line.
    std::optional<Stop> travelTo(Run& r, const Isometry3d& target) {
        constexpr double kTolerance = 0.001;  // m
        std::string error;
        const std::optional<Isometry3d> here = r.arm->flangePose(error);
        if (!here) {
            options.log("straight to " + ua::spatial::positionText(target) +
                        ": where the arm is is unknown (" + error + ")");
            return move(r, target, options.travelVelocity);
        }
        // Already at the dock's approach pose (e.g. a retry): the dock's own way.
        if (samePose(*here, target)) return move(r, target, options.travelVelocity);
        const double height = std::max({here->translation().z(), travelFlangeZ(r, *here),
                                        travelFlangeZ(r, target), target.translation().z()});
        Isometry3d up = *here;
        up.translation().z() = height;
        Isometry3d across = target;
        across.translation().z() = height;
        if (height - here->translation().z() > kTolerance)
            if (auto s = move(r, up, options.travelVelocity)) return s;
        const bool moved =
            (across.translation() - up.translation()).norm() > kTolerance ||
            Eigen::AngleAxisd(up.linear().transpose() * across.linear()).angle() > kTolerance;
        if (moved)
            if (auto s = move(r, across, options.travelVelocity)) return s;
        if (height - target.translation().z() > kTolerance)
            if (auto s = move(r, target, options.travelVelocity)) return s;
        return std::nullopt;
    }

    // Straight up from `from` (where the last move left the flange) until what it carries is
    // at the travel height; nothing when it is already.
    std::optional<Stop> clearUp(Run& r, const Isometry3d& from) {
        const double z = travelFlangeZ(r, from);
        if (z <= from.translation().z()) return std::nullopt;
        Isometry3d p = from;
        p.translation().z() = z;
        return move(r, p, options.travelVelocity);
    }
    // clearUp after a failure with a tool locked: what it could not do, appended.
    std::string clearAfterFailure(Run& r, const Isometry3d& from) {
        if (r.stop.stop_requested()) return {};
        if (auto s = clearUp(r, from))
            return "; could not move clear above the dock: " + s->message;
        return {};
    }

    // Waits for the ADC to show what `pred` wants; the sample it ended on.
    AdcSample expect(Run& r, const std::function<bool(const AdcSample&)>& pred) {
        auto s = r.adc->waitFor(pred, options.settleTimeout, r.stop);
        if (r.stop.stop_requested()) r.halted = true;
        return s ? *s : r.adc->latest();
    }

    // Moves back up clear of the dock after a failure; what it could not do, appended.
    std::string recover(Run& r, const std::vector<Isometry3d>& path) {
        for (const Isometry3d& p : path) {
            if (r.stop.stop_requested()) return "; halted while moving clear of the dock";
            MoveOutcome m = r.arm->moveLinear(p, options.dockVelocity, options.moveTimeout, r.stop);
            if (!m.completed)
                return "; could not move clear of the dock: " + m.message + " (to " +
                       ua::spatial::positionText(p) + ")";
        }
        return {};
    }

    static bool isReady(const AdcSample& s) {
        return s.valid && s.reading.state == ChangerState::kReady;
    }
    static bool isTool(const AdcSample& s) {
        return s.valid && s.reading.state == ChangerState::kTool;
    }

    // The first check of every run: the changer's state now.
    AdcSample currentState(Run& r) {
        return expect(r, [](const AdcSample& s) { return s.valid; });
    }

    // ---- attach --------------------------------------------------------------------------
    // The docking poses of a dock: the changer's open angle in it, and both raised above.
    struct DockPoses {
        Isometry3d open, openAbove, lockedAbove;
        std::string where;
    };
    DockPoses dockPoses(const Isometry3d& dock) const {
        DockPoses p;
        p.open = dock * Eigen::AngleAxisd(-options.lockAngle, Eigen::Vector3d::UnitZ());
        p.openAbove = raised(p.open, options.liftHeight);
        p.lockedAbove = raised(dock, options.liftHeight);
        p.where = " at the dock " + ua::spatial::positionText(dock);
        return p;
    }

    std::optional<Stop> attach(Run& r, const Isometry3d& dock, const std::string& appUri) {
        r.dock = dock;
        r.tool = ToolRecord{};
        const auto [open, openAbove, lockedAbove, where] = dockPoses(dock);

        const AdcSample pre = currentState(r);
        if (r.halted) return Stop{skill::SkillResult::Aborted, "halted"};
        if (!isReady(pre)) {
            std::string why;
            switch (pre.reading.state) {
                case ChangerState::kTool:
                    why = "a tool is already attached (" + describe(pre) +
                          "): detach it first (DetachTool, DropTool) or use ChangeTool";
                    break;
                case ChangerState::kNoTool:
                    why = "the changer is locked without a tool (" + describe(pre) +
                          "): it must be open to attach a tool";
                    break;
                default:
                    why = "the changer is not open (" + describe(pre) + "); it must read ready";
            }
            return Stop{skill::SkillResult::Failed, why};
        }
        if (auto e = r.arm->clearTool(""); !e.empty()) return Stop{skill::SkillResult::Failed, e};

        r.carried.reset();
        beginPhase(r, "Approach");
        if (auto s = travelTo(r, openAbove)) return s;
        if (auto s = move(r, open, options.dockVelocity)) {
            if (s->result == skill::SkillResult::Failed) s->message += recover(r, {openAbove});
            return s;
        }
        if (const AdcSample s = expect(r, isReady); !isReady(s)) {
            if (r.halted) return Stop{skill::SkillResult::Aborted, "halted"};
            return Stop{skill::SkillResult::Failed,
                        "the changer reads " + describe(s) + " in the open pose" + where +
                            ", expected ready" + recover(r, {openAbove})};
        }
        beginPhase(r, "Lock");
        // A tool's power comes on with the lock: its server appears after this.
        const auto lockStart = Clock::now();
        if (auto s = move(r, dock, options.dockVelocity)) {
            if (s->result == skill::SkillResult::Failed)
                s->message += recover(r, {open, openAbove});
            return s;
        }
        const AdcSample locked = expect(r, isTool);
        if (!isTool(locked)) {
            if (r.halted) return Stop{skill::SkillResult::Aborted, "halted"};
            std::string why;
            switch (locked.reading.state) {
                case ChangerState::kNoTool:
                    why = "no tool in the dock" + where + ": the changer locked empty (" +
                          describe(locked) + ")";
                    break;
                case ChangerState::kReady:
                    why = "the changer did not turn" + where + " (still " + describe(locked) +
                          "): is ToolPosition a dock?";
                    break;
                default:
                    why = "the changer did not lock" + where + " (" + describe(locked) + ")";
            }
            // Turn the ring back open before leaving, so that nothing stays half locked.
            return Stop{skill::SkillResult::Failed, why + recover(r, {open, openAbove})};
        }
        const int toolId = locked.reading.toolId;
        const auto lockedAt = Clock::now();
        r.carried = unknownTool();
        beginPhase(r, "Leave");
        if (auto s = move(r, lockedAbove, options.dockVelocity)) return s;
        if (const AdcSample s = expect(r, isTool); !isTool(s) || s.reading.toolId != toolId) {
            if (r.halted) return Stop{skill::SkillResult::Aborted, "halted"};
            return Stop{
                skill::SkillResult::Failed,
                "the tool did not stay on the changer when leaving the dock (" + describe(s) + ")"};
        }
        {
            std::lock_guard l(mutex);
            // A dock holds one tool: what an earlier attach learned about it goes (an
            // operator may have swapped the tool in it since).
            std::erase_if(docks, [&](const auto& d) { return samePose(d.second, dock); });
            docks[toolId] = dock;
            current = CurrentTool{toolId, appUri, {}, {}, {}, {}};
        }
        r.tool = ToolRecord{toolId, appUri, {}, {}, dock};
        publishTool();

        beginPhase(r, "ToolDetected");
        std::vector<skill::detector::DetectedSkill> toolSkills;
        std::string error;
        if (appUri.empty())
            toolSkills = newToolServer(r, lockStart, error);
        else
            toolSkills = namedToolServer(r, appUri);
        if (r.stop.stop_requested()) {
            r.halted = true;
            return Stop{skill::SkillResult::Aborted, "halted"};
        }
        if (!error.empty())
            return Stop{skill::SkillResult::Failed, "tool " + std::to_string(toolId) +
                                                        " locked, but " + error +
                                                        clearAfterFailure(r, lockedAbove)};
        if (toolSkills.empty())
            return Stop{
                skill::SkillResult::Failed,
                (appUri.empty() ? "tool " + std::to_string(toolId) +
                                      " locked but no tool server appeared within " +
                                      std::to_string(options.toolDetectTimeout.count()) + " ms"
                                : "tool " + std::to_string(toolId) + " is locked, but no server " +
                                      appUri + " with skills was detected within " +
                                      std::to_string(options.toolDetectTimeout.count()) + " ms") +
                    clearAfterFailure(r, lockedAbove)};
        const double detectedAfterLock =
            std::chrono::duration<double>(Clock::now() - lockedAt).count();
        endPhase(r);
        const auto& first = toolSkills.front();
        const std::string toolUri = first.componentUri;
        r.tool = ToolRecord{toolId, toolUri, first.componentName, first.endpointUrl, dock};
        std::string frameName =
            first.componentName.empty() ? "tool-" + std::to_string(toolId) : first.componentName;
        std::string note;
        const std::optional<Isometry3d> offset = gripOffset(toolSkills);
        if (offset) r.carried = *offset;
        {
            std::lock_guard l(mutex);
            current =
                CurrentTool{toolId, toolUri, first.componentName, first.endpointUrl, {}, offset};
        }
        // Up until the tool's grip point is at the travel height, still in flange targets
        // (before SetTool makes the tool frame the robot's active one).
        beginPhase(r, "Clear");
        if (auto s = clearUp(r, lockedAbove)) return s;
        endPhase(r);
        if (offset) {
            if (auto e = r.arm->setTool(frameName, *offset); !e.empty())
                return Stop{skill::SkillResult::Failed,
                            "tool " + std::to_string(toolId) + " attached, but " + e};
        } else {
            frameName.clear();
            note = "; the tool has no IGripperType grip point: the robot's tool frame is not set";
        }
        {
            std::lock_guard l(mutex);
            current.toolFrame = frameName;
        }
        publishTool();
        // When its skills appeared (the detector's event), from the changer's "tool N": the
        // latency of power-up + announcement + discovery, which runs during Leave.
        std::string appeared;
        if (auto when = appearances->when(serverKey(first)))
            appeared = ", its skills appeared " +
                       formatSeconds(std::chrono::duration<double>(*when - lockedAt).count()) +
                       " after the lock";
        options.log("tool " + std::to_string(toolId) + " (" + toolUri + " at " + first.endpointUrl +
                    ") detected " + formatSeconds(detectedAfterLock) + " after the lock" +
                    appeared + (appUri.empty() ? " (learned)" : "") + note);
        return std::nullopt;
    }

    // The skills of the server with ApplicationUri `appUri`, once the detector has them
    // (within toolDetectTimeout; empty: not detected or halted).
    std::vector<skill::detector::DetectedSkill> namedToolServer(Run& r, const std::string& appUri) {
        std::vector<skill::detector::DetectedSkill> toolSkills;
        const auto end = Clock::now() + options.toolDetectTimeout;
        auto ofTool = [&appUri](const skill::detector::SkillDetector& d) {
            std::vector<skill::detector::DetectedSkill> out;
            for (auto& s : d.all())
                if (s.componentUri == appUri) out.push_back(s);
            return out;
        };
        while (!r.stop.stop_requested()) {
            toolSkills = ofTool(*detector);
            if (!toolSkills.empty() || Clock::now() >= end) break;
            detector->waitUntil([&](const auto& d) { return !ofTool(d).empty(); }, 50ms);
        }
        return toolSkills;
    }

    // The tool that was just locked, learned from discovery: the server whose skills appeared
    // in the detector after `lockStart` (the tool's power comes on with the lock), other than
    // the robot, the ADC board and this component. A server with gripper skills is taken
    // before others; two such servers at once are ambiguous (`error`). Its skills, within
    // toolDetectTimeout; empty: none appeared (or halted, or `error`).
    std::vector<skill::detector::DetectedSkill> newToolServer(Run& r, Clock::time_point lockStart,
                                                              std::string& error) {
        std::set<std::string> excludedUrls = {ua::discovery::normaliseUrl(r.arm->endpointUrl()),
                                              ua::discovery::normaliseUrl(r.adc->url())};
        const std::string self = server.config().applicationUri;
        auto candidates = [&](const skill::detector::SkillDetector& d) {
            std::map<std::string, std::vector<skill::detector::DetectedSkill>> byServer;
            std::set<std::string> excluded;
            for (auto& s : d.all()) {
                const std::string key = serverKey(s);
                if (excludedUrls.contains(ua::discovery::normaliseUrl(s.endpointUrl)) ||
                    (!self.empty() && s.componentUri == self))
                    excluded.insert(key);
                byServer[key].push_back(s);
            }
            for (const auto& k : excluded) byServer.erase(k);
            std::erase_if(byServer, [&](const auto& kv) {
                const auto when = appearances->when(kv.first);
                return !when || *when < lockStart;
            });
            return byServer;
        };
        auto isGripper = [](const std::vector<skill::detector::DetectedSkill>& skills) {
            return std::any_of(skills.begin(), skills.end(),
                               [](const auto& s) { return s.isA(skill::types::GripperSkillType); });
        };
        const auto end = Clock::now() + options.toolDetectTimeout;
        while (!r.stop.stop_requested()) {
            auto found = candidates(*detector);
            if (!found.empty()) {
                std::vector<std::string> grippers, all;
                for (const auto& [key, skills] : found) {
                    all.push_back(key);
                    if (isGripper(skills)) grippers.push_back(key);
                }
                const auto& pick = grippers.empty() ? all : grippers;
                if (pick.size() == 1) return found.at(pick.front());
                error = "several servers appeared after the lock (";
                for (std::size_t i = 0; i < pick.size(); ++i)
                    error +=
                        (i ? ", " : "") + pick[i] + " at " + found.at(pick[i]).front().endpointUrl;
                error += "): name the tool with ToolAppUri";
                return {};
            }
            if (Clock::now() >= end) break;
            detector->waitUntil([&](const auto& d) { return !candidates(d).empty(); }, 50ms);
        }
        return {};
    }

    // GripPoints/GripPoint_1/Offset (else the first grip point) below a controller of the
    // tool's server (IGripperType); nullopt when there is none.
    std::optional<Isometry3d> gripOffset(
        const std::vector<skill::detector::DetectedSkill>& skills) {
        std::set<std::pair<std::string, std::string>> seen;
        for (const auto& s : skills) {
            if (!seen.insert({s.endpointUrl, s.controller.toString()}).second) continue;
            try {
                ua::client::ClientConfig cc;
                cc.applicationName = "pnp tool changer";
                cc.applicationUri = "urn:pnp:component:toolchanger:tool-client";
                cc.requestTimeout = options.requestTimeout;
                cc.connectTimeout = options.requestTimeout;
                ua::client::Client c(cc);
                c.connect(s.endpointUrl);
                const ua::UInt16 base = c.namespaceIndex(skill::kBaseUri);
                auto childNamed = [&](const ua::NodeId& parent, const std::string& name,
                                      bool prefix) -> std::optional<ua::NodeId> {
                    std::optional<ua::NodeId> firstMatch;
                    for (const auto& r : c.browse(parent)) {
                        if (r.nodeId.serverIndex != 0) continue;
                        if (r.browseName.name == name) return r.nodeId.nodeId;
                        if (prefix && !firstMatch && r.browseName.namespaceIndex == base &&
                            r.browseName.name.starts_with("GripPoint_"))
                            firstMatch = r.nodeId.nodeId;
                    }
                    return firstMatch;
                };
                auto points = childNamed(s.controller, "GripPoints", false);
                if (!points) continue;
                auto point = childNamed(*points, "GripPoint_1", true);
                if (!point) continue;
                auto offset = childNamed(*point, "Offset", false);
                if (!offset) continue;
                const ua::Variant v = c.readValue(*offset);
                const auto* x = v.scalar<ua::ExtensionObject>();
                if (x == nullptr) continue;
                auto f = ua::fromExtensionObject<ua::ThreeDFrame>(*x);
                if (!f || !ua::spatial::finite(*f)) continue;
                return ua::spatial::toIsometry(*f);
            } catch (const std::exception& e) {
                options.log("reading the grip point of " + s.endpointUrl + ": " + e.what());
            }
        }
        return std::nullopt;
    }

    // ---- detach --------------------------------------------------------------------------
    std::optional<Stop> detach(Run& r, const Isometry3d& dock) {
        r.dock = dock;
        const auto [open, openAbove, lockedAbove, where] = dockPoses(dock);

        const AdcSample pre = currentState(r);
        if (r.halted) return Stop{skill::SkillResult::Aborted, "halted"};
        if (!isTool(pre)) {
            std::string why = pre.valid && (pre.reading.state == ChangerState::kReady ||
                                            pre.reading.state == ChangerState::kNoTool)
                                  ? "no tool attached (" + describe(pre) + ")"
                                  : "the changer holds no locked tool (" + describe(pre) + ")";
            return Stop{skill::SkillResult::Failed, why};
        }
        const int toolId = pre.reading.toolId;
        {
            std::lock_guard l(mutex);
            r.tool = current.id == toolId ? ToolRecord{toolId, current.applicationUri, current.name,
                                                       current.endpoint, dock}
                                          : ToolRecord{toolId, {}, {}, {}, dock};
        }
        if (auto e = r.arm->clearTool(""); !e.empty()) return Stop{skill::SkillResult::Failed, e};
        {
            std::lock_guard l(mutex);
            r.carried =
                current.id == toolId && current.gripOffset ? *current.gripOffset : unknownTool();
        }

        beginPhase(r, "Approach");
        if (auto s = travelTo(r, lockedAbove)) return s;
        if (auto s = move(r, dock, options.dockVelocity)) {
            if (s->result == skill::SkillResult::Failed) s->message += recover(r, {lockedAbove});
            return s;
        }
        beginPhase(r, "Unlock");
        if (auto s = move(r, open, options.dockVelocity)) {
            if (s->result == skill::SkillResult::Failed)
                s->message += recover(r, {dock, lockedAbove});
            return s;
        }
        const AdcSample opened = expect(r, isReady);
        if (!isReady(opened)) {
            if (r.halted) return Stop{skill::SkillResult::Aborted, "halted"};
            std::string why =
                isTool(opened) ? "the changer did not open" + where + " (still " +
                                     describe(opened) + "): is ToolPosition this tool's dock?"
                               : "the changer did not open" + where + " (" + describe(opened) + ")";
            // Turn back (the tool stays locked on the flange) and leave.
            return Stop{skill::SkillResult::Failed, why + recover(r, {dock, lockedAbove})};
        }
        r.carried.reset();  // the tool stays in the dock (checked below)
        beginPhase(r, "Leave");
        if (auto s = move(r, openAbove, options.dockVelocity)) return s;
        endPhase(r);
        const AdcSample after = expect(r, isReady);
        std::string frame;
        {
            std::lock_guard l(mutex);
            frame = current.toolFrame;
            current = CurrentTool{};
        }
        publishTool();
        if (!frame.empty())
            if (auto e = r.arm->clearTool(frame); !e.empty()) options.log(e);
        if (!isReady(after))
            return Stop{skill::SkillResult::Failed, "after leaving the dock the changer reads " +
                                                        describe(after) +
                                                        ", expected ready: did tool " +
                                                        std::to_string(toolId) + " come along?"};
        return std::nullopt;
    }

    // ---- the skills ------------------------------------------------------------------------
    enum class Kind { Change, Attach, Detach, Drop };

    Outcome run(Kind kind, Execution& exec) {
        const ua::NodeId skillNode = skillNodes.at(static_cast<int>(kind));
        std::unique_lock busy(changeMutex, std::try_to_lock);
        if (!busy.owns_lock()) return Outcome::failed("another tool change is running");
        Run r;
        r.stop = exec.stopToken();
        const ua::Variant* position = exec.value("ToolPosition");
        const ua::Variant* uri = exec.value("ToolAppUri");
        const ua::Variant* endpoint = exec.value("MoveSkillControllerEndpoint");
        Isometry3d dock = Isometry3d::Identity();
        if (position != nullptr) {
            ua::ThreeDFrame f;
            if (!skill::server::ParamTraits<ua::ThreeDFrame>::fromVariant(*position, f) ||
                !ua::spatial::finite(f))
                return Outcome::failed("ToolPosition is not a finite ThreeDFrame");
            dock = ua::spatial::toIsometry(f);
        }
        std::string appUri;
        if (uri != nullptr)
            if (const auto* s = uri->scalar<ua::String>()) appUri = *s;
        std::string moveEndpoint;
        if (endpoint != nullptr)
            if (const auto* s = endpoint->scalar<ua::String>()) moveEndpoint = *s;

        std::string error;
        r.arm = robotArm(robotUrl(moveEndpoint), error, r.stop, options.findTimeout);
        if (!r.arm) return Outcome::failed(error);
        r.adc = adcMonitor(error, r.stop, options.findTimeout);
        if (!r.adc) return Outcome::failed(error);
        const std::string before = condition();

        std::optional<Stop> stop;
        std::string done;
        const auto started = Clock::now();
        switch (kind) {
            case Kind::Attach:
                stop = attach(r, dock, appUri);
                done = "attached";
                break;
            case Kind::Detach:
                stop = detach(r, dock);
                done = "detached";
                break;
            case Kind::Drop:
            case Kind::Change: {
                const AdcSample s = currentState(r);
                if (r.halted) {
                    stop = Stop{skill::SkillResult::Aborted, "halted"};
                    break;
                }
                syncWithAdc(s);
                std::optional<Isometry3d> from;
                CurrentTool cur;
                {
                    std::lock_guard l(mutex);
                    cur = current;
                    if (auto it = docks.find(s.reading.toolId); it != docks.end())
                        from = it->second;
                }
                if (kind == Kind::Drop) {
                    if (!isTool(s)) {
                        stop = Stop{skill::SkillResult::Failed,
                                    "no tool attached (" + describe(s) + ")"};
                    } else if (!from) {
                        stop = Stop{skill::SkillResult::Failed,
                                    "tool " + std::to_string(s.reading.toolId) +
                                        " was not attached by this component: where it came "
                                        "from is unknown (DetachTool with its ToolPosition)"};
                    } else {
                        stop = detach(r, *from);
                    }
                    done = "dropped";
                    break;
                }
                if (isTool(s)) {
                    // The tool of that dock is on the flange already ("" = whichever tool
                    // the dock held; else the one named).
                    if (from && samePose(*from, dock) &&
                        (appUri.empty() || cur.applicationUri == appUri)) {
                        r.tool =
                            ToolRecord{cur.id, cur.applicationUri, cur.name, cur.endpoint, *from};
                        done = "already attached";
                        break;
                    }
                    if (!from) {
                        stop = Stop{skill::SkillResult::Failed,
                                    "tool " + std::to_string(s.reading.toolId) +
                                        " is attached and where it came from is unknown: "
                                        "DetachTool with its ToolPosition first"};
                        break;
                    }
                    if (samePose(*from, dock)) {
                        stop = Stop{skill::SkillResult::Failed,
                                    "ToolPosition is the dock the attached tool " +
                                        std::to_string(s.reading.toolId) + " came from"};
                        break;
                    }
                    r.prefix = "Detach.";
                    stop = detach(r, *from);
                    if (stop) break;
                    r.prefix = "Attach.";
                }
                stop = attach(r, dock, appUri);
                done = "changed to tool";
                break;
            }
        }
        endPhase(r);
        const double total = std::chrono::duration<double>(Clock::now() - started).count();
        {
            std::lock_guard l(mutex);
            phases = r.phases;
        }
        std::vector<ua::String> names;
        std::vector<double> seconds;
        std::string phaseText;
        for (const auto& p : r.phases) {
            names.push_back(p.name);
            seconds.push_back(p.seconds);
            phaseText += (phaseText.empty() ? "" : ", ") + p.name + " " + formatSeconds(p.seconds);
        }
        const bool halted = r.halted || (stop && stop->result == skill::SkillResult::Aborted);
        if (halted) {
            // The robot is at rest now; what the changer reads reaches us through the board's
            // poll and the subscription: give it a few notifications (bounded).
            const std::uint64_t seen = r.adc->latest().updates;
            (void)r.adc->waitFor([seen](const AdcSample& s) { return s.updates >= seen + 6; },
                                 std::min<std::chrono::milliseconds>(options.settleTimeout, 200ms));
        }
        const AdcSample now = r.adc->latest();
        syncWithAdc(now);
        if (halted) {
            std::string report = "halted during " +
                                 (r.phase.empty() && !r.phases.empty() ? r.phases.back().name
                                                                       : std::string("the start")) +
                                 " at the dock " + ua::spatial::positionText(r.dock) +
                                 ": changer " + describe(now);
            if (!now.valid || now.reading.state == ChangerState::kIntermediate)
                report +=
                    ": the tool may be half locked; turn the changer back by hand or run "
                    "AttachTool / DetachTool at this dock";
            setCondition(report);
            writeFinalMessage(skillNode, report);
            options.log(report);
            return withTool(Outcome::aborted(report)
                                .with("Phases", ua::Variant(names))
                                .with("PhaseDurations", ua::Variant(seconds)),
                            r.tool);
        }
        if (stop) {
            if (!before.empty()) stop->message += " (earlier: " + before + ")";
            options.log("failed: " + stop->message + (phaseText.empty() ? "" : "; " + phaseText));
            return withTool(Outcome::failed(stop->message)
                                .with("Phases", ua::Variant(names))
                                .with("PhaseDurations", ua::Variant(seconds)),
                            r.tool);
        }
        setCondition("");
        CurrentTool cur;
        {
            std::lock_guard l(mutex);
            cur = current;
        }
        std::string message = done;
        if (kind == Kind::Change || kind == Kind::Attach)
            message += " " + std::to_string(cur.id) +
                       (cur.name.empty() ? "" : " (" + cur.name + ", " + cur.applicationUri + ")");
        message += " in " + formatSeconds(total) + (phaseText.empty() ? "" : ": " + phaseText);
        options.log(message);
        return withTool(Outcome::completed(message)
                            .with("Phases", ua::Variant(names))
                            .with("PhaseDurations", ua::Variant(seconds)),
                        r.tool);
    }

    // FinalResultData's tool (IToolChangeResultType): every run writes all five, so that
    // nothing of an earlier run's tool stays there (0 / "" / null: none).
    static Outcome withTool(Outcome o, const ToolRecord& t) {
        o.with("ToolAppUri", ua::Variant(ua::String(t.applicationUri)))
            .with("ToolName", ua::Variant(ua::String(t.name)))
            .with("ToolEndpoint", ua::Variant(ua::String(t.endpoint)))
            .with("ToolId", ua::Variant(ua::Int32{t.id}))
            .with("ToolPosition", t.dock ? skill::server::ParamTraits<ua::ThreeDFrame>::toVariant(
                                               ua::spatial::toFrame(*t.dock))
                                         : ua::Variant());
        return o;
    }

    // FinalResultData/Message of the halted skill: Halt set it at once ("halted"); what the
    // halt left behind is known once the robot is at rest (the Reset waits for that).
    void writeFinalMessage(const ua::NodeId& skillNode, const std::string& text) {
        auto& space = server.addressSpace();
        const ua::QualifiedName path[] = {ua::QualifiedName(0, "FinalResultData"),
                                          ua::QualifiedName(baseNs, "Message")};
        if (auto id = space.resolvePath(skillNode, path))
            (void)space.setValue(*id, ua::DataValue(ua::Variant(ua::String(text))));
    }
    std::map<int, ua::NodeId> skillNodes;  // by Kind (set before the server starts)
    ua::NodeId node;                       // DeviceSet/<name>

    std::string condition() const {
        std::lock_guard l(mutex);
        return conditionText;
    }
};

namespace {

std::shared_ptr<skill::server::Skill> makeToolSkill(
    std::weak_ptr<ToolChangerComponent::Impl> weak, skill::ModelNode type, int kind,
    std::vector<skill::server::ParameterDeclaration> params) {
    using skill::server::SkillCallbacks;
    SkillCallbacks cb;
    cb.execute = [weak, kind](Execution& exec) -> Outcome {
        auto impl = weak.lock();
        if (!impl) return Outcome::failed("the component is shutting down");
        return impl->run(static_cast<ToolChangerComponent::Impl::Kind>(kind), exec);
    };
    cb.reset = [weak]() -> ua::StatusCode {
        if (auto impl = weak.lock()) {
            const std::string c = impl->condition();
            if (!c.empty()) impl->options.log("reset; the changer was left: " + c);
        }
        return {};
    };
    return skill::server::makeSkill(type, std::move(params), std::move(cb));
}

}  // namespace

ToolChangerComponent::ToolChangerComponent(ua::server::Server& server, ToolChangerOptions options,
                                           mdns::Mdns* mdns)
    : impl_(std::make_shared<Impl>(server, std::move(options))) {
    Impl& m = *impl_;
    auto& space = server.addressSpace();
    skill::server::loadSkillModels(space, {skill::kBaseUri, skill::kToolChangerUri});
    m.baseNs = *space.namespaceIndex(skill::kBaseUri);
    const ua::UInt16 tc = *space.namespaceIndex(skill::kToolChangerUri);
    m.controller = std::make_unique<skill::server::SkillController>(
        server, skill::server::SkillControllerOptions{.name = m.options.name,
                                                      .type = types::ToolChangerType});
    const ua::NodeId node = m.controller->node();
    m.node = node;
    auto child = [&](std::initializer_list<const char*> names) {
        std::vector<ua::QualifiedName> path;
        for (const char* n : names) path.emplace_back(tc, n);
        auto id = space.resolvePath(node, path);
        if (!id)
            throw skill::server::SkillError(std::string("ToolChangerType instance without ") +
                                            *(names.end() - 1));
        return *id;
    };
    m.hasToolNode = child({"HasTool"});
    m.toolIdNode = child({"CurrentTool", "Id"});
    m.toolDescriptionNode = child({"CurrentTool", "Description"});
    m.toolEndpointNode = child({"CurrentTool", "Endpoint"});
    m.toolUriNode = child({"CurrentTool", "ApplicationUri"});
    m.conditionNode = child({"Condition"});
    m.publishTool();

    using skill::server::declareParameter;
    auto frame = [] { return declareParameter<ua::ThreeDFrame>("ToolPosition"); };
    auto uri = [] { return declareParameter<ua::String>("ToolAppUri", ""); };
    auto endpoint = [] { return declareParameter<ua::String>("MoveSkillControllerEndpoint", ""); };
    using K = Impl::Kind;
    std::weak_ptr<Impl> weak = impl_;
    auto add = [&](const char* name, const skill::ModelNode& type, K kind,
                   std::vector<skill::server::ParameterDeclaration> params) {
        const int k = static_cast<int>(kind);
        m.skillNodes[k] =
            m.controller->add(name, makeToolSkill(weak, type, k, std::move(params))).node();
    };
    add(skill_names::ChangeTool, skill::types::ChangeToolSkillType, K::Change,
        {frame(), uri(), endpoint()});
    add(skill_names::AttachTool, skill::types::AttachToolSkillType, K::Attach,
        {frame(), uri(), endpoint()});
    add(skill_names::DetachTool, skill::types::DetachToolSkillType, K::Detach,
        {frame(), endpoint()});
    add(skill_names::DropTool, types::DropToolSkillType, K::Drop, {});
    m.detector = std::make_unique<skill::detector::SkillDetector>(mdns, m.options.detector);
    m.detector->onChange(
        [appearances = m.appearances](const skill::detector::DetectedSkill& s, bool added) {
            if (added) appearances->added(serverKey(s));
        });
}

ToolChangerComponent::~ToolChangerComponent() { stop(); }

void ToolChangerComponent::start() {
    impl_->detector->start();
    if (impl_->options.robot != "auto" && !impl_->options.robot.empty())
        impl_->detector->addServer(impl_->options.robot);
}

void ToolChangerComponent::stop() {
    if (impl_->controller) impl_->controller.reset();  // halts a running change, joins it
    impl_->detector->stop();
    std::lock_guard l(impl_->mutex);
    impl_->arm.reset();
    impl_->adc.reset();
}

std::string ToolChangerComponent::waitReady(std::chrono::milliseconds timeout) {
    std::string error;
    auto arm = impl_->robotArm(impl_->robotUrl(""), error, {}, timeout);
    std::shared_ptr<AdcMonitor> adc;
    if (arm) adc = impl_->adcMonitor(error, {}, timeout);
    if (!arm || !adc) return error;
    if (auto s = adc->waitFor([](const AdcSample& s) { return s.valid; }, timeout); s)
        impl_->syncWithAdc(*s);
    return {};
}

skill::detector::SkillDetector& ToolChangerComponent::detector() { return *impl_->detector; }
const ua::NodeId& ToolChangerComponent::node() const { return impl_->node; }
std::vector<skill::server::SkillHandle> ToolChangerComponent::skills() const {
    if (!impl_->controller) return {};
    return impl_->controller->skills();
}
std::string ToolChangerComponent::condition() const { return impl_->condition(); }
std::vector<PhaseTime> ToolChangerComponent::lastPhases() const {
    std::lock_guard l(impl_->mutex);
    return impl_->phases;
}

}  // namespace pnp::component::toolchanger
