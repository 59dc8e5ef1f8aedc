#include "skill/detector/skill_detector.hpp"

#include <algorithm>
#include <atomic>
#include <set>
#include <stop_token>
#include <utility>

#include "ua/client/client.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::skill::detector {

namespace ns0 = ua::ns0;
using ua::client::Client;
using Clock = std::chrono::steady_clock;

std::string_view toString(ServerState::Status s) {
    switch (s) {
        case ServerState::Status::Examining:
            return "examining";
        case ServerState::Status::Skills:
            return "skills";
        case ServerState::Status::NoSkills:
            return "no-skills";
        case ServerState::Status::Unreachable:
            return "unreachable";
    }
    return "";
}

namespace {

constexpr ua::UInt32 kResultAll = 0x3F;
constexpr ua::UInt32 kResultBrowseName = 0x08 | 0x20;  // BrowseName + TypeDefinition
// Below the MaxNodesPerBrowse of common servers (ours: 10000).
constexpr std::size_t kMaxPerBrowse = 500;

// The outcome of one examination of a server.
struct Examination {
    ServerState::Status status = ServerState::Status::Unreachable;
    std::string error;
    std::string applicationUri, applicationName;
    std::vector<DetectedSkill> skills;
    std::size_t controllers = 0;
    std::size_t roundTrips = 0;
    double ms = 0;
    std::shared_ptr<Client> client;  // kept connected for the health checks
};

// One examination: the address space walk of docs/skill_detector.md. Throws
// ua::client::Error when the server fails on the way.
class Examiner {
  public:
    Examiner(Client& client, const DetectorConfig& config) : c_(client), cfg_(config) {}

    std::size_t roundTrips = 0;

    // false: no skill namespace.
    bool readNamespaces(std::string& serverUri) {
        std::vector<ua::ReadValueId> ids(2);
        ids[0].nodeId = ua::NodeId(0, ns0::Server_NamespaceArray);
        ids[1].nodeId = ua::NodeId(0, ns0::Server_ServerArray);
        for (auto& i : ids) i.attributeId = 13;  // Value
        auto values = c_.read(std::move(ids), ua::TimestampsToReturn::Neither, deadline());
        ++roundTrips;
        if (values.size() != 2 || !values[0].value)
            throw ua::client::Error(ua::StatusCode(0x80000000), "NamespaceArray unreadable");
        const auto* nsArray = values[0].value->array<ua::String>();
        if (nsArray == nullptr)
            throw ua::client::Error(ua::StatusCode(0x80000000), "NamespaceArray not String[]");
        ns_ = *nsArray;
        if (values[1].value)
            if (const auto* servers = values[1].value->array<ua::String>();
                servers != nullptr && !servers->empty())
                serverUri = servers->front();
        auto it = std::find(ns_.begin(), ns_.end(), kBaseUri);
        if (it == ns_.end()) return false;
        skillsNs_ = static_cast<ua::UInt16>(it - ns_.begin());
        return true;
    }

    void walk();
    std::vector<DetectedSkill> skills(const std::string& url, const std::string& componentUri,
                                      const std::string& componentName);
    std::size_t controllers() const { return controllers_.size(); }

  private:
    struct Node {
        ua::NodeId id;
        ua::QualifiedName browseName;
        std::string displayName;
        ua::NodeId typeDef;
        std::size_t depth = 0;
        std::size_t parent = SIZE_MAX;
        bool browsed = false;  // its children are known
        bool queued = false;   // in a Browse of the current round
        bool directIface = false;
        bool skillsFolder = false;  // the Skills folder of a controller: children are skills
        bool propsBrowsed = false;
        ua::NodeId nameProperty;
        std::vector<std::size_t> children;
    };
    struct Type {
        bool walked = false;  // parent and HasInterface known
        bool queued = false;
        std::optional<ua::NodeId> parent;  // none: a root (or ns0 reached)
        bool iface = false;
        std::optional<ua::QualifiedName> name;
    };
    struct Batch {
        std::vector<ua::BrowseDescription> descriptions;
        std::vector<std::function<void(const ua::BrowseResult&)>> handlers;
        void add(const ua::NodeId& node, ua::BrowseDirection dir, ua::UInt32 refType, bool subtypes,
                 ua::UInt32 classMask, ua::UInt32 resultMask,
                 std::function<void(const ua::BrowseResult&)> handler) {
            ua::BrowseDescription d;
            d.nodeId = node;
            d.browseDirection = dir;
            d.referenceTypeId = ua::NodeId(0, refType);
            d.includeSubtypes = subtypes;
            d.nodeClassMask = classMask;
            d.resultMask = resultMask;
            descriptions.push_back(std::move(d));
            handlers.push_back(std::move(handler));
        }
    };

    ua::client::Deadline deadline() const { return cfg_.requestTimeout; }
    void send(Batch& b) {
        // Chunks, for servers with a low MaxNodesPerBrowse (one request in the usual case).
        std::vector<ua::BrowseResult> results;
        for (std::size_t at = 0; at < b.descriptions.size(); at += kMaxPerBrowse) {
            std::size_t end = std::min(b.descriptions.size(), at + kMaxPerBrowse);
            std::vector<ua::BrowseDescription> chunk(
                b.descriptions.begin() + static_cast<std::ptrdiff_t>(at),
                b.descriptions.begin() + static_cast<std::ptrdiff_t>(end));
            auto part = c_.browse(std::move(chunk), 0, deadline());
            ++roundTrips;
            for (auto& r : part) results.push_back(std::move(r));
        }
        for (std::size_t i = 0; i < results.size() && i < b.handlers.size(); ++i) {
            // A server that pages its answer: fetch the rest of this node now (rare).
            std::size_t pages = 0;
            while (!results[i].continuationPoint.empty() && ++pages < 64) {
                auto next = c_.browseNext(results[i].continuationPoint, false, deadline());
                ++roundTrips;
                results[i].continuationPoint = next.continuationPoint;
                for (auto& r : next.references) results[i].references.push_back(std::move(r));
            }
            if (!results[i].statusCode.isBad()) b.handlers[i](results[i]);
        }
    }
    // A reference target on this server, or nullopt (another server, unknown URI).
    std::optional<ua::NodeId> local(const ua::ExpandedNodeId& x) const {
        if (x.serverIndex != 0) return std::nullopt;
        if (x.namespaceUri.empty()) return x.nodeId;
        auto it = std::find(ns_.begin(), ns_.end(), x.namespaceUri);
        if (it == ns_.end()) return std::nullopt;
        ua::NodeId id = x.nodeId;
        id.setNamespaceIndex(static_cast<ua::UInt16>(it - ns_.begin()));
        return id;
    }
    bool isIface(const ua::NodeId& id) const {
        return id == ua::NodeId(skillsNs_, types::ISkillControllerType.id);
    }
    ua::NodeId skillType() const { return ua::NodeId(skillsNs_, types::SkillType.id); }
    // The type implements ISkillControllerType (itself or a supertype); nullopt: not known yet.
    std::optional<bool> controllerType(const ua::NodeId& t) const {
        ua::NodeId cur = t;
        for (int guard = 0; guard < 64; ++guard) {
            if (cur.namespaceIndex() == 0) return false;  // ns0 types do not implement it
            auto it = types_.find(cur);
            if (it == types_.end() || !it->second.walked) return std::nullopt;
            if (it->second.iface) return true;
            if (!it->second.parent) return false;
            cur = *it->second.parent;
        }
        return false;
    }
    bool isController(const Node& n) const {
        return n.directIface || controllerType(n.typeDef).value_or(false);
    }
    void noteType(const ua::NodeId& t) {
        if (t.isNull() || t.namespaceIndex() == 0) return;
        types_.try_emplace(t);
    }
    std::size_t addNode(const ua::ReferenceDescription& r, std::size_t parent) {
        auto id = local(r.nodeId);
        if (!id) return SIZE_MAX;
        if (auto it = index_.find(*id); it != index_.end()) return it->second;
        if (nodes_.size() >= cfg_.maxNodes) return SIZE_MAX;
        Node n;
        n.id = *id;
        n.browseName = r.browseName;
        n.displayName = r.displayName.text;
        if (auto td = local(r.typeDefinition)) n.typeDef = *td;
        n.depth = parent == SIZE_MAX ? 0 : nodes_[parent].depth + 1;
        n.parent = parent;
        noteType(n.typeDef);
        nodes_.push_back(std::move(n));
        index_.emplace(*id, nodes_.size() - 1);
        return nodes_.size() - 1;
    }
    std::string text(const ua::NodeId& id) const {
        if (id.namespaceIndex() == 0 || id.namespaceIndex() >= ns_.size()) return id.toString();
        ua::NodeId bare = id;
        bare.setNamespaceIndex(0);
        return "nsu=" + ns_[id.namespaceIndex()] + ";" + bare.toString();
    }
    TypeName typeName(const ua::NodeId& t) const {
        TypeName out;
        out.uri = t.namespaceIndex() < ns_.size() ? ns_[t.namespaceIndex()] : std::string();
        out.id = t.isNumeric() ? t.numeric() : 0;
        if (auto it = types_.find(t); it != types_.end() && it->second.name)
            out.name = it->second.name->name;
        return out;
    }

    Client& c_;
    const DetectorConfig& cfg_;
    std::vector<std::string> ns_;
    ua::UInt16 skillsNs_ = 0;
    std::vector<Node> nodes_;
    std::map<ua::NodeId, std::size_t> index_;
    std::map<ua::NodeId, Type> types_;
    std::vector<std::size_t> controllers_;
};

// Rounds of one Browse request each: the next level of the breadth-first walk, the next step
// up of every type not yet known, and the Skills folders / Name properties of the controllers
// found so far; until nothing is left to ask.
void Examiner::walk() {
    {
        Node objects;
        objects.id = ua::NodeId(0, ns0::ObjectsFolder);
        nodes_.push_back(objects);
        index_.emplace(objects.id, 0);
        // SkillType ends every skill's chain: no need to walk above it.
        Type& st = types_[skillType()];
        st.walked = true;
        st.name = ua::QualifiedName{skillsNs_, std::string(types::SkillType.name)};
    }
    std::vector<std::size_t> frontier{0};
    for (std::size_t round = 0; round < 256; ++round) {
        Batch b;
        auto browseChildren = [&](std::size_t i) {
            nodes_[i].queued = true;
            b.add(nodes_[i].id, ua::BrowseDirection::Forward, ns0::HierarchicalReferences, true,
                  1 /* Object */, kResultAll, [this, i](const ua::BrowseResult& r) {
                      nodes_[i].browsed = true;
                      for (const auto& ref : r.references) {
                          if (!ref.isForward) continue;
                          std::size_t c = addNode(ref, i);
                          if (c == SIZE_MAX || c == i) continue;
                          if (std::find(nodes_[i].children.begin(), nodes_[i].children.end(), c) ==
                              nodes_[i].children.end())
                              nodes_[i].children.push_back(c);
                      }
                  });
            b.add(nodes_[i].id, ua::BrowseDirection::Forward, ns0::HasInterface, false, 0,
                  kResultBrowseName, [this, i](const ua::BrowseResult& r) {
                      for (const auto& ref : r.references)
                          if (auto t = local(ref.nodeId); t && isIface(*t))
                              nodes_[i].directIface = true;
                  });
        };
        for (std::size_t i : frontier) browseChildren(i);
        // Controllers found so far: their Skills folder and Name property, even below the
        // depth limit.
        for (std::size_t i = 0; i < nodes_.size(); ++i) {
            Node& n = nodes_[i];
            if (!isController(n)) continue;
            if (!n.browsed && !n.queued) browseChildren(i);
            for (std::size_t c : n.children)
                if (nodes_[c].browseName.name == names::Skills) {
                    nodes_[c].skillsFolder = true;
                    if (!nodes_[c].browsed && !nodes_[c].queued) browseChildren(c);
                }
            if (!n.propsBrowsed) {
                n.propsBrowsed = true;
                b.add(n.id, ua::BrowseDirection::Forward, ns0::HasProperty, true, 2,
                      kResultBrowseName, [this, i](const ua::BrowseResult& r) {
                          for (const auto& ref : r.references)
                              if (ref.browseName.name == "Name")
                                  if (auto id = local(ref.nodeId)) nodes_[i].nameProperty = *id;
                      });
            }
        }
        // One step up the type hierarchy for every type not known yet.
        for (auto& [id, t] : types_) {
            if (t.walked || t.queued) continue;
            t.queued = true;
            const ua::NodeId tid = id;
            b.add(tid, ua::BrowseDirection::Inverse, ns0::HasSubtype, false, 0, kResultBrowseName,
                  [this, tid](const ua::BrowseResult& r) {
                      Type& me = types_[tid];
                      me.walked = true;
                      for (const auto& ref : r.references) {
                          auto p = local(ref.nodeId);
                          if (!p) continue;
                          me.parent = *p;
                          if (p->namespaceIndex() != 0) types_[*p].name = ref.browseName;
                          noteType(*p);
                          break;
                      }
                  });
            b.add(tid, ua::BrowseDirection::Forward, ns0::HasInterface, false, 0, kResultBrowseName,
                  [this, tid](const ua::BrowseResult& r) {
                      for (const auto& ref : r.references)
                          if (auto t2 = local(ref.nodeId); t2 && isIface(*t2))
                              types_[tid].iface = true;
                  });
        }
        if (b.descriptions.empty()) break;
        send(b);
        for (auto& n : nodes_) n.queued = false;
        for (auto& [id, t] : types_) t.queued = false;
        // The next level: children of this level, not below a Skills folder (skills are
        // leaves for this walk), not the Server object (never holds a controller).
        std::vector<std::size_t> next;
        for (std::size_t i : frontier) {
            Node& n = nodes_[i];
            if (n.directIface)
                for (std::size_t c : n.children)
                    if (nodes_[c].browseName.name == names::Skills) nodes_[c].skillsFolder = true;
            if (n.skillsFolder) continue;
            for (std::size_t c : n.children) {
                Node& child = nodes_[c];
                if (child.browsed || child.depth != n.depth + 1 || child.depth >= cfg_.maxDepth)
                    continue;
                if (child.id == ua::NodeId(0, ns0::Server)) continue;
                if (std::find(next.begin(), next.end(), c) == next.end()) next.push_back(c);
            }
        }
        frontier = std::move(next);
    }
    for (std::size_t i = 0; i < nodes_.size(); ++i)
        if (isController(nodes_[i])) controllers_.push_back(i);

    // One Read for what the Browses did not give: the controllers' Name values and the
    // BrowseNames of concrete skill types (no subtype named them).
    std::vector<ua::ReadValueId> ids;
    std::vector<std::function<void(const ua::DataValue&)>> handlers;
    for (std::size_t i : controllers_) {
        if (nodes_[i].nameProperty.isNull()) continue;
        ua::ReadValueId r;
        r.nodeId = nodes_[i].nameProperty;
        r.attributeId = 13;
        ids.push_back(std::move(r));
        handlers.push_back([this, i](const ua::DataValue& v) {
            if (!v.value) return;
            if (const auto* lt = v.value->scalar<ua::LocalizedText>(); lt && !lt->text.empty())
                nodes_[i].displayName = lt->text;
            else if (const auto* s = v.value->scalar<ua::String>(); s && !s->empty())
                nodes_[i].displayName = *s;
        });
    }
    for (auto& [id, t] : types_) {
        if (t.name) continue;
        ua::ReadValueId r;
        r.nodeId = id;
        r.attributeId = 3;  // BrowseName
        ids.push_back(std::move(r));
        const ua::NodeId tid = id;
        handlers.push_back([this, tid](const ua::DataValue& v) {
            if (v.value)
                if (const auto* q = v.value->scalar<ua::QualifiedName>()) types_[tid].name = *q;
        });
    }
    if (!ids.empty()) {
        auto values = c_.read(std::move(ids), ua::TimestampsToReturn::Neither, deadline());
        ++roundTrips;
        for (std::size_t i = 0; i < values.size() && i < handlers.size(); ++i)
            if (!values[i].statusOrGood().isBad()) handlers[i](values[i]);
    }
}

std::vector<DetectedSkill> Examiner::skills(const std::string& url, const std::string& componentUri,
                                            const std::string& componentName) {
    std::vector<DetectedSkill> out;
    const ua::NodeId top = skillType();
    for (std::size_t ci : controllers_) {
        const Node& ctrl = nodes_[ci];
        for (std::size_t fi : ctrl.children) {
            if (nodes_[fi].browseName.name != names::Skills) continue;
            for (std::size_t si : nodes_[fi].children) {
                const Node& s = nodes_[si];
                // The type chain from the server's hierarchy; not a skill unless it ends at
                // SkillType.
                std::vector<TypeName> chain;
                ua::NodeId cur = s.typeDef;
                bool reached = false;
                for (int guard = 0; guard < 64 && !cur.isNull(); ++guard) {
                    chain.push_back(typeName(cur));
                    if (cur == top) {
                        reached = true;
                        break;
                    }
                    auto it = types_.find(cur);
                    if (it == types_.end() || !it->second.parent) break;
                    cur = *it->second.parent;
                }
                if (!reached) continue;
                DetectedSkill d;
                d.endpointUrl = url;
                d.node = s.id;
                d.nodeText = text(s.id);
                d.name = s.browseName.name;
                d.type = chain.front();
                d.typeChain = std::move(chain);
                d.componentUri = componentUri;
                d.componentName = componentName;
                d.controller = ctrl.id;
                d.controllerName =
                    ctrl.displayName.empty() ? ctrl.browseName.name : ctrl.displayName;
                out.push_back(std::move(d));
            }
        }
    }
    return out;
}

Examination examine(const std::string& url, const std::optional<ua::ApplicationDescription>& app,
                    const DetectorConfig& cfg) {
    Examination ex;
    auto t0 = Clock::now();
    ua::client::ClientConfig cc;
    cc.applicationName = "pnp skill detector";
    cc.applicationUri = "urn:pnp:skill-detector";
    cc.requestTimeout = cfg.requestTimeout;
    cc.connectTimeout = cfg.connectTimeout;
    cc.closeTimeout = std::chrono::milliseconds(200);
    // A broken connection must show as a failed health check (skills removed, server
    // examined afresh), not be papered over by a silent reconnect.
    cc.reconnect.enabled = false;
    auto client = std::make_shared<Client>(cc);
    try {
        client->connect(url);
        Examiner x(*client, cfg);
        std::string serverUri;
        bool hasSkills = x.readNamespaces(serverUri);
        ex.applicationUri = app ? app->applicationUri : serverUri;
        if (app) {
            ex.applicationName = app->applicationName.text;
        } else {
            // Not from discovery: FindServers on the open channel names the application.
            auto found = client->findServers({}, cfg.requestTimeout);
            ++x.roundTrips;
            for (const auto& a : found)
                if (a.applicationUri == ex.applicationUri || found.size() == 1) {
                    ex.applicationName = a.applicationName.text;
                    if (ex.applicationUri.empty()) ex.applicationUri = a.applicationUri;
                    break;
                }
        }
        if (hasSkills) {
            x.walk();
            ex.skills = x.skills(url, ex.applicationUri, ex.applicationName);
            ex.controllers = x.controllers();
            ex.status = ServerState::Status::Skills;
        } else {
            ex.status = ServerState::Status::NoSkills;
        }
        ex.roundTrips = x.roundTrips;
        ex.client = std::move(client);
    } catch (const std::exception& e) {
        ex.status = ServerState::Status::Unreachable;
        ex.error = e.what();
    }
    ex.ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    return ex;
}

// The liveness check: one Read of ServerStatus/State (Running = 0).
bool healthy(Client& c, const DetectorConfig& cfg, std::string& error) {
    try {
        ua::ReadValueId r;
        r.nodeId = ua::NodeId(0, ns0::Server_ServerStatus_State);
        r.attributeId = 13;
        auto v = c.read({r}, ua::TimestampsToReturn::Neither, cfg.requestTimeout);
        if (v.empty() || v[0].statusOrGood().isBad() || !v[0].value) {
            error = "ServerStatus/State unreadable";
            return false;
        }
        if (const auto* s = v[0].value->scalar<ua::Int32>(); s && *s != 0) {
            error = "server state " + std::to_string(*s);
            return false;
        }
        return true;
    } catch (const std::exception& e) {
        error = e.what();
        return false;
    }
}

}  // namespace

struct SkillDetector::Impl {
    struct Entry {
        ServerState state;
        std::optional<ua::ApplicationDescription> app;
        std::uint64_t gen = 0;
        bool queued = false, busy = false, again = false;
        std::shared_ptr<Client> client;
        std::vector<DetectedSkill> skills;
    };
    using Event = std::pair<DetectedSkill, bool>;

    mdns::Mdns* mdns;
    DetectorConfig config;
    mutable std::mutex mutex;
    std::condition_variable_any work;
    std::map<std::string, Entry> entries;
    std::deque<std::string> queue;
    std::uint64_t nextGen = 1;
    std::vector<std::jthread> workers;
    std::jthread health;
    std::unique_ptr<ua::discovery::DiscoveryWatcher> watcher;
    bool running = false;

    std::mutex callbackMutex;
    std::vector<ChangeCallback> callbacks;

    mutable std::mutex versionMutex;
    mutable std::condition_variable versionCv;
    std::uint64_t version = 0;

    // Under mutex.
    void enqueue(Entry& e, const std::string& url, bool front) {
        if (e.busy) {
            e.again = true;
            return;
        }
        if (e.queued) return;
        e.queued = true;
        if (front)
            queue.push_front(url);
        else
            queue.push_back(url);
        work.notify_one();
    }
    // Under mutex: the entry's skills go (events returned).
    static void dropSkills(Entry& e, std::vector<Event>& events) {
        for (auto& s : e.skills) events.emplace_back(std::move(s), false);
        e.skills.clear();
        e.state.skills = 0;
        e.state.controllers = 0;
    }
    void fire(std::vector<Event>& events) {
        if (!events.empty()) {
            std::vector<ChangeCallback> cbs;
            {
                std::lock_guard l(callbackMutex);
                cbs = callbacks;
            }
            for (auto& [s, added] : events)
                for (auto& cb : cbs) cb(s, added);
        }
        bump();
    }
    void bump() {
        {
            std::lock_guard l(versionMutex);
            ++version;
        }
        versionCv.notify_all();
    }

    void discovered(const ua::discovery::DiscoveredServer& s, bool up) {
        std::vector<Event> events;
        std::shared_ptr<Client> gone;
        {
            std::lock_guard l(mutex);
            if (up) {
                auto [it, fresh] = entries.try_emplace(s.discoveryUrl);
                Entry& e = it->second;
                if (fresh) {
                    e.gen = nextGen++;
                    e.state.url = s.discoveryUrl;
                }
                e.state.discovered = true;
                if (s.application) e.app = s.application;
                // New, or failed before: examine now (discovery says it is there).
                if (fresh || e.state.status == ServerState::Status::Unreachable)
                    enqueue(e, s.discoveryUrl, true);
            } else {
                auto it = entries.find(s.discoveryUrl);
                if (it == entries.end()) return;
                it->second.state.discovered = false;
                if (!it->second.state.manual) {
                    dropSkills(it->second, events);
                    gone = std::move(it->second.client);
                    entries.erase(it);
                }
            }
        }
        gone.reset();  // CloseSession outside the lock
        fire(events);
    }

    void runWorker(std::stop_token stop) {
        std::unique_lock l(mutex);
        while (!stop.stop_requested()) {
            if (queue.empty()) {
                work.wait(l, stop, [&] { return !queue.empty(); });
                continue;
            }
            std::string url = std::move(queue.front());
            queue.pop_front();
            auto it = entries.find(url);
            if (it == entries.end()) continue;
            Entry& e = it->second;
            e.queued = false;
            if (e.busy) {
                e.again = true;
                continue;
            }
            e.busy = true;
            const std::uint64_t gen = e.gen;
            auto client = e.client;
            auto app = e.app;
            const bool check = client != nullptr;
            l.unlock();

            std::vector<Event> events;
            std::optional<Examination> ex;
            std::string error;
            bool ok = true;
            if (check) {
                ok = healthy(*client, config, error);
            } else {
                ex = examine(url, app, config);
            }
            client.reset();
            std::shared_ptr<Client> discard;

            l.lock();
            it = entries.find(url);
            if (it == entries.end() || it->second.gen != gen) {
                // Removed (or removed and added again) meanwhile: the result is stale.
                if (ex) discard = std::move(ex->client);
            } else {
                Entry& cur = it->second;
                cur.busy = false;
                if (check && !ok) {
                    dropSkills(cur, events);
                    discard = std::move(cur.client);
                    cur.state.status = ServerState::Status::Unreachable;
                    cur.state.error = error;
                } else if (ex) {
                    apply(cur, std::move(*ex), events, discard);
                }
                if (cur.again) {
                    cur.again = false;
                    enqueue(cur, url, true);
                }
            }
            l.unlock();
            discard.reset();
            fire(events);
            l.lock();
        }
    }

    // Under mutex: an examination's result replaces the entry's skills.
    static void apply(Entry& e, Examination&& ex, std::vector<Event>& events,
                      std::shared_ptr<Client>& discard) {
        e.state.status = ex.status;
        e.state.error = ex.error;
        e.state.examineMs = ex.ms;
        e.state.roundTrips = ex.roundTrips;
        if (!ex.applicationUri.empty()) e.state.applicationUri = ex.applicationUri;
        if (!ex.applicationName.empty()) e.state.applicationName = ex.applicationName;
        discard = std::move(e.client);
        e.client = std::move(ex.client);
        std::map<std::string, const DetectedSkill*> fresh;
        for (const auto& s : ex.skills) fresh.emplace(s.nodeText, &s);
        std::set<std::string> unchanged;
        for (auto& old : e.skills) {
            auto f = fresh.find(old.nodeText);
            if (f != fresh.end() && f->second->typeChain == old.typeChain &&
                f->second->name == old.name && f->second->controller == old.controller) {
                unchanged.insert(old.nodeText);  // no event
                continue;
            }
            events.emplace_back(std::move(old), false);
        }
        for (const auto& s : ex.skills)
            if (!unchanged.contains(s.nodeText)) events.emplace_back(s, true);
        e.skills = std::move(ex.skills);
        e.state.skills = e.skills.size();
        e.state.controllers = ex.controllers;
    }

    void runHealth(std::stop_token stop) {
        std::mutex m;
        std::condition_variable_any cv;
        while (!stop.stop_requested()) {
            {
                std::unique_lock l(m);
                cv.wait_for(l, stop, config.healthInterval, [] { return false; });
            }
            if (stop.stop_requested()) break;
            std::lock_guard l(mutex);
            for (auto& [url, e] : entries)
                if (!e.busy && !e.queued) enqueue(e, url, false);
        }
    }
};

SkillDetector::SkillDetector(mdns::Mdns* mdns, DetectorConfig config)
    : impl_(std::make_unique<Impl>()) {
    impl_->mdns = mdns;
    impl_->config = std::move(config);
    if (impl_->config.workers == 0) impl_->config.workers = 1;
}

SkillDetector::~SkillDetector() { stop(); }

void SkillDetector::start() {
    Impl& d = *impl_;
    {
        std::lock_guard l(d.mutex);
        if (d.running) return;
        d.running = true;
    }
    for (std::size_t i = 0; i < d.config.workers; ++i)
        d.workers.emplace_back([&d](std::stop_token s) { d.runWorker(s); });
    d.health = std::jthread([&d](std::stop_token s) { d.runHealth(s); });
    if (d.config.useDiscovery) {
        d.watcher = std::make_unique<ua::discovery::DiscoveryWatcher>(
            d.mdns, d.config.watcher,
            [&d](const ua::discovery::DiscoveredServer& s, bool up) { d.discovered(s, up); });
        d.watcher->start();
    }
}

void SkillDetector::stop() {
    Impl& d = *impl_;
    {
        std::lock_guard l(d.mutex);
        if (!d.running) return;
        d.running = false;
    }
    if (d.watcher) d.watcher->stop();
    d.watcher.reset();
    d.health = {};
    for (auto& w : d.workers) w.request_stop();
    d.work.notify_all();
    d.workers.clear();
    {
        std::lock_guard l(d.mutex);
        d.queue.clear();
        for (auto& [url, e] : d.entries) {
            e.queued = false;
            e.busy = false;
            e.client.reset();  // sessions closed; skills stay listed until restart
        }
    }
}

void SkillDetector::addServer(const std::string& url) {
    std::string key = ua::discovery::normaliseUrl(url);
    if (key.empty()) key = url;
    Impl& d = *impl_;
    std::lock_guard l(d.mutex);
    auto [it, fresh] = d.entries.try_emplace(key);
    Impl::Entry& e = it->second;
    if (fresh) {
        e.gen = d.nextGen++;
        e.state.url = key;
    }
    e.state.manual = true;
    if (fresh || e.state.status == ServerState::Status::Unreachable) d.enqueue(e, key, true);
}

void SkillDetector::removeServer(const std::string& url) {
    std::string key = ua::discovery::normaliseUrl(url);
    if (key.empty()) key = url;
    Impl& d = *impl_;
    std::vector<Impl::Event> events;
    std::shared_ptr<Client> gone;
    {
        std::lock_guard l(d.mutex);
        auto it = d.entries.find(key);
        if (it == d.entries.end()) return;
        it->second.state.manual = false;
        if (it->second.state.discovered) return;  // discovery still lists it
        Impl::dropSkills(it->second, events);
        gone = std::move(it->second.client);
        d.entries.erase(it);
    }
    gone.reset();
    d.fire(events);
}

std::vector<DetectedSkill> SkillDetector::find(const ModelNode& type) const {
    std::lock_guard l(impl_->mutex);
    std::vector<DetectedSkill> out;
    for (const auto& [url, e] : impl_->entries)
        for (const auto& s : e.skills)
            if (s.isA(type)) out.push_back(s);
    return out;
}

std::vector<DetectedSkill> SkillDetector::all() const {
    std::lock_guard l(impl_->mutex);
    std::vector<DetectedSkill> out;
    for (const auto& [url, e] : impl_->entries)
        out.insert(out.end(), e.skills.begin(), e.skills.end());
    return out;
}

std::vector<ServerState> SkillDetector::servers() const {
    std::lock_guard l(impl_->mutex);
    std::vector<ServerState> out;
    for (const auto& [url, e] : impl_->entries) {
        out.push_back(e.state);
        if (e.app && out.back().applicationUri.empty())
            out.back().applicationUri = e.app->applicationUri;
        if (e.app && out.back().applicationName.empty())
            out.back().applicationName = e.app->applicationName.text;
    }
    return out;
}

void SkillDetector::onChange(ChangeCallback callback) {
    std::lock_guard l(impl_->callbackMutex);
    impl_->callbacks.push_back(std::move(callback));
}

bool SkillDetector::waitUntil(const std::function<bool(const SkillDetector&)>& pred,
                              std::chrono::milliseconds timeout) const {
    const auto end = Clock::now() + timeout;
    for (;;) {
        std::uint64_t seen;
        {
            std::lock_guard l(impl_->versionMutex);
            seen = impl_->version;
        }
        if (pred(*this)) return true;
        std::unique_lock l(impl_->versionMutex);
        if (!impl_->versionCv.wait_until(l, end, [&] { return impl_->version != seen; }))
            return pred(*this);
    }
}

}  // namespace pnp::skill::detector
