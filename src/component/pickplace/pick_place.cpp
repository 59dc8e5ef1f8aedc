#include "component/pickplace/pick_place.hpp"

#include <condition_variable>
#include <cstdio>
#include <deque>
#include <iostream>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <stdexcept>
#include <stop_token>
#include <thread>

#include "component/pickplace/knowledge.hpp"
#include "skill/client/typed_clients.hpp"
#include "ua/client/client.hpp"
#include "ua/discovery/watcher.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"

namespace pnp::component::pickplace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using Eigen::Isometry3d;
using skill::ProgramState;
using skill::server::Execution;
using skill::server::Outcome;
namespace client = skill::client;

namespace {

double unixSeconds(const ua::DateTime& t) { return static_cast<double>(t.toUnixNanos()) * 1e-9; }

// A lower skill on another component's server, kept across runs (its subscription too).
struct Lower {
    std::string endpoint;   // the server's URL
    std::string component;  // its ApplicationName (else the URL)
    std::string name;       // the skill's BrowseName
    std::unique_ptr<client::SkillClient> skill;
    std::string label() const { return name + "@" + endpoint; }
};

// What the detector found for a run.
struct Robot {
    skill::detector::DetectedSkill move;
};
struct Tool {
    skill::detector::DetectedSkill grasp, release;
    GripPoint grip;
    std::string frameName;  // the name the tool changer gave the robot's tool frame
};

// One lower skill run of the sequence.
struct StepDef {
    std::string name;
    std::shared_ptr<Lower> lower;
    client::NamedValues params;
    std::chrono::milliseconds timeout{};
};

struct StepEnd {
    skill::SkillResult result = skill::SkillResult::None;
    std::string message;
    ua::DateTime start, end;
};

enum class Control { Suspend, Resume };

}  // namespace

struct PickPlaceComponent::Impl : std::enable_shared_from_this<Impl> {
    ua::server::Server& server;
    PickPlaceOptions options;
    std::unique_ptr<skill::detector::SkillDetector> detector;
    std::unique_ptr<skill::server::SkillController> controller;
    ua::NodeId node, skillNode;

    std::mutex runMutex;  // one PickAndPlace at a time

    // Lower skills' transitions and the Suspend / Resume requests, for the run's thread.
    std::mutex eventMutex;
    std::condition_variable_any eventCv;
    std::deque<std::pair<const client::SkillClient*, client::Transition>> events;
    std::deque<Control> controls;

    mutable std::mutex mutex;                                            // the members below
    std::map<std::string, std::shared_ptr<ua::client::Client>> clients;  // by URL
    std::map<std::string, std::shared_ptr<Lower>> lowers;                // by URL + node
    std::vector<StepRecord> last;

    Impl(ua::server::Server& s, PickPlaceOptions o) : server(s), options(std::move(o)) {
        if (!options.log)
            options.log = [](const std::string& line) {
                std::cerr << "pnp component pick-place: " << line << std::endl;
            };
    }

    // ---- connections -------------------------------------------------------------------
    std::shared_ptr<ua::client::Client> clientFor(const std::string& url) {
        {
            std::lock_guard l(mutex);
            if (auto it = clients.find(url); it != clients.end()) return it->second;
        }
        ua::client::ClientConfig cc;
        cc.applicationName = "pnp pick-place";
        cc.applicationUri = "urn:pnp:component:pickplace:client";
        cc.requestTimeout = options.requestTimeout;
        cc.connectTimeout = options.requestTimeout;
        auto c = std::make_shared<ua::client::Client>(cc);
        c->connect(url);
        std::lock_guard l(mutex);
        return clients.emplace(url, c).first->second;
    }

    // Forgets a server's connection and skills (it failed: the next run connects anew).
    void forget(const std::string& url) {
        std::shared_ptr<ua::client::Client> c;
        std::vector<std::shared_ptr<Lower>> gone;
        {
            std::lock_guard l(mutex);
            if (auto it = clients.find(url); it != clients.end()) {
                c = it->second;
                clients.erase(it);
            }
            for (auto it = lowers.begin(); it != lowers.end();)
                if (it->second->endpoint == url) {
                    gone.push_back(it->second);
                    it = lowers.erase(it);
                } else {
                    ++it;
                }
        }
        gone.clear();
        if (c) c->stopBackgroundThread();
    }

    std::shared_ptr<Lower> lowerFor(const skill::detector::DetectedSkill& s) {
        const std::string key = s.endpointUrl + " " + s.nodeText;
        {
            std::lock_guard l(mutex);
            if (auto it = lowers.find(key); it != lowers.end()) return it->second;
        }
        auto c = clientFor(s.endpointUrl);
        auto lower = std::make_shared<Lower>();
        lower->endpoint = s.endpointUrl;
        lower->component = s.componentName.empty() ? s.endpointUrl : s.componentName;
        lower->name = s.name;
        client::SkillClientOptions so;
        so.lockContext = "pnp pick-place";
        lower->skill = std::make_unique<client::SkillClient>(
            c, s.node, client::Deadline(Clock::now() + options.requestTimeout), so);
        // Transitions go to the run's queue (the client's dispatching thread: no blocking).
        std::weak_ptr<Impl> weak = weak_from_this();
        const client::SkillClient* from = lower->skill.get();
        lower->skill->onTransition(
            [weak, from](const client::Transition& t) {
                auto self = weak.lock();
                if (!self) return;
                {
                    std::lock_guard l(self->eventMutex);
                    self->events.emplace_back(from, t);
                    while (self->events.size() > 1000) self->events.pop_front();
                }
                self->eventCv.notify_all();
            },
            client::Deadline(Clock::now() + options.requestTimeout));
        std::lock_guard l(mutex);
        return lowers.emplace(key, lower).first->second;
    }

    // ---- finding the robot and the tool -------------------------------------------------
    // The robot's CartesianLinearMove ("" = the only robot), within findTimeout.
    std::optional<Robot> findRobot(const std::string& endpoint, std::string& error,
                                   std::stop_token stop) {
        const std::string wanted = endpoint.empty() ? "" : ua::discovery::normaliseUrl(endpoint);
        if (!endpoint.empty()) detector->addServer(endpoint);
        const auto end = Clock::now() + options.findTimeout;
        while (!stop.stop_requested()) {
            std::map<std::string, skill::detector::DetectedSkill> robots;  // by ApplicationUri
            for (auto& s : detector->find(skill::types::CartesianLinearMoveSkillType)) {
                const std::string u = ua::discovery::normaliseUrl(s.endpointUrl);
                if (!wanted.empty() && u != wanted) continue;
                robots.emplace(s.componentUri.empty() ? u : s.componentUri, s);
            }
            if (robots.size() > 1) {
                error = "several robots offer CartesianLinearMove (";
                for (const auto& [uri, s] : robots)
                    error += (error.back() == '(' ? "" : ", ") + s.componentName + " at " +
                             s.endpointUrl;
                error += "): name one in MoveSkillControllerEndpoint";
                return std::nullopt;
            }
            if (robots.size() == 1) return Robot{robots.begin()->second};
            if (Clock::now() >= end) break;
            detector->waitUntil(
                [](const skill::detector::SkillDetector& d) {
                    return !d.find(skill::types::CartesianLinearMoveSkillType).empty();
                },
                50ms);
        }
        error = wanted.empty() ? "no robot with a CartesianLinearMove skill detected"
                               : "no CartesianLinearMove skill detected at " + endpoint;
        return std::nullopt;
    }

    // The gripper with Grasp and Release ("" = the only one detected), within findTimeout.
    std::optional<Tool> findTool(const std::string& endpoint, std::string& error,
                                 std::stop_token stop) {
        const std::string wanted = endpoint.empty() ? "" : ua::discovery::normaliseUrl(endpoint);
        if (!endpoint.empty()) detector->addServer(endpoint);
        const auto end = Clock::now() + options.findTimeout;
        struct Candidate {
            std::optional<skill::detector::DetectedSkill> grasp, release;
        };
        while (!stop.stop_requested()) {
            // By component (ApplicationUri, else URL) and controller.
            std::map<std::string, Candidate> tools;
            auto keyOf = [](const skill::detector::DetectedSkill& s) {
                return (s.componentUri.empty() ? ua::discovery::normaliseUrl(s.endpointUrl)
                                               : s.componentUri) +
                       " " + s.controller.toString();
            };
            for (auto& s : detector->find(skill::types::GraspGripperSkillType))
                if (wanted.empty() || ua::discovery::normaliseUrl(s.endpointUrl) == wanted)
                    if (!tools[keyOf(s)].grasp) tools[keyOf(s)].grasp = s;
            for (auto& s : detector->find(skill::types::ReleaseGripperSkillType))
                if (wanted.empty() || ua::discovery::normaliseUrl(s.endpointUrl) == wanted)
                    if (!tools[keyOf(s)].release) tools[keyOf(s)].release = s;
            std::vector<Candidate> complete;
            for (auto& [k, c] : tools)
                if (c.grasp && c.release) complete.push_back(c);
            if (complete.size() > 1) {
                error = "several grippers offer Grasp and Release (";
                for (const auto& c : complete)
                    error += (error.back() == '(' ? "" : ", ") + c.grasp->componentName + " at " +
                             c.grasp->endpointUrl;
                error += "): name one in ToolSkillControllerEndpoint";
                return std::nullopt;
            }
            if (complete.size() == 1) {
                Tool t;
                t.grasp = *complete.front().grasp;
                t.release = *complete.front().release;
                t.frameName = t.grasp.componentName;
                if (!readGripPoint(t, error)) return std::nullopt;
                return t;
            }
            if (Clock::now() >= end) break;
            detector->waitUntil(
                [](const skill::detector::SkillDetector& d) {
                    return !d.find(skill::types::GraspGripperSkillType).empty();
                },
                50ms);
        }
        error = wanted.empty()
                    ? "no gripper with Grasp and Release skills detected (is a tool attached?)"
                    : "no gripper with Grasp and Release skills detected at " + endpoint;
        return std::nullopt;
    }

    // GripPoints/GripPoint_1 (else the first GripPoint_*) of the tool's controller.
    bool readGripPoint(Tool& t, std::string& error) {
        const std::string who = t.grasp.componentName + " at " + t.grasp.endpointUrl;
        try {
            auto c = clientFor(t.grasp.endpointUrl);
            const auto deadline = ua::client::Deadline(Clock::now() + options.requestTimeout);
            auto childNamed = [&](const ua::NodeId& parent, const std::string& name,
                                  bool anyGripPoint) -> std::optional<ua::NodeId> {
                std::optional<ua::NodeId> first;
                for (const auto& r : c->browse(parent, {}, deadline)) {
                    if (r.nodeId.serverIndex != 0) continue;
                    if (r.browseName.name == name) return r.nodeId.nodeId;
                    if (anyGripPoint && !first && r.browseName.name.starts_with("GripPoint_"))
                        first = r.nodeId.nodeId;
                }
                return first;
            };
            auto points = childNamed(t.grasp.controller, "GripPoints", false);
            auto point = points ? childNamed(*points, "GripPoint_1", true) : std::nullopt;
            if (!point) {
                error = "the tool " + who + " has no IGripperType grip point (GripPoints)";
                return false;
            }
            auto type = childNamed(*point, "Type", false);
            auto offset = childNamed(*point, "Offset", false);
            auto span = childNamed(*point, "Span", false);
            if (!type || !offset) {
                error = "the grip point of " + who + " has no Type / Offset";
                return false;
            }
            const ua::Variant tv = c->readValue(*type, deadline);
            const ua::Variant ov = c->readValue(*offset, deadline);
            std::optional<ua::Int32> kind;
            if (const auto* k = tv.scalar<ua::Int32>()) kind = *k;
            if (const auto* k = tv.scalar<ua::UInt32>()) kind = static_cast<ua::Int32>(*k);
            if (!kind || (*kind != 0 && *kind != 1)) {
                error = "the grip point Type of " + who +
                        " is not Parallel (0) / Vacuum (1): " + tv.toString();
                return false;
            }
            t.grip.kind = *kind == 1 ? GripKind::Vacuum : GripKind::Parallel;
            const auto* ox = ov.scalar<ua::ExtensionObject>();
            auto of = ox ? ua::fromExtensionObject<ua::ThreeDFrame>(*ox) : std::nullopt;
            if (!of || !ua::spatial::finite(*of)) {
                error = "the grip point Offset of " + who + " is not a finite ThreeDFrame";
                return false;
            }
            t.grip.offset = ua::spatial::toIsometry(*of);
            if (t.grip.kind == GripKind::Parallel) {
                std::optional<ua::Range> range;
                if (span) {
                    const ua::Variant sv = c->readValue(*span, deadline);
                    if (const auto* sx = sv.scalar<ua::ExtensionObject>())
                        range = ua::fromExtensionObject<ua::Range>(*sx);
                }
                if (!range || !std::isfinite(range->low) || !std::isfinite(range->high) ||
                    range->high <= 0) {
                    error = "the parallel grip point of " + who + " has no valid Span";
                    return false;
                }
                t.grip.spanLow = range->low;
                t.grip.spanHigh = range->high;
            }
            t.grip.name = "GripPoint_1";
            return true;
        } catch (const std::exception& e) {
            forget(t.grasp.endpointUrl);
            error = "reading the grip point of " + who + ": " + e.what();
            return false;
        }
    }

    // ---- running the lower skills --------------------------------------------------------
    struct Run {
        Execution* exec = nullptr;
        std::stop_token stop;
        std::vector<std::shared_ptr<Lower>> locked;
        std::vector<StepRecord> records;
        Clock::time_point nextRenew;
        bool halted = false;
    };

    void pushControl(Control c) {
        {
            std::lock_guard l(eventMutex);
            controls.push_back(c);
        }
        eventCv.notify_all();
    }

    void renewLocks(Run& r) {
        if (Clock::now() < r.nextRenew) return;
        for (auto& l : r.locked) try {
                l->skill->renewLock(ua::client::Deadline(Clock::now() + options.requestTimeout));
            } catch (const std::exception& e) {
                options.log("renewing the lock of " + l->label() + ": " + e.what());
            }
        r.nextRenew = Clock::now() + lockRenewPeriod(r);
    }
    std::chrono::milliseconds lockRenewPeriod(const Run& r) const {
        auto t = std::chrono::milliseconds(10000);
        for (const auto& l : r.locked) t = std::min(t, l->skill->lockTime());
        return std::max<std::chrono::milliseconds>(t / 3, 50ms);
    }

    // Locks each lower skill once for the whole run; resets a Halted one. "" or why not.
    std::string prepare(Run& r, const std::vector<std::shared_ptr<Lower>>& all) {
        for (const auto& l : all) {
            if (std::find(r.locked.begin(), r.locked.end(), l) != r.locked.end()) continue;
            const auto end = Clock::now() + options.findTimeout;
            bool got = false;
            for (auto backoff = 5ms; !r.stop.stop_requested();
                 backoff = std::min(backoff * 2, 200ms)) {
                got = l->skill->lock("pnp pick-place",
                                     ua::client::Deadline(Clock::now() + options.requestTimeout));
                if (got || Clock::now() + backoff >= end) break;
                std::this_thread::sleep_for(backoff);
            }
            if (!got) return l->name + " on " + l->component + " is locked by another client";
            r.locked.push_back(l);
            const auto d = ua::client::Deadline(Clock::now() + options.requestTimeout);
            const ProgramState s = l->skill->state(d);
            if (s == ProgramState::Halted) {
                // The robot's Reset waits until the arm is at rest (after a halt).
                l->skill->reset(ua::client::Deadline(Clock::now() + options.moveTimeout));
            } else if (s != ProgramState::Ready) {
                return l->name + " on " + l->component + " is " + std::string(skill::toString(s)) +
                       ", not Ready";
            }
        }
        r.nextRenew = Clock::now() + lockRenewPeriod(r);
        return {};
    }

    void unlockAll(Run& r) {
        for (auto& l : r.locked) try {
                l->skill->unlock(ua::client::Deadline(Clock::now() + options.requestTimeout));
            } catch (const std::exception&) {
                // the lock expires on its own
            }
        r.locked.clear();
    }

    // Waits for the end of the run of `lower` started just before; forwards Suspend / Resume;
    // halts it on the composite's Halt or the timeout.
    StepEnd waitEnd(Run& r, Lower& lower, std::chrono::milliseconds timeout) {
        StepEnd out;
        const auto started = Clock::now();
        const auto deadline = started + timeout;
        auto nextPoll = started + 1s;
        bool running = false;
        const client::SkillClient* me = lower.skill.get();
        auto req = [&] { return ua::client::Deadline(Clock::now() + options.requestTimeout); };
        std::stop_callback wake(r.stop, [this] { eventCv.notify_all(); });
        for (;;) {
            std::vector<client::Transition> mine;
            std::vector<Control> ctl;
            {
                std::unique_lock l(eventMutex);
                eventCv.wait_until(l, std::min({deadline, r.nextRenew, nextPoll}), [&] {
                    return !events.empty() || !controls.empty() || r.stop.stop_requested();
                });
                for (auto& [from, t] : events)
                    if (from == me) mine.push_back(std::move(t));
                events.clear();
                ctl.assign(controls.begin(), controls.end());
                controls.clear();
            }
            for (const auto& t : mine) {
                if (t.from == ProgramState::Ready && t.to == ProgramState::Running) {
                    running = true;
                    out.start = t.time;
                    continue;
                }
                if (running && (t.to == ProgramState::Ready || t.to == ProgramState::Halted) &&
                    (t.from == ProgramState::Running || t.from == ProgramState::Suspended)) {
                    out.end = t.time;
                    out.result = t.to == ProgramState::Ready ? skill::SkillResult::Completed
                                                             : skill::SkillResult::Failed;
                    out.message = t.message;
                    if (out.result != skill::SkillResult::Completed) {
                        try {
                            const auto f = lower.skill->finalResult(req());
                            if (f.result != skill::SkillResult::None) out.result = f.result;
                            if (!f.message.empty()) out.message = f.message;
                        } catch (const std::exception&) {
                            // the event's message stands
                        }
                    }
                    return out;
                }
            }
            for (Control c : ctl) try {
                    if (c == Control::Suspend)
                        lower.skill->suspend(req());
                    else
                        lower.skill->resume(req());
                } catch (const std::exception& e) {
                    options.log(std::string(c == Control::Suspend ? "Suspend" : "Resume") + " of " +
                                lower.label() + ": " + e.what());
                }
            const auto now = Clock::now();
            if (r.stop.stop_requested() || now >= deadline) {
                const bool halted = r.stop.stop_requested();
                try {
                    lower.skill->halt(req());
                } catch (const std::exception&) {
                    // BadInvalidState: it ended meanwhile
                }
                r.halted = r.halted || halted;
                out.result = halted ? skill::SkillResult::Aborted : skill::SkillResult::Failed;
                out.message = halted ? "halted"
                                     : "did not end within " + std::to_string(timeout.count()) +
                                           " ms (halted)";
                out.end = ua::DateTime::now();
                return out;
            }
            renewLocks(r);
            if (now >= nextPoll) {  // a lost event: the state says it ended
                nextPoll = now + 1s;
                try {
                    const ProgramState s = lower.skill->state(req());
                    if (s == ProgramState::Ready || s == ProgramState::Halted) {
                        const auto f = lower.skill->finalResult(req());
                        if (f.result != skill::SkillResult::None) {
                            out.result = f.result;
                            out.message = f.message;
                            out.end = ua::DateTime::now();
                            if (out.start == ua::DateTime{}) out.start = out.end;
                            return out;
                        }
                    }
                } catch (const std::exception& e) {
                    options.log("polling " + lower.label() + ": " + e.what());
                }
            }
        }
    }

    // Runs the steps in order; each next one's parameters are written while the one before
    // runs. Returns the index of the step that did not complete (steps.size(): all did) and
    // its end.
    std::pair<std::size_t, StepEnd> runSteps(Run& r, std::vector<StepDef>& stepList) {
        std::vector<bool> written(stepList.size(), false);
        auto req = [&] { return ua::client::Deadline(Clock::now() + options.requestTimeout); };
        for (std::size_t i = 0; i < stepList.size(); ++i) {
            StepDef& s = stepList[i];
            StepEnd end;
            if (!r.exec->checkpoint()) {  // Suspended between steps: wait; a Halt ends it
                r.halted = true;
                end.result = skill::SkillResult::Aborted;
                end.message = "halted";
                return {i, end};
            }
            r.exec->progress(ua::Variant(ua::String(s.name)));
            r.exec->progress(ua::Variant(
                std::vector<ua::String>{ua::String(s.name), ua::String(s.lower->label())}));
            try {
                if (!written[i] && !s.params.empty())
                    s.lower->skill->setParameters(s.params, req());
                {
                    std::lock_guard l(eventMutex);  // events of earlier runs are history
                    std::erase_if(events,
                                  [&](const auto& e) { return e.first == s.lower->skill.get(); });
                }
                s.lower->skill->start(req());
            } catch (const std::exception& e) {
                end.result = skill::SkillResult::Failed;
                end.message = std::string("Start refused: ") + e.what();
                end.start = end.end = ua::DateTime::now();
                record(r, s, end);
                return {i, end};
            }
            // Prepare the next one now: its parameters are taken at its own Start.
            if (i + 1 < stepList.size() && !stepList[i + 1].params.empty()) try {
                    stepList[i + 1].lower->skill->setParameters(stepList[i + 1].params, req());
                    written[i + 1] = true;
                } catch (const std::exception& e) {
                    options.log("writing the parameters of " + stepList[i + 1].name +
                                " early: " + e.what());
                }
            end = waitEnd(r, *s.lower, s.timeout);
            record(r, s, end);
            if (end.result != skill::SkillResult::Completed) return {i, end};
        }
        return {stepList.size(), {}};
    }

    void record(Run& r, const StepDef& s, const StepEnd& end) {
        StepRecord rec;
        rec.step = s.name;
        rec.skill = s.lower->label();
        rec.startUnixS = unixSeconds(end.start);
        rec.endUnixS = unixSeconds(end.end);
        if (!r.records.empty())
            rec.overheadMs = (rec.startUnixS - r.records.back().endUnixS) * 1000.0;
        rec.result = std::string(skill::toString(end.result));
        r.records.push_back(std::move(rec));
    }

    StepDef moveStep(const std::string& name, const std::shared_ptr<Lower>& move,
                     const Isometry3d& target, const std::vector<double>& velocity,
                     const std::string& toolFrame) {
        client::CartesianMove m;
        m.target = ua::spatial::toFrame(target);
        m.maxVelocity = velocity;
        m.toolFrame = toolFrame;
        return {name, move, client::parametersOf(m), options.moveTimeout};
    }

    // ---- the skill ---------------------------------------------------------------------------
    Outcome run(Execution& exec) {
        std::unique_lock busy(runMutex, std::try_to_lock);
        if (!busy.owns_lock()) return Outcome::failed("another PickAndPlace is running");
        Run r;
        r.exec = &exec;
        r.stop = exec.stopToken();
        {
            std::lock_guard l(eventMutex);
            controls.clear();
        }
        exec.progress(ua::Variant(ua::String(steps::Init)));
        auto text = [&](const char* name) {
            std::string v;
            if (const ua::Variant* p = exec.value(name))
                if (const auto* s = p->scalar<ua::String>()) v = *s;
            return v;
        };
        const std::string objectId = text("ObjectId");
        const std::string toolEndpoint = text("ToolSkillControllerEndpoint");
        const std::string moveEndpoint = text("MoveSkillControllerEndpoint");
        ua::ThreeDFrame placeFrame;
        const ua::Variant* pv = exec.value("PlacePosition");
        if (pv == nullptr ||
            !skill::server::ParamTraits<ua::ThreeDFrame>::fromVariant(*pv, placeFrame) ||
            !ua::spatial::finite(placeFrame))
            return finish(r, Outcome::failed("PlacePosition is not a finite ThreeDFrame"));
        const Isometry3d place = ua::spatial::toIsometry(placeFrame);

        // The object, from the world model.
        std::string error;
        std::optional<ObjectInfo> object;
        {
            const auto deadline = Clock::now() + options.requestTimeout;
            object = lookupObject(*options.knowledge, objectId, deadline, error);
        }
        if (!object) return finish(r, Outcome::failed(error));
        auto robot = findRobot(moveEndpoint, error, r.stop);
        if (!robot) return finish(r, Outcome::failed(error));
        auto tool = findTool(toolEndpoint, error, r.stop);
        if (!tool) return finish(r, Outcome::failed(error));
        const auto plan = planPickAndPlace(*object, tool->grip, place, options.plan, error);
        if (!plan)
            return finish(r, Outcome::failed("refused before any motion: " + error + " (" +
                                             tool->grasp.componentName + ", " +
                                             toString(tool->grip.kind) + " grip)"));
        std::shared_ptr<Lower> move, grasp, release;
        try {
            move = lowerFor(robot->move);
        } catch (const std::exception& e) {
            forget(robot->move.endpointUrl);
            return finish(
                r, Outcome::failed("the robot at " + robot->move.endpointUrl + ": " + e.what()));
        }
        try {
            grasp = lowerFor(tool->grasp);
            release = lowerFor(tool->release);
        } catch (const std::exception& e) {
            forget(tool->grasp.endpointUrl);
            return finish(
                r, Outcome::failed("the tool at " + tool->grasp.endpointUrl + ": " + e.what()));
        }
        try {
            if (auto why = prepare(r, {move, grasp, release}); !why.empty()) {
                unlockAll(r);
                return finish(r, Outcome::failed(why));
            }
        } catch (const std::exception& e) {
            unlockAll(r);
            forget(robot->move.endpointUrl);
            forget(tool->grasp.endpointUrl);
            return finish(r,
                          Outcome::failed(std::string("preparing the lower skills: ") + e.what()));
        }

        const std::string frame = tool->frameName;
        std::vector<StepDef> seq;
        // A parallel gripper opens first (it may have closed on nothing before).
        if (tool->grip.kind == GripKind::Parallel)
            seq.push_back({steps::Init, release, {}, options.gripperTimeout});
        seq.push_back(moveStep(steps::MovePickApproachBefore, move, plan->pickApproach,
                               options.travelVelocity, frame));
        seq.push_back(moveStep(steps::MovePick, move, plan->pick, options.nearVelocity, frame));
        seq.push_back({steps::Grasp, grasp, {}, options.gripperTimeout});
        seq.push_back(moveStep(steps::MovePickApproachAfter, move, plan->pickApproach,
                               options.nearVelocity, frame));
        seq.push_back(moveStep(steps::MovePlaceApproachBefore, move, plan->placeApproach,
                               options.travelVelocity, frame));
        seq.push_back(moveStep(steps::MovePlace, move, plan->place, options.nearVelocity, frame));
        seq.push_back({steps::Release, release, {}, options.gripperTimeout});
        seq.push_back(moveStep(steps::MovePlaceApproachAfter, move, plan->placeApproach,
                               options.nearVelocity, frame));
        options.log("PickAndPlace " + objectId + " from " +
                    ua::spatial::positionText(object->pose) + " to " +
                    ua::spatial::positionText(plan->objectAtPlace) + " with " +
                    tool->grasp.componentName + " (" + toString(tool->grip.kind) + ") and " +
                    robot->move.componentName);

        auto [failedAt, end] = runSteps(r, seq);
        if (failedAt == seq.size()) {
            unlockAll(r);
            std::string message =
                "placed " + objectId + " at " + ua::spatial::positionText(plan->objectAtPlace);
            try {
                storeObjectPose(*options.knowledge, objectId, plan->objectAtPlace,
                                Clock::now() + options.requestTimeout);
            } catch (const std::exception& e) {
                message += "; the knowledge base was NOT updated: " + std::string(e.what());
            }
            exec.progress(ua::Variant(ua::String(steps::Idle)));
            return finish(r, Outcome::completed(message + "; " + overheadSummary(r)));
        }
        const StepDef& failed = seq[failedAt];
        if (end.result == skill::SkillResult::Aborted || r.halted) {
            unlockAll(r);
            const std::string why =
                "halted during " + failed.name + " (" + failed.lower->label() + " halted)";
            options.log(why);
            return finish(r, Outcome::aborted(why));
        }
        std::string why =
            failed.lower->name + " on " + failed.lower->component + " failed: " + end.message;
        if (end.message.find("is not a tool frame") != std::string::npos)
            why +=
                " (the robot's tool frame is not the gripper's grip point: attach the tool "
                "with the tool changer, which sets it)";
        why += " (step " + failed.name + ")";
        // Back up to the approach pose of where it failed (after a failed grasp: up first).
        const bool atPick = failed.name == steps::MovePick || failed.name == steps::Grasp;
        const bool atPlace = failed.name == steps::MovePlace || failed.name == steps::Release;
        if (atPick || atPlace) {
            std::vector<StepDef> back{moveStep(
                atPick ? steps::MovePickApproachAfter : steps::MovePlaceApproachAfter, move,
                atPick ? plan->pickApproach : plan->placeApproach, options.nearVelocity, frame)};
            auto [at, e] = runSteps(r, back);
            if (at != back.size())
                why += "; moving back up to the approach pose: " + e.message;
            else
                why += "; the robot is back at the approach pose " +
                       ua::spatial::positionText(atPick ? plan->pickApproach : plan->placeApproach);
        }
        unlockAll(r);
        options.log("failed: " + why);
        return finish(r, Outcome::failed(why));
    }

    std::string overheadSummary(const Run& r) const {
        std::vector<double> o;
        for (const auto& s : r.records)
            if (s.overheadMs >= 0) o.push_back(s.overheadMs);
        if (o.empty()) return "no composition overhead measured";
        std::sort(o.begin(), o.end());
        char buf[120];
        std::snprintf(buf, sizeof buf, "composition overhead median %.2f ms, max %.2f ms",
                      o[o.size() / 2], o.back());
        return buf;
    }

    // The outcome with FinalResultData/Steps, StepSkills, StepStart, StepEnd,
    // CompositionOverheadMs.
    Outcome finish(Run& r, Outcome outcome) {
        std::vector<ua::String> names, skills;
        std::vector<ua::DateTime> starts, ends;
        std::vector<double> overhead;
        for (const auto& s : r.records) {
            names.push_back(s.step);
            skills.push_back(s.skill);
            starts.push_back(
                ua::DateTime::fromUnixNanos(static_cast<ua::Int64>(s.startUnixS * 1e9)));
            ends.push_back(ua::DateTime::fromUnixNanos(static_cast<ua::Int64>(s.endUnixS * 1e9)));
            if (s.overheadMs >= 0) overhead.push_back(s.overheadMs);
        }
        {
            std::lock_guard l(mutex);
            last = r.records;
        }
        // FinalResultData of PickAndPlaceSkillType (models/Pnp.Skills.Composite.NodeSet2.xml).
        return outcome.with("Steps", ua::Variant(names))
            .with("StepSkills", ua::Variant(skills))
            .with("StepStart", ua::Variant(starts))
            .with("StepEnd", ua::Variant(ends))
            .with("CompositionOverheadMs", ua::Variant(overhead));
    }
};

PickPlaceComponent::PickPlaceComponent(ua::server::Server& server, PickPlaceOptions options,
                                       mdns::Mdns* mdns)
    : impl_(std::make_shared<Impl>(server, std::move(options))) {
    Impl& m = *impl_;
    if (!m.options.knowledge) throw std::invalid_argument("PickPlaceComponent: no knowledge base");
    auto& space = server.addressSpace();
    skill::server::loadSkillModels(space, {skill::kBaseUri, skill::kCompositeUri});
    m.controller = std::make_unique<skill::server::SkillController>(
        server, skill::server::SkillControllerOptions{.name = m.options.name});
    m.node = m.controller->node();

    using skill::server::declareParameter;
    std::weak_ptr<Impl> weak = impl_;
    skill::server::SkillCallbacks cb;
    cb.execute = [weak](Execution& exec) -> Outcome {
        auto impl = weak.lock();
        if (!impl) return Outcome::failed("the component is shutting down");
        return impl->run(exec);
    };
    // Network thread: only queue the request; the run's thread forwards it.
    cb.suspend = [weak]() -> ua::StatusCode {
        if (auto impl = weak.lock()) impl->pushControl(Control::Suspend);
        return {};
    };
    cb.resume = [weak]() -> ua::StatusCode {
        if (auto impl = weak.lock()) impl->pushControl(Control::Resume);
        return {};
    };
    auto pickPlace =
        skill::server::makeSkill(skill::types::PickAndPlaceSkillType,
                                 {declareParameter<ua::String>("ObjectId", ""),
                                  declareParameter<ua::String>("ToolSkillControllerEndpoint", ""),
                                  declareParameter<ua::String>("MoveSkillControllerEndpoint", ""),
                                  declareParameter<ua::ThreeDFrame>("PlacePosition")},
                                 std::move(cb));
    m.skillNode = m.controller->add("PickAndPlace", std::move(pickPlace)).node();

    m.detector = std::make_unique<skill::detector::SkillDetector>(mdns, m.options.detector);
}

PickPlaceComponent::~PickPlaceComponent() { stop(); }

void PickPlaceComponent::start() { impl_->detector->start(); }

void PickPlaceComponent::stop() {
    if (impl_->controller) impl_->controller.reset();  // halts a running PickAndPlace, joins it
    impl_->detector->stop();
    std::vector<std::shared_ptr<ua::client::Client>> clients;
    {
        std::lock_guard l(impl_->mutex);
        impl_->lowers.clear();
        for (auto& [url, c] : impl_->clients) clients.push_back(c);
        impl_->clients.clear();
    }
    for (auto& c : clients) c->stopBackgroundThread();
}

skill::detector::SkillDetector& PickPlaceComponent::detector() { return *impl_->detector; }
const ua::NodeId& PickPlaceComponent::node() const { return impl_->node; }
const ua::NodeId& PickPlaceComponent::skillNode() const { return impl_->skillNode; }
std::vector<StepRecord> PickPlaceComponent::lastSteps() const {
    std::lock_guard l(impl_->mutex);
    return impl_->last;
}

}  // namespace pnp::component::pickplace
