// The dashboard's OPC UA side: what the cell looks like right now, and every change of it as
// a small JSON message (docs/dashboard.md).
//
//   CellView view(&mdns, {.ldsUrls = {lds}, .worldUrl = world}, [&](std::string m) {
//       web.broadcast(std::move(m));
//   });
//   view.start();
//   std::string first = view.snapshot().dump();
//
// Sources: a DiscoveryWatcher (mDNS and / or the LDS-MEs: servers, their capabilities and
// which LDS-ME lists them = the hierarchy) feeds a SkillDetector (addServer / removeServer:
// one watcher, not two); each detected skill gets a SkillClient on one monitoring session
// per server (its state, parameters, transition events with the event's Time, its
// FinalResultData read when a run ends); a skill of ExecuteProcessSkillType is the MES, whose
// Record (FinalResultData) becomes the `process` message; the simulator's ground truth
// (urn:pnp:sim:world) becomes `world` messages at most `worldRate` per second.
//
// Threads: the watcher's and the detector's (callbacks only record and queue), one
// monitoring thread that does every blocking OPC UA call (each with a deadline), the
// clients' dispatch threads (transition events: a message at once, no blocking), one world
// thread (coalescing). `publish` is called from any of them, never under a lock of ours
// held by another thread for long; it must not block.
#pragma once

#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "mdns/mdns.hpp"
#include "ua/types/builtin.hpp"

namespace pnp::dashboard {

struct CellViewOptions {
    std::vector<std::string> ldsUrls;  // LDS-MEs polled (and those they list)
    std::vector<std::string> urls;     // servers watched without discovery (tests, scripts)
    std::string worldUrl;              // the simulator's ground truth server; "" = none
    bool discovery = true;             // false: `urls` only
    std::chrono::milliseconds pollInterval{250};
    std::chrono::milliseconds requestTimeout{1000};
    std::chrono::milliseconds connectTimeout{3000};
    std::size_t maxServers = 1000;
    std::size_t maxSkills = 10000;
    std::size_t timelineLength = 200;  // transitions kept for a snapshot
    std::size_t statsLength = 200;     // per list of stats
    double worldRate = 30;             // `world` messages per second at most
};

// What an action needs to reach a skill.
struct SkillTarget {
    std::string id;
    std::string endpointUrl;
    ua::NodeId node;
    std::string name;
    std::string type;
};

class CellView {
  public:
    using Publish = std::function<void(std::string message)>;

    // mdns may be null (no multicast: ldsUrls / urls only).
    CellView(mdns::Mdns* mdns, CellViewOptions options, Publish publish);
    ~CellView();  // stop()
    CellView(const CellView&) = delete;
    CellView& operator=(const CellView&) = delete;

    void start();
    void stop();  // joins every thread; no publish afterwards

    // {"type":"snapshot", servers, components, skills, process, world, timeline, stats}
    nlohmann::json snapshot() const;
    std::optional<SkillTarget> skill(const std::string& id) const;
    // The MES's ExecuteProcess skill, if one is detected.
    std::optional<SkillTarget> processSkill() const;
    // A server with skills the login is checked on (the MES's first), "" = none.
    std::string anySkillServer() const;

    struct Impl;

  private:
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::dashboard
