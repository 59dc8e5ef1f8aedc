// The skill detector (docs/skill_detector.md): which skills the OPC UA servers on the network
// offer, by skill type. Driven by the DiscoveryWatcher (mDNS and / or LDS-ME polling), or by
// addServer() for a server known by URL.
//
//   SkillDetector detector(&mdns, {.watcher = {.ldsUrls = {lds}}});
//   detector.onChange([](const DetectedSkill& s, bool added) { ... });
//   detector.start();
//   for (auto& s : detector.find(types::GripperSkillType)) ...  // Grasp, Release, Move ...
//
// For each server: connect, read the NamespaceArray (no urn:pnp:ua:skills: no skills, no
// further requests), then a bounded breadth-first Browse from Objects, one Browse request per
// level, to find the skill controllers (HasInterface ISkillControllerType on the instance or
// on its type or a supertype); their Skills folders list the skills, whose type is taken
// from the server's type hierarchy (HasTypeDefinition, then inverse HasSubtype up to
// SkillType) — never from a browse name. A server is checked every healthInterval (one Read)
// and its skills are removed when it stops answering or discovery reports it gone.
//
// Threads: the watcher's, a health thread and `workers` examination threads. Every public
// member function is thread-safe; change callbacks run on a worker thread, without the
// detector's lock (they may call find() & co., not the destructor).
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "mdns/mdns.hpp"
#include "skill/model/model.hpp"
#include "ua/discovery/watcher.hpp"
#include "ua/types/ns0_enums.hpp"

namespace pnp::skill::detector {

// A type of the skill model (or any ObjectType) by namespace URI and numeric id, with its
// BrowseName's name; owns its strings (ModelNode only views them).
struct TypeName {
    std::string uri;
    ua::UInt32 id = 0;  // 0 for a type with a non-numeric NodeId
    std::string name;
    bool matches(const ModelNode& t) const { return id == t.id && uri == t.uri; }
    bool operator==(const TypeName&) const = default;
};

struct DetectedSkill {
    std::string endpointUrl;          // the server's (discovery) URL
    ua::NodeId node;                  // the skill instance, in the server's namespace indices
    std::string nodeText;             // "nsu=<uri>;s=..." (stable across servers and restarts)
    std::string name;                 // BrowseName's name of the instance
    TypeName type;                    // concrete type (its HasTypeDefinition)
    std::vector<TypeName> typeChain;  // type, its supertype, ..., SkillType
    std::string componentUri;         // the server's ApplicationUri
    std::string componentName;        // its ApplicationName
    ua::NodeId controller;
    std::string controllerName;  // the interface's Name property, else its DisplayName
    bool isA(const ModelNode& t) const {
        for (const auto& c : typeChain)
            if (c.matches(t)) return true;
        return false;
    }
};

// What the detector knows about a server.
struct ServerState {
    enum class Status {
        Examining,    // queued or being examined
        Skills,       // examined: has the skill namespace (skills may still be none)
        NoSkills,     // examined: no urn:pnp:ua:skills in its NamespaceArray
        Unreachable,  // connect, examination or health check failed; retried every check
    };
    std::string url;
    std::string applicationUri;
    std::string applicationName;
    Status status = Status::Examining;
    std::size_t skills = 0;
    std::size_t controllers = 0;
    std::string error;           // why Unreachable
    double examineMs = 0;        // duration of the last examination (connect included)
    std::size_t roundTrips = 0;  // service requests of the last examination (connect excluded)
    bool discovered = false;     // listed by discovery
    bool manual = false;         // addServer()
};
std::string_view toString(ServerState::Status s);

struct DetectorConfig {
    ua::discovery::WatcherConfig watcher;
    bool useDiscovery = true;                        // false: addServer() only, no watcher
    std::chrono::milliseconds requestTimeout{1000};  // per request
    // Per connect: a secured one (GetEndpoints, OpenSecureChannel with RSA on both sides,
    // CreateSession and ActivateSession with signatures) needs more than a request does on
    // a loaded machine.
    std::chrono::milliseconds connectTimeout{3000};
    std::chrono::milliseconds healthInterval{250};
    std::size_t maxDepth = 4;     // Browse levels below Objects
    std::size_t maxNodes = 2000;  // Objects browsed per server at most
    std::size_t workers = 4;      // servers examined in parallel
};

class SkillDetector {
  public:
    using ChangeCallback = std::function<void(const DetectedSkill&, bool added)>;

    // mdns may be null (config.watcher.ldsUrls only, or addServer()).
    SkillDetector(mdns::Mdns* mdns, DetectorConfig config);
    ~SkillDetector();  // stop()
    SkillDetector(const SkillDetector&) = delete;
    SkillDetector& operator=(const SkillDetector&) = delete;

    void start();  // idempotent
    void stop();   // joins every thread; no callbacks afterwards

    // A server by URL, without discovery (tests, `--url`): examined now, kept (and checked)
    // until removeServer().
    void addServer(const std::string& url);
    void removeServer(const std::string& url);

    // Skills of this type or of a subtype of it (match anywhere in the type chain).
    std::vector<DetectedSkill> find(const ModelNode& type) const;
    std::vector<DetectedSkill> all() const;
    std::vector<ServerState> servers() const;

    // Called after a skill appeared (added) or went; see the threads note above.
    void onChange(ChangeCallback callback);

    // Blocks until pred(*this) holds or the timeout passes; re-evaluated on every change
    // and every examination result. For tests and CLIs.
    bool waitUntil(const std::function<bool(const SkillDetector&)>& pred,
                   std::chrono::milliseconds timeout) const;

    struct Impl;  // skill_detector.cpp

  private:
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::skill::detector
