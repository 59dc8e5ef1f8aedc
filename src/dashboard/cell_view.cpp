#include "dashboard/cell_view.hpp"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <set>
#include <thread>

#include "dashboard/client_config.hpp"
#include "skill/client/generic_client.hpp"
#include "skill/detector/skill_detector.hpp"
#include "skill/model/model.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"
#include "ua/discovery/watcher.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_model.hpp"

namespace pnp::dashboard {

namespace {

using json = nlohmann::json;
using Steady = std::chrono::steady_clock;
using skill::client::GenericSkillClient;
using skill::detector::DetectedSkill;

constexpr std::string_view kWorldUri = "urn:pnp:sim:world";
constexpr std::string_view kRoboticsUri = "http://opcfoundation.org/UA/Robotics/";
constexpr std::string_view kDiUri = "http://opcfoundation.org/UA/DI/";
constexpr std::size_t kMaxAxes = 12;                  // axes of one motion device we show
constexpr std::size_t kMaxRecordBytes = 1024 * 1024;  // an MES Record we parse
constexpr std::size_t kMaxJobs = 100000;              // queued monitoring jobs
constexpr std::size_t kMaxWorldItems = 3000;          // robots, objects, tools watched
constexpr std::size_t kMaxSteps = 1000;               // steps of a process we show
constexpr std::size_t kReadBatch = 500;               // nodes per Read of the world's facts

std::int64_t epochMs(const ua::DateTime& t) {
    return t.ticks == 0 ? 0 : t.toUnixNanos() / 1'000'000;
}
std::int64_t nowMs() { return epochMs(ua::DateTime::now()); }

std::string skillId(const DetectedSkill& d) { return d.endpointUrl + "#" + d.nodeText; }
std::string componentId(const DetectedSkill& d) {
    return d.endpointUrl + "#" + d.controller.toString();
}

template <class T>
void pushBounded(T& list, typename T::value_type v, std::size_t max) {
    list.push_back(std::move(v));
    while (list.size() > max) list.erase(list.begin());
}

// A ThreeDFrame value as [x,y,z,a,b,c] (null when it is not one).
json frameJson(const ua::Variant& v) {
    if (const auto* x = v.scalar<ua::ExtensionObject>()) {
        try {
            if (auto f = ua::fromExtensionObject<ua::ThreeDFrame>(*x))
                return json::array({f->cartesianCoordinates.x, f->cartesianCoordinates.y,
                                    f->cartesianCoordinates.z, f->orientation.a, f->orientation.b,
                                    f->orientation.c});
        } catch (const std::exception&) {
        }
    }
    return nullptr;
}

// A ThreeDVector value as [x,y,z] (null when it is not one).
json vectorJson(const ua::Variant& v) {
    if (const auto* x = v.scalar<ua::ExtensionObject>()) {
        try {
            if (auto t = ua::fromExtensionObject<ua::ThreeDVector>(*x)) return {t->x, t->y, t->z};
        } catch (const std::exception&) {
        }
    }
    return nullptr;
}

// A step of the MES's Record or Progress (JSON) as the `process` message shows it.
json stepJson(const json& s) {
    return {{"index", s.value("index", json(nullptr))},
            {"label", s.value("label", json(nullptr))},
            {"skillType", s.value("skillType", json(nullptr))},
            {"skill", s.value("skill", json(nullptr))},
            {"component", s.value("componentName", json(nullptr))},
            {"result", s.value("result", json(nullptr))},
            {"message", s.value("message", json(nullptr))},
            {"durationS", s.value("durationS", json(nullptr))}};
}

json stepsJson(const json& steps) {
    json out = json::array();
    if (!steps.is_array()) return out;
    for (const auto& s : steps) {
        if (out.size() >= kMaxSteps) break;
        if (s.is_object()) out.push_back(stepJson(s));
    }
    return out;
}

json textOrNull(const ua::Variant& v) {
    if (const auto* s = v.scalar<ua::String>(); s && !s->empty()) return *s;
    if (const auto* t = v.scalar<ua::LocalizedText>(); t && !t->text.empty()) return t->text;
    return nullptr;
}

// Axis1 < Axis2 < Axis10: the axes' order is in their names' numbers.
bool naturalLess(const std::string& a, const std::string& b) {
    return a.size() != b.size() ? a.size() < b.size() : a < b;
}

bool isEnd(skill::ProgramState from, skill::ProgramState to) {
    using S = skill::ProgramState;
    return (from == S::Running || from == S::Suspended) && (to == S::Ready || to == S::Halted);
}

}  // namespace

struct CellView::Impl {
    CellViewOptions options;
    Publish publish;
    mdns::Mdns* mdns;

    // ---- state, under mutex ----------------------------------------------------------
    struct ServerEntry {
        json info;
        Steady::time_point seen;
        bool detectionRecorded = false;
    };
    struct SkillEntry {
        DetectedSkill detected;
        std::string component;
        std::string state = "Unknown";
        json parameters = json::array();
        json lastResult = nullptr;
        std::string error;
        std::int64_t runStartMs = 0;
        bool isProcess = false;
    };
    mutable std::mutex mutex;
    std::map<std::string, ServerEntry> servers;  // by normalised URL
    std::map<std::string, SkillEntry> skills;    // by id
    std::map<std::string, json> components;      // by id
    std::map<std::string, std::size_t> componentSkills;
    std::deque<json> timeline;
    std::deque<double> detectionMs;
    std::map<std::string, std::deque<double>> durations;  // by skill type name
    json process = nullptr;
    bool stopping = false;

    // ---- world, under worldMutex --------------------------------------------------------
    std::mutex worldMutex;
    std::condition_variable worldWake;
    struct World {
        std::map<std::string, json> joints;  // robot -> [6]
        std::map<std::string, json> tool;    // robot -> name | null
        std::map<std::string, json> model;   // robot -> model | null
        std::map<std::string, json> base;    // robot -> pose
        std::map<std::string, json> objectPose, objectHolder, objectSize, objectColor;
        std::map<std::string, json> toolDock, toolRobot, toolTcp;
        std::map<std::string, json> tables;    // name -> {name, pose, size}
        std::map<std::string, json> dockPose;  // dock -> pose (null: unknown)
        std::int64_t time = 0;
        bool any = false;
    } world;
    bool worldDirty = false;
    bool worldStop = false;
    std::thread worldThread;

    // ---- monitoring thread --------------------------------------------------------------
    std::mutex jobMutex;
    std::condition_variable jobWake;
    std::deque<std::function<void()>> jobs;
    bool jobsStop = false;
    std::thread monitor;
    // monitoring thread only
    struct Link {
        std::shared_ptr<ua::client::Client> client;
        // The skills' transition events, all on one subscription of the session.
        std::shared_ptr<ua::client::Subscription> events;
        std::map<std::string, std::unique_ptr<GenericSkillClient>> skills;
        struct ProgressWatch {  // the MES's ExecuteProcess/Progress
            ua::client::Subscription subscription;
            ua::client::MonitoredItem item;
        };
        std::map<std::string, ProgressWatch> progress;  // by skill id
        // A motion device's Robotics nodes, when there is no ground truth (real hardware).
        struct RobotWatch {
            std::string name;  // the key of the world's robot maps
            ua::client::Subscription subscription;
            std::vector<ua::client::MonitoredItem> items;
        };
        std::map<std::string, RobotWatch> robots;  // by component id
    };
    std::map<std::string, Link> links;
    std::shared_ptr<ua::client::Client> worldClient;
    ua::client::Subscription worldSubscription;
    std::vector<ua::client::MonitoredItem> worldItems;
    Steady::time_point worldRetry{};

    std::unique_ptr<ua::discovery::DiscoveryWatcher> watcher;
    std::unique_ptr<skill::detector::SkillDetector> detector;

    Impl(mdns::Mdns* m, CellViewOptions o, Publish p)
        : options(std::move(o)), publish(std::move(p)), mdns(m) {}

    ua::client::ClientConfig clientConfig() const {
        return dashboard::clientConfig(options.requestTimeout, options.connectTimeout);
    }

    void queue(std::function<void()> job) {
        {
            std::lock_guard lock(jobMutex);
            if (jobsStop || jobs.size() >= kMaxJobs) return;
            jobs.push_back(std::move(job));
        }
        jobWake.notify_one();
    }

    void runJobs() {
        for (;;) {
            std::function<void()> job;
            {
                std::unique_lock lock(jobMutex);
                const bool wantWorld = !options.worldUrl.empty() && !worldClient;
                const auto wait =
                    wantWorld ? std::chrono::milliseconds(200) : std::chrono::milliseconds(1000);
                jobWake.wait_for(lock, wait, [&] { return jobsStop || !jobs.empty(); });
                if (jobsStop) return;
                if (!jobs.empty()) {
                    job = std::move(jobs.front());
                    jobs.pop_front();
                }
            }
            try {
                if (job) job();
                if (!options.worldUrl.empty() && !worldClient && Steady::now() >= worldRetry)
                    connectWorld();
            } catch (const std::exception&) {
                // each job reports its own errors; nothing may end this thread
            }
        }
    }

    // ---- servers --------------------------------------------------------------------------
    static json serverJson(const ua::discovery::DiscoveredServer& s) {
        json parent = nullptr;
        for (const auto& source : s.sources)
            if (source != "mdns" && source != "manual" && source != s.discoveryUrl) {
                parent = source;
                break;
            }
        std::string uri, name = s.name;
        if (s.application) {
            uri = s.application->applicationUri;
            if (!s.application->applicationName.text.empty())
                name = s.application->applicationName.text;
        }
        return {{"url", s.discoveryUrl},
                {"applicationUri", uri},
                {"name", name},
                {"capabilities", s.capabilities},
                {"parent", parent},
                {"sources", std::vector<std::string>(s.sources.begin(), s.sources.end())},
                {"error", s.detailsError}};
    }

    void onServer(const ua::discovery::DiscoveredServer& s, bool up) {
        std::string message;
        {
            std::lock_guard lock(mutex);
            if (stopping) return;
            if (up) {
                auto it = servers.find(s.discoveryUrl);
                if (it == servers.end()) {
                    if (servers.size() >= options.maxServers) return;
                    it = servers.emplace(s.discoveryUrl, ServerEntry{}).first;
                    it->second.seen = Steady::now();
                }
                it->second.info = serverJson(s);
                message =
                    json{{"type", "server"}, {"op", "add"}, {"server", it->second.info}}.dump();
            } else {
                if (servers.erase(s.discoveryUrl) == 0) return;
                message =
                    json{
                        {"type", "server"}, {"op", "remove"}, {"server", {{"url", s.discoveryUrl}}}}
                        .dump();
            }
        }
        publish(std::move(message));
        if (up)
            detector->addServer(s.discoveryUrl);
        else
            detector->removeServer(s.discoveryUrl);
    }

    void addManualServer(const std::string& url) {
        ua::discovery::DiscoveredServer s;
        s.discoveryUrl = ua::discovery::normaliseUrl(url);
        if (s.discoveryUrl.empty()) return;
        s.sources.insert("manual");
        onServer(s, true);
    }

    // ---- skills ---------------------------------------------------------------------------
    json skillJson(const std::string& id, const SkillEntry& e) const {
        json types = json::array();
        for (const auto& t : e.detected.typeChain) types.push_back(t.name);
        json j = {{"id", id},
                  {"component", e.detected.controllerName},
                  {"componentId", e.component},
                  {"componentUri", e.detected.componentUri},
                  {"componentName", e.detected.componentName},
                  {"endpoint", e.detected.endpointUrl},
                  {"name", e.detected.name},
                  {"type", e.detected.type.name},
                  {"types", types},
                  {"parameters", e.parameters},
                  {"state", e.state},
                  {"lastResult", e.lastResult}};
        if (!e.error.empty()) j["error"] = e.error;
        return j;
    }

    void onSkill(const DetectedSkill& d, bool added) {
        const std::string id = skillId(d);
        const std::string comp = componentId(d);
        std::vector<std::string> messages;
        bool newComponent = false, componentGone = false;
        {
            std::lock_guard lock(mutex);
            if (stopping) return;
            if (added) {
                if (skills.count(id) || skills.size() >= options.maxSkills) return;
                SkillEntry e;
                e.detected = d;
                e.component = comp;
                e.isProcess = d.isA(skill::types::ExecuteProcessSkillType);
                if (componentSkills[comp]++ == 0) {
                    newComponent = true;
                    components[comp] = {{"id", comp},
                                        {"name", d.controllerName},
                                        {"endpoint", d.endpointUrl},
                                        {"applicationUri", d.componentUri},
                                        {"applicationName", d.componentName}};
                    messages.push_back(
                        json{{"type", "component"}, {"op", "add"}, {"component", components[comp]}}
                            .dump());
                }
                // A server given by --url is known by its URL alone until its skills say
                // which application it is.
                if (auto s = servers.find(d.endpointUrl);
                    s != servers.end() && s->second.info.value("applicationUri", "").empty() &&
                    !d.componentUri.empty()) {
                    s->second.info["applicationUri"] = d.componentUri;
                    if (s->second.info.value("name", "").empty())
                        s->second.info["name"] = d.componentName;
                    messages.push_back(
                        json{{"type", "server"}, {"op", "add"}, {"server", s->second.info}}.dump());
                }
                if (auto s = servers.find(d.endpointUrl);
                    s != servers.end() && !s->second.detectionRecorded) {
                    s->second.detectionRecorded = true;
                    const double ms =
                        std::chrono::duration<double, std::milli>(Steady::now() - s->second.seen)
                            .count();
                    pushBounded(detectionMs, ms, options.statsLength);
                    messages.push_back(statsJson().dump());
                }
                auto& entry = skills.emplace(id, std::move(e)).first->second;
                messages.push_back(
                    json{{"type", "skill"}, {"op", "add"}, {"skill", skillJson(id, entry)}}.dump());
            } else {
                if (skills.erase(id) == 0) return;
                messages.push_back(
                    json{{"type", "skill"}, {"op", "remove"}, {"skill", {{"id", id}}}}.dump());
                if (--componentSkills[comp] == 0) {
                    componentGone = true;
                    componentSkills.erase(comp);
                    components.erase(comp);
                    messages.push_back(
                        json{{"type", "component"}, {"op", "remove"}, {"component", {{"id", comp}}}}
                            .dump());
                }
            }
        }
        for (auto& m : messages) publish(std::move(m));
        if (added)
            queue([this, id] { attach(id); });
        else
            queue([this, id, url = d.endpointUrl] { detach(id, url); });
        // Without a ground truth the 3D view follows the robots' own Robotics nodes.
        if (options.worldUrl.empty() && newComponent)
            queue([this, comp, d] { watchRobot(comp, d); });
        if (options.worldUrl.empty() && componentGone)
            queue([this, comp, url = d.endpointUrl] { unwatchRobot(comp, url); });
    }

    // Monitoring thread: a SkillClient on the server's monitoring session.
    void attach(const std::string& id) {
        DetectedSkill d;
        {
            std::lock_guard lock(mutex);
            const auto it = skills.find(id);
            if (it == skills.end()) return;
            d = it->second.detected;
        }
        json parameters = json::array(), lastResult = nullptr;
        std::string state = "Unknown", error;
        Link& link = links[d.endpointUrl];
        try {
            if (!link.client) {
                auto client = std::make_shared<ua::client::Client>(clientConfig());
                client->connect(d.endpointUrl, ua::client::Anonymous{}, options.connectTimeout);
                client->startBackgroundThread();
                link.client = std::move(client);
            }
            if (!link.events) {
                ua::client::SubscriptionSettings settings;
                settings.publishingInterval = 10;  // an event reaches the page about one RTT
                settings.maxKeepAliveCount = 100;  // after its transition
                settings.lifetimeCount = 6000;
                link.events = std::make_shared<ua::client::Subscription>(
                    *link.client, settings, ua::client::SubscriptionStatusCallback{},
                    options.requestTimeout);
            }
            const ua::client::Deadline deadline(options.requestTimeout * 3);
            skill::client::SkillClientOptions clientOptions;
            clientOptions.subscription = link.events;
            auto sc =
                std::make_unique<GenericSkillClient>(link.client, d.node, deadline, clientOptions);
            for (const auto& p : sc->parameters())
                parameters.push_back(
                    {{"name", p.name},
                     {"dataType", skill::client::typeName(p.dataType, p.valueRank)},
                     {"valueRank", p.valueRank},
                     {"writable", p.writable}});
            state = std::string(skill::toString(sc->state(options.requestTimeout)));
            sc->onTransition(
                [this, id](const skill::client::Transition& t) { onTransition(id, t); },
                options.requestTimeout);
            lastResult = resultJson(sc->finalResult(options.requestTimeout));
            link.skills[id] = std::move(sc);
            if (d.isA(skill::types::ExecuteProcessSkillType)) watchProgress(id, link, d.node);
        } catch (const std::exception& e) {
            error = e.what();
            if (link.skills.empty()) {
                if (link.client) link.client->disconnect();
                links.erase(d.endpointUrl);
            }
        }
        std::string message;
        {
            std::lock_guard lock(mutex);
            const auto it = skills.find(id);
            if (it == skills.end() || stopping) return;
            auto& e = it->second;
            e.parameters = std::move(parameters);
            // A transition may have come first: it is newer than the Read.
            if (e.state == "Unknown") e.state = state;
            if (e.lastResult.is_null()) e.lastResult = std::move(lastResult);
            e.error = error;
            message = json{{"type", "skill"}, {"op", "add"}, {"skill", skillJson(id, e)}}.dump();
        }
        publish(std::move(message));
    }

    void detach(const std::string& id, const std::string& url) {
        const auto link = links.find(url);
        if (link == links.end()) return;
        // A server that is gone: close its session first, so that dropping the skills'
        // monitored items does not wait for it.
        bool gone = true;
        for (const auto& s : detector->servers())
            if (s.url == url && s.status == skill::detector::ServerState::Status::Skills)
                gone = false;
        if (gone) link->second.client->disconnect();
        link->second.progress.erase(id);
        link->second.skills.erase(id);
        if (link->second.skills.empty()) {
            link->second.client->disconnect();
            std::vector<std::string> names;
            for (const auto& [comp, r] : link->second.robots) names.push_back(r.name);
            links.erase(link);
            for (const auto& n : names) forgetRobot(n);
        }
    }

    // Monitoring thread: a component that is a motion device (OPC 40010: an Axes folder
    // whose axes have ParameterSet/ActualPosition) becomes a robot of the world: its joints
    // from ActualPosition, its model from the DI Model, its base from WorldToRobotBase.
    void watchRobot(const std::string& comp, const DetectedSkill& d) {
        const auto link = links.find(d.endpointUrl);
        if (link == links.end() || !link->second.client || link->second.robots.count(comp)) return;
        auto& client = *link->second.client;
        std::string inserted;  // the world's entry, once made
        try {
            const ua::UInt16 rob = client.namespaceIndex(kRoboticsUri, options.requestTimeout);
            const ua::UInt16 di = client.namespaceIndex(kDiUri, options.requestTimeout);
            ua::NodeId axesFolder, model, base;
            for (const auto& r : client.browse(d.controller, {}, options.requestTimeout)) {
                const auto& n = r.browseName;
                if (n.namespaceIndex == rob && n.name == "Axes") axesFolder = r.nodeId.nodeId;
                if (n.namespaceIndex == di && n.name == "Model") model = r.nodeId.nodeId;
                if (n.name == "WorldToRobotBase") base = r.nodeId.nodeId;
            }
            if (axesFolder.isNull()) return;  // not a motion device
            std::vector<std::pair<std::string, ua::NodeId>> axes;
            for (const auto& r : client.browse(axesFolder, {}, options.requestTimeout))
                if (axes.size() < kMaxAxes) axes.emplace_back(r.browseName.name, r.nodeId.nodeId);
            std::sort(axes.begin(), axes.end(),
                      [](const auto& a, const auto& b) { return naturalLess(a.first, b.first); });
            const std::string path = "/" + std::to_string(di) + ":ParameterSet/" +
                                     std::to_string(rob) + ":ActualPosition";
            std::vector<ua::NodeId> positions;
            for (const auto& [name, axis] : axes)
                positions.push_back(client.resolve(axis, path, options.requestTimeout));
            if (positions.empty()) return;

            Link::RobotWatch w;
            {
                std::lock_guard lock(worldMutex);
                w.name = d.controllerName.empty() ? comp : d.controllerName;
                if (world.joints.count(w.name)) w.name += " (" + d.endpointUrl + ")";
                world.joints[w.name] = json(std::vector<double>(positions.size(), 0.0));
                world.tool[w.name] = nullptr;
                world.model[w.name] = nullptr;
                inserted = w.name;
            }
            const std::string name = w.name;
            w.subscription = ua::client::Subscription(
                client, {.publishingInterval = 1000.0 / std::max(1.0, options.worldRate)}, {},
                options.requestTimeout);
            std::vector<ua::NodeId> nodes = positions;
            if (!model.isNull()) nodes.push_back(model);
            if (!base.isNull()) nodes.push_back(base);
            const std::size_t axisCount = positions.size();
            const bool hasModel = !model.isNull();
            w.items = w.subscription.monitorValues(
                nodes,
                [this, name, axisCount, hasModel](std::size_t i, const ua::DataValue& v) {
                    if (!v.value) return;
                    {
                        std::lock_guard lock(worldMutex);
                        auto joints = world.joints.find(name);
                        if (joints == world.joints.end()) return;  // forgotten meanwhile
                        if (i < axisCount) {
                            const auto* q = v.value->scalar<ua::Double>();
                            if (!q) return;
                            joints->second[i] = *q;
                        } else if (i == axisCount && hasModel) {
                            world.model[name] = textOrNull(*v.value);
                        } else {
                            world.base[name] = frameJson(*v.value);
                        }
                        world.time = v.sourceTimestamp ? epochMs(*v.sourceTimestamp) : nowMs();
                        world.any = true;
                        worldDirty = true;
                    }
                    worldWake.notify_one();
                },
                {.samplingInterval = 0}, nullptr, options.requestTimeout);
            link->second.robots[comp] = std::move(w);
        } catch (const std::exception&) {
            // not a motion device we can follow: the 3D view shows no robot for it
            if (!inserted.empty()) forgetRobot(inserted);
        }
    }

    void unwatchRobot(const std::string& comp, const std::string& url) {
        const auto link = links.find(url);
        if (link == links.end()) return;
        const auto it = link->second.robots.find(comp);
        if (it == link->second.robots.end()) return;
        const std::string name = it->second.name;
        link->second.robots.erase(it);
        forgetRobot(name);
    }

    void forgetRobot(const std::string& name) {
        {
            std::lock_guard lock(worldMutex);
            world.joints.erase(name);
            world.tool.erase(name);
            world.model.erase(name);
            world.base.erase(name);
            worldDirty = true;
        }
        worldWake.notify_one();
    }

    static json resultJson(const skill::client::FinalResult& r) {
        if (r.result == skill::SkillResult::None) return nullptr;
        json values = json::object();
        for (const auto& [name, value] : r.values) {
            std::string text = skill::client::formatValue(value);
            if (text.size() > 4096) text = text.substr(0, 4096) + "...";
            values[name] = text;
        }
        return {{"result", std::string(skill::toString(r.result))},
                {"message", r.message},
                {"values", values},
                {"time", nowMs()}};
    }

    json statsJson() const {
        json d = json::object();
        for (const auto& [type, list] : durations) d[type] = list;
        return {{"type", "stats"}, {"detectionMs", detectionMs}, {"skillDurations", d}};
    }

    // A client's dispatch thread: the message at once; reads go to the monitoring thread.
    void onTransition(const std::string& id, const skill::client::Transition& t) {
        std::vector<std::string> messages;
        bool ended = false, processStarted = false;
        {
            std::lock_guard lock(mutex);
            if (stopping) return;
            const auto it = skills.find(id);
            if (it == skills.end()) return;
            auto& e = it->second;
            const std::int64_t time = epochMs(t.time) ? epochMs(t.time) : nowMs();
            json m = {{"type", "transition"},
                      {"skill", id},
                      {"from", std::string(skill::toString(t.from))},
                      {"to", std::string(skill::toString(t.to))},
                      {"transition", t.name},
                      {"time", time}};
            if (!t.message.empty()) m["message"] = t.message;
            e.state = std::string(skill::toString(t.to));
            using S = skill::ProgramState;
            if (t.to == S::Running && t.from == S::Ready) e.runStartMs = time;
            ended = isEnd(t.from, t.to);
            if (ended && e.runStartMs > 0) {
                auto& list = durations[e.detected.type.name];
                if (durations.size() <= 1000)
                    pushBounded(list, static_cast<double>(time - e.runStartMs),
                                options.statsLength);
                e.runStartMs = 0;
            }
            pushBounded(timeline, m, options.timelineLength);
            messages.push_back(m.dump());
            if (ended) messages.push_back(statsJson().dump());
            const bool processShown =
                process.is_object() && process["skill"] == id &&
                (process["state"] == "Running" || process["state"] == "Suspended");
            if (e.isProcess && t.from == S::Ready && t.to == S::Running) {
                processStarted = true;
                process = runningProcess(id, time);
                messages.push_back(processMessage());
            } else if (e.isProcess && processShown &&
                       (t.to == S::Suspended || (t.from == S::Suspended && t.to == S::Running))) {
                process["state"] = e.state;  // Suspend / Resume of the whole process
                messages.push_back(processMessage());
            } else if (!e.isProcess && t.to == S::Running && process.is_object() &&
                       (process["state"] == "Running" || process["state"] == "Suspended")) {
                process["activeSkill"] = id;
                messages.push_back(processMessage());
            }
        }
        for (auto& m : messages) publish(std::move(m));
        if (ended) queue([this, id] { readResult(id); });
        if (processStarted) queue([this, id] { readProcessIri(id); });
    }

    // The process panel's state when a run of ExecuteProcess `id` starts (or is first seen).
    static json runningProcess(const std::string& id, json start) {
        return {{"skill", id},
                {"execution", nullptr},
                {"processIri", nullptr},
                {"state", "Running"},
                {"steps", json::array()},
                {"running", nullptr},
                {"activeSkill", nullptr},
                {"start", std::move(start)}};
    }

    // Monitoring thread: the MES publishes the run as it goes in ExecuteProcess/Progress
    // (src/mes/mes.hpp); an MES without it only gives the Record at the end.
    void watchProgress(const std::string& id, Link& link, const ua::NodeId& node) {
        try {
            ua::NodeId progressNode;
            for (const auto& r : link.client->browse(node, {}, options.requestTimeout))
                if (r.browseName.name == "Progress") progressNode = r.nodeId.nodeId;
            if (progressNode.isNull()) return;
            Link::ProgressWatch w;
            w.subscription = ua::client::Subscription(*link.client, {.publishingInterval = 50}, {},
                                                      options.requestTimeout);
            w.item = w.subscription.monitorValue(
                progressNode, [this, id](const ua::DataValue& v) { onProgress(id, v); },
                {.samplingInterval = 0, .queueSize = 10}, options.requestTimeout);
            link.progress[id] = std::move(w);
        } catch (const std::exception&) {
            // the process panel then shows the steps when the run has ended
        }
    }

    // A client's dispatch thread: the running step and the steps' results so far.
    void onProgress(const std::string& id, const ua::DataValue& v) {
        const auto* text = v.value ? v.value->scalar<ua::String>() : nullptr;
        if (!text || text->empty() || text->size() > kMaxRecordBytes) return;
        const json p = json::parse(*text, nullptr, false);
        if (!p.is_object() || !p.contains("result") || !p["result"].is_null())
            return;  // not a run in progress: its end comes with the Record (readResult)
        std::string message;
        {
            std::lock_guard lock(mutex);
            if (stopping) return;
            const auto it = skills.find(id);
            if (it == skills.end()) return;
            const bool runs = it->second.state == "Running" || it->second.state == "Suspended";
            const bool shown = process.is_object() && process["skill"] == id &&
                               (process["state"] == "Running" || process["state"] == "Suspended");
            if (!shown) {
                // A run that began before this dashboard saw it start; else an old value.
                if (!runs) return;
                process = runningProcess(id, nullptr);
            }
            const json execution = p.value("execution", json(nullptr));
            if (!process["execution"].is_null() && process["execution"] != execution)
                return;  // another run's
            process["execution"] = execution;
            if (const auto iri = p.value("process", json(nullptr));
                iri.is_string() && !iri.get<std::string>().empty())
                process["processIri"] = iri;
            const json running = p.value("running", json(nullptr));
            process["running"] = running.is_number_integer() ? running : json(nullptr);
            process["steps"] = stepsJson(p.value("steps", json::array()));
            message = processMessage();
        }
        publish(std::move(message));
    }

    std::string processMessage() const {
        json m = process;
        m["type"] = "process";
        return m.dump();
    }

    GenericSkillClient* skillClient(const std::string& id) {
        for (auto& [url, link] : links)
            if (const auto it = link.skills.find(id); it != link.skills.end())
                return it->second.get();
        return nullptr;
    }

    void readProcessIri(const std::string& id) {
        auto* sc = skillClient(id);
        if (!sc) return;
        json iri = nullptr;
        try {
            iri = textOrNull(sc->parameter("ProcessIri", options.requestTimeout));
        } catch (const std::exception&) {
            return;
        }
        std::string message;
        {
            std::lock_guard lock(mutex);
            if (!process.is_object() || process["skill"] != id || stopping) return;
            process["processIri"] = iri;
            message = processMessage();
        }
        publish(std::move(message));
    }

    void readResult(const std::string& id) {
        auto* sc = skillClient(id);
        if (!sc) return;
        skill::client::FinalResult r;
        try {
            r = sc->finalResult(options.requestTimeout);
        } catch (const std::exception&) {
            return;
        }
        std::vector<std::string> messages;
        {
            std::lock_guard lock(mutex);
            const auto it = skills.find(id);
            if (it == skills.end() || stopping) return;
            auto& e = it->second;
            e.lastResult = resultJson(r);
            messages.push_back(
                json{{"type", "skill"}, {"op", "add"}, {"skill", skillJson(id, e)}}.dump());
            if (e.isProcess) {
                updateProcessFromRecord(id, r);
                messages.push_back(processMessage());
            }
        }
        for (auto& m : messages) publish(std::move(m));
    }

    // The MES's Record (FinalResultData/Record, JSON) -> the process message.
    void updateProcessFromRecord(const std::string& id, const skill::client::FinalResult& r) {
        if (!process.is_object() || process["skill"] != id)
            process = {{"skill", id}, {"processIri", nullptr}, {"start", nullptr}};
        // Steps the run shown so far planned (Progress) that the Record lacks: not reached.
        std::vector<json> planned;
        if (process.is_object() && process["skill"] == id && process.contains("steps") &&
            process["steps"].is_array())
            planned.assign(process["steps"].begin(), process["steps"].end());
        const json shownExecution = process.value("execution", json(nullptr));
        process["state"] = skills[id].state;
        process["running"] = nullptr;
        process["activeSkill"] = nullptr;
        process["result"] = std::string(skill::toString(r.result));
        process["reason"] = r.message;
        json steps = json::array();
        for (const auto& [name, value] : r.values) {
            if (name != "Record") continue;
            const auto* text = value.scalar<ua::String>();
            if (!text || text->size() > kMaxRecordBytes) continue;
            const json record = json::parse(*text, nullptr, false);
            if (!record.is_object()) continue;
            if (record.contains("execution")) process["execution"] = record["execution"];
            if (record.contains("process")) process["processIri"] = record["process"];
            if (record.contains("result")) process["result"] = record["result"];
            if (record.contains("reason")) process["reason"] = record["reason"];
            if (record.contains("steps")) steps = stepsJson(record["steps"]);
        }
        if (!shownExecution.is_null() && process["execution"] == shownExecution) {
            std::set<json> recorded;
            for (const auto& st : steps) recorded.insert(st["index"]);
            for (const auto& st : planned)
                if (st.is_object() && !recorded.count(st.value("index", json(nullptr))) &&
                    steps.size() < kMaxSteps)
                    steps.push_back(st);  // already in the message's form
        }
        process["steps"] = steps;
    }

    // ---- the world -------------------------------------------------------------------------
    void connectWorld() {
        worldRetry = Steady::now() + std::chrono::seconds(2);
        try {
            auto client = std::make_shared<ua::client::Client>(clientConfig());
            client->connect(options.worldUrl, ua::client::Anonymous{}, options.connectTimeout);
            const ua::UInt16 ns = client->namespaceIndex(kWorldUri, options.requestTimeout);
            auto children = [&](const std::string& folder) {
                std::vector<std::string> names;
                for (const auto& r :
                     client->browse(ua::NodeId(ns, folder), {}, options.requestTimeout))
                    if (names.size() < kMaxWorldItems) names.push_back(r.browseName.name);
                return names;
            };
            // Folders an older ground truth does not have.
            auto optionalChildren = [&](const std::string& folder) {
                try {
                    return children(folder);
                } catch (const std::exception&) {
                    return std::vector<std::string>{};
                }
            };
            const auto robots = children("Robots");
            const auto objects = children("Objects");
            const auto tools = children("Tools");
            const auto tables = optionalChildren("Tables");
            const auto docks = optionalChildren("Docks");
            readWorldFacts(*client, ns, robots, objects, tools, tables, docks);
            client->startBackgroundThread();
            ua::client::Subscription sub(
                *client, {.publishingInterval = 1000.0 / std::max(1.0, options.worldRate)}, {},
                options.requestTimeout);
            std::vector<ua::client::MonitoredItem> items;
            auto watch = [&](const std::string& path,
                             std::function<void(World&, const ua::Variant&)> apply) {
                items.push_back(sub.monitorValue(
                    ua::NodeId(ns, path),
                    [this, apply](const ua::DataValue& v) {
                        if (!v.value) return;
                        {
                            std::lock_guard lock(worldMutex);
                            apply(world, *v.value);
                            world.time = v.sourceTimestamp ? epochMs(*v.sourceTimestamp) : nowMs();
                            world.any = true;
                            worldDirty = true;
                        }
                        worldWake.notify_one();
                    },
                    {.samplingInterval = 0}, options.requestTimeout));
            };
            for (const auto& r : robots) {
                watch("Robots." + r + ".Joints", [r](World& w, const ua::Variant& v) {
                    if (const auto* q = v.array<ua::Double>()) w.joints[r] = *q;
                });
                watch("Robots." + r + ".Tool",
                      [r](World& w, const ua::Variant& v) { w.tool[r] = textOrNull(v); });
            }
            for (const auto& o : objects) {
                watch("Objects." + o + ".Pose",
                      [o](World& w, const ua::Variant& v) { w.objectPose[o] = frameJson(v); });
                watch("Objects." + o + ".Holder",
                      [o](World& w, const ua::Variant& v) { w.objectHolder[o] = textOrNull(v); });
            }
            for (const auto& t : tools) {
                watch("Tools." + t + ".Dock",
                      [t](World& w, const ua::Variant& v) { w.toolDock[t] = textOrNull(v); });
                watch("Tools." + t + ".Robot",
                      [t](World& w, const ua::Variant& v) { w.toolRobot[t] = textOrNull(v); });
            }
            worldItems = std::move(items);
            worldSubscription = std::move(sub);
            worldClient = std::move(client);
        } catch (const std::exception&) {
            worldItems.clear();
            worldSubscription = {};
        }
    }

    // The cell file's static facts (written once by the ground truth): read once, in
    // batches; a node an older ground truth lacks is null.
    void readWorldFacts(ua::client::Client& client, ua::UInt16 ns,
                        const std::vector<std::string>& robots,
                        const std::vector<std::string>& objects,
                        const std::vector<std::string>& tools,
                        const std::vector<std::string>& tables,
                        const std::vector<std::string>& docks) {
        std::vector<std::pair<std::string, std::function<void(World&, const ua::Variant*)>>> facts;
        auto fact = [&](std::string path, std::function<void(World&, const ua::Variant*)> f) {
            facts.emplace_back(std::move(path), std::move(f));
        };
        auto text = [](const ua::Variant* v) { return v ? textOrNull(*v) : json(nullptr); };
        auto frame = [](const ua::Variant* v) { return v ? frameJson(*v) : json(nullptr); };
        auto vector = [](const ua::Variant* v) { return v ? vectorJson(*v) : json(nullptr); };
        for (const auto& r : robots) {
            fact("Robots." + r + ".Model",
                 [r, text](World& w, const ua::Variant* v) { w.model[r] = text(v); });
            fact("Robots." + r + ".Base",
                 [r, frame](World& w, const ua::Variant* v) { w.base[r] = frame(v); });
        }
        for (const auto& o : objects) {
            fact("Objects." + o + ".Size",
                 [o, vector](World& w, const ua::Variant* v) { w.objectSize[o] = vector(v); });
            fact("Objects." + o + ".Color",
                 [o, text](World& w, const ua::Variant* v) { w.objectColor[o] = text(v); });
        }
        for (const auto& t : tools)
            fact("Tools." + t + ".Tcp",
                 [t, frame](World& w, const ua::Variant* v) { w.toolTcp[t] = frame(v); });
        for (const auto& t : tables) {
            fact("Tables." + t + ".Pose", [t, frame](World& w, const ua::Variant* v) {
                w.tables[t]["name"] = t;
                w.tables[t]["pose"] = frame(v);
            });
            fact("Tables." + t + ".Size", [t, vector](World& w, const ua::Variant* v) {
                w.tables[t]["name"] = t;
                w.tables[t]["size"] = vector(v);
            });
        }
        for (const auto& d : docks)
            fact("Docks." + d + ".Pose",
                 [d, frame](World& w, const ua::Variant* v) { w.dockPose[d] = frame(v); });
        for (std::size_t first = 0; first < facts.size(); first += kReadBatch) {
            const std::size_t last = std::min(facts.size(), first + kReadBatch);
            std::vector<ua::ReadValueId> ids;
            for (std::size_t i = first; i < last; ++i)
                ids.push_back(ua::ReadValueId{ua::NodeId(ns, facts[i].first),
                                              static_cast<ua::UInt32>(ua::AttributeId::Value),
                                              ua::String(),
                                              {}});
            const auto values = client.read(std::move(ids), options.requestTimeout);
            std::lock_guard lock(worldMutex);
            for (std::size_t i = first; i < last; ++i) {
                const std::size_t k = i - first;
                const bool good = k < values.size() && values[k].statusOrGood().isGood() &&
                                  values[k].value && !values[k].value->isEmpty();
                facts[i].second(world, good ? &*values[k].value : nullptr);
            }
        }
    }

    json worldJson() {  // under worldMutex
        json joints = json::object(), tool = json::object(), models = json::object();
        for (const auto& [r, q] : world.joints) joints[r] = q;
        for (const auto& [r, t] : world.tool) tool[r] = t;
        for (const auto& [r, m] : world.model) models[r] = m;
        json bases = json::object();
        for (const auto& [r, b] : world.base)
            if (!b.is_null()) bases[r] = b;
        auto find = [](const std::map<std::string, json>& m, const std::string& key) {
            const auto it = m.find(key);
            return it == m.end() ? json(nullptr) : it->second;
        };
        json objects = json::array();
        for (const auto& [name, pose] : world.objectPose)
            objects.push_back({{"name", name},
                               {"pose", pose},
                               {"holder", find(world.objectHolder, name)},
                               {"size", find(world.objectSize, name)},
                               {"color", find(world.objectColor, name)}});
        json tools = json::array(), docks = json::array();
        std::map<std::string, json> dockTool;  // dock -> the tool parked there
        for (const auto& [name, dock] : world.toolDock) {
            tools.push_back({{"name", name},
                             {"dock", dock},
                             {"robot", find(world.toolRobot, name)},
                             {"tcp", find(world.toolTcp, name)}});
            if (dock.is_string() && !dockTool.count(dock.get<std::string>()))
                dockTool[dock.get<std::string>()] = name;
        }
        std::set<std::string> dockNames;  // the ground truth's docks, and any a tool names
        for (const auto& [name, pose] : world.dockPose) dockNames.insert(name);
        for (const auto& [name, tool] : dockTool) dockNames.insert(name);
        for (const auto& name : dockNames)
            docks.push_back({{"name", name},
                             {"tool", find(dockTool, name)},
                             {"pose", find(world.dockPose, name)}});
        json tables = json::array();
        for (const auto& [name, t] : world.tables)
            tables.push_back({{"name", name},
                              {"pose", t.value("pose", json(nullptr))},
                              {"size", t.value("size", json(nullptr))}});
        return {{"type", "world"},  {"joints", joints},   {"tool", tool},   {"models", models},
                {"bases", bases},   {"objects", objects}, {"tools", tools}, {"docks", docks},
                {"tables", tables}, {"time", world.time}};
    }

    void runWorld() {
        const auto period = std::chrono::duration_cast<Steady::duration>(
            std::chrono::duration<double>(1.0 / std::max(1.0, options.worldRate)));
        std::unique_lock lock(worldMutex);
        while (!worldStop) {
            worldWake.wait(lock, [&] { return worldStop || worldDirty; });
            if (worldStop) return;
            worldDirty = false;
            std::string message = worldJson().dump();
            lock.unlock();
            publish(std::move(message));
            std::this_thread::sleep_for(period);  // at most worldRate messages per second
            lock.lock();
        }
    }

    json snapshot() {
        json s;
        {
            std::lock_guard lock(mutex);
            json sv = json::array(), comps = json::array(), sk = json::array();
            for (const auto& [url, e] : servers) sv.push_back(e.info);
            for (const auto& [id, c] : components) comps.push_back(c);
            for (const auto& [id, e] : skills) sk.push_back(skillJson(id, e));
            const json stats = statsJson();
            s = {{"type", "snapshot"},
                 {"servers", sv},
                 {"components", comps},
                 {"skills", sk},
                 {"process", process},
                 {"timeline", json(timeline)},
                 {"stats",
                  {{"detectionMs", stats["detectionMs"]},
                   {"skillDurations", stats["skillDurations"]}}},
                 {"time", nowMs()}};
        }
        std::lock_guard lock(worldMutex);
        s["world"] = world.any ? worldJson() : json(nullptr);
        return s;
    }
};

CellView::CellView(mdns::Mdns* mdns, CellViewOptions options, Publish publish)
    : impl_(std::make_unique<Impl>(mdns, std::move(options), std::move(publish))) {}

CellView::~CellView() { stop(); }

void CellView::start() {
    Impl& d = *impl_;
    if (d.detector) return;
    skill::detector::DetectorConfig dc;
    dc.useDiscovery = false;  // fed by our watcher: one watcher for servers and skills
    dc.requestTimeout = d.options.requestTimeout;
    dc.connectTimeout = d.options.connectTimeout;
    d.detector = std::make_unique<skill::detector::SkillDetector>(nullptr, dc);
    d.detector->onChange([&d](const DetectedSkill& s, bool added) { d.onSkill(s, added); });
    d.monitor = std::thread([&d] { d.runJobs(); });
    d.worldThread = std::thread([&d] { d.runWorld(); });
    d.detector->start();
    if (d.options.discovery) {
        ua::discovery::WatcherConfig wc;
        wc.ldsUrls = d.options.ldsUrls;
        wc.pollInterval = d.options.pollInterval;
        wc.requestTimeout = d.options.requestTimeout;
        wc.maxServers = d.options.maxServers;
        d.watcher = std::make_unique<ua::discovery::DiscoveryWatcher>(
            d.mdns, wc,
            [&d](const ua::discovery::DiscoveredServer& s, bool up) { d.onServer(s, up); });
        d.watcher->start();
    }
    for (const auto& url : d.options.urls) d.addManualServer(url);
}

void CellView::stop() {
    Impl& d = *impl_;
    if (!d.detector) return;
    if (d.watcher) d.watcher->stop();
    {
        std::lock_guard lock(d.mutex);
        d.stopping = true;
    }
    d.detector->stop();
    {
        std::lock_guard lock(d.jobMutex);
        d.jobsStop = true;
    }
    d.jobWake.notify_all();
    if (d.monitor.joinable()) d.monitor.join();
    {
        std::lock_guard lock(d.worldMutex);
        d.worldStop = true;
    }
    d.worldWake.notify_all();
    if (d.worldThread.joinable()) d.worldThread.join();
    // Sessions closed first: dropping the items then costs no round trips.
    for (auto& [url, link] : d.links) link.client->disconnect();
    d.links.clear();
    if (d.worldClient) d.worldClient->disconnect();
    d.worldItems.clear();
    d.worldSubscription = {};
    d.worldClient.reset();
    d.watcher.reset();
    d.detector.reset();
}

nlohmann::json CellView::snapshot() const { return impl_->snapshot(); }

std::optional<SkillTarget> CellView::skill(const std::string& id) const {
    std::lock_guard lock(impl_->mutex);
    const auto it = impl_->skills.find(id);
    if (it == impl_->skills.end()) return std::nullopt;
    const auto& d = it->second.detected;
    return SkillTarget{id, d.endpointUrl, d.node, d.name, d.type.name};
}

std::optional<SkillTarget> CellView::processSkill() const {
    std::lock_guard lock(impl_->mutex);
    for (const auto& [id, e] : impl_->skills)
        if (e.isProcess) {
            const auto& d = e.detected;
            return SkillTarget{id, d.endpointUrl, d.node, d.name, d.type.name};
        }
    return std::nullopt;
}

std::string CellView::anySkillServer() const {
    if (auto p = processSkill()) return p->endpointUrl;
    std::lock_guard lock(impl_->mutex);
    return impl_->skills.empty() ? std::string()
                                 : impl_->skills.begin()->second.detected.endpointUrl;
}

}  // namespace pnp::dashboard
