// The client side of discovery: reports OPC UA servers appearing and disappearing, from
// mDNS announcements (_opcua-tcp._tcp) and from polling FindServersOnNetwork on every LDS-ME
// it knows of — hierarchically: an LDS-ME listed by another one is polled too, so a client on
// the cell bus sees the workstations and, through them, their devices. Each new server's
// endpoints (GetEndpoints: each carries the ApplicationDescription) are fetched before it is
// reported. The base of the skill detector.
//
// A server is identified by its discovery URL (normalised: host lower case, explicit port,
// no trailing '/'); it is up while at least one source lists it (mDNS or an LDS-ME), and
// reported down when the last source lost it (goodbye, TTL, an LDS-ME no longer listing it or
// no longer answering).
#pragma once

#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "mdns/mdns.hpp"
#include "ua/discovery/browsing_worker.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::discovery {

struct DiscoveredServer {
    std::string discoveryUrl;  // normalised; the identity
    std::string name;          // mDNS instance or ServerOnNetwork.serverName
    std::vector<std::string> capabilities;
    std::set<std::string> sources;  // "mdns" and / or the URLs of the LDS-MEs listing it
    std::optional<ApplicationDescription> application;  // from GetEndpoints (fetchDetails)
    std::vector<EndpointDescription> endpoints;         // from GetEndpoints (fetchDetails)
    std::string detailsError;                           // why they could not be fetched, if so
};

struct WatcherConfig {
    bool followLds = true;             // poll FindServersOnNetwork on every LDS-ME seen
    bool fetchDetails = true;          // GetEndpoints before reporting a server
    std::vector<std::string> ldsUrls;  // polled in any case
    std::chrono::milliseconds pollInterval{250};
    std::chrono::milliseconds requestTimeout{1000};
    std::size_t maxServers = 10000;  // bound on what the network can make us hold
    std::size_t maxLds = 64;         // LDS-MEs polled at most
};

// Normalised discovery URL ("" when it is not an opc.tcp URL).
std::string normaliseUrl(const std::string& url);

class DiscoveryWatcher {
  public:
    using Callback = std::function<void(const DiscoveredServer&, bool up)>;
    // mdns may be null (polling of config.ldsUrls only). The callback runs on the watcher's
    // thread.
    DiscoveryWatcher(mdns::Mdns* mdns, WatcherConfig config, Callback callback);
    ~DiscoveryWatcher();
    DiscoveryWatcher(const DiscoveryWatcher&) = delete;
    DiscoveryWatcher& operator=(const DiscoveryWatcher&) = delete;

    void start();
    void stop();
    std::vector<DiscoveredServer> servers() const;  // those reported up

  private:
    struct Entry {
        DiscoveredServer server;
        bool reported = false;
    };
    struct MdnsEvent {
        mdns::DiscoveredService service;
        bool up;
    };
    void run(std::stop_token stop);
    void addSource(const std::string& url, const std::string& name,
                   const std::vector<std::string>& caps, const std::string& source);
    void removeSource(const std::string& url, const std::string& source);
    void pollLds(const std::string& ldsUrl);
    void settle();  // reports what changed

    mdns::Mdns* mdns_;
    WatcherConfig config_;
    Callback callback_;
    mutable std::mutex mutex_;
    std::condition_variable_any wake_;
    std::deque<MdnsEvent> events_;  // from the mDNS thread
    std::map<std::string, Entry>
        servers_;  // by normalised URL (watcher thread; copies under mutex_)
    std::map<std::string, std::set<std::string>> ldsListed_;  // LDS URL -> URLs it listed
    BrowsingWorker worker_;                                   // last: stopped before the rest goes
};

}  // namespace pnp::ua::discovery
