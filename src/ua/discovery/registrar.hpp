// The server side of discovery: a server finds its LDS-ME (by mDNS, or a configured URL),
// registers with it (RegisterServer2 with an MdnsDiscoveryConfiguration, so that the LDS-ME
// announces it), re-registers periodically and whenever the LDS-ME set changes, and
// unregisters (isOnline = false) when stopped.
//
// Which LDS-ME, when several answer (docs/discovery.md, "Choosing the LDS-ME"):
//   1. a configured URL wins, and nothing else is tried;
//   2. otherwise the mDNS announcements with caps LDS, of the same discovery group (TXT dg=,
//      absent = ""), not this server's own LDS-ME, and — when this server is itself an
//      LDS-ME of level L — only those of a level below L (an LDS-ME without lvl= counts as 0);
//   3. of those the highest level (the nearest supervisor: a device on a workstation's
//      segment picks the workstation over the cell bus), then the lowest instance name,
//      then the lowest URL.
// The rule depends only on what is announced, never on start order; it is evaluated again
// whenever an announcement comes or goes, and a registration moves to a new choice. When no
// candidate is announced any more, the registrar stays with the current LDS-ME and keeps
// trying it (an mDNS record can lapse while the LDS-ME is still reachable).
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "mdns/mdns.hpp"
#include "ua/client/client.hpp"
#include "ua/discovery/browsing_worker.hpp"

namespace pnp::ua::server {
class Server;
}

namespace pnp::ua::discovery {

struct RegistrarConfig {
    std::string ldsUrl;           // a configured LDS-ME: only this one ("" = choose by mDNS)
    std::string discoveryGroup;   // register only within this group (TXT dg=)
    std::optional<int> ownLevel;  // this server is itself an LDS-ME of this level
    std::string ownInstance;      // ... announced under this mDNS instance name (never chosen)
    std::string mdnsServerName;   // the name the LDS-ME announces us by; default from the config
    std::vector<std::string> capabilities;   // announced for us; default {"NA"}
    std::vector<std::string> discoveryUrls;  // default: the server's endpoint URL
    // Re-registration period; below the LDS-ME's registration expiry (default 2 s).
    std::chrono::milliseconds interval{500};
    std::chrono::milliseconds retryInterval{100};  // after a failed registration
    std::chrono::milliseconds requestTimeout{1000};
    // Opening the (secured) channel to the LDS-ME: GetEndpoints and OpenSecureChannel with
    // RSA on both sides.
    std::chrono::milliseconds connectTimeout{3000};
};

class Registrar {
  public:
    // mdns may be null when config.ldsUrl is set. The server must have been started (its
    // endpoint URL is registered).
    Registrar(server::Server& server, mdns::Mdns* mdns, RegistrarConfig config);
    ~Registrar();
    Registrar(const Registrar&) = delete;
    Registrar& operator=(const Registrar&) = delete;

    void start();
    // Unregisters from the current LDS-ME (bounded by requestTimeout) and stops.
    void stop();

    std::string currentLds() const;       // "" while none is chosen
    std::uint64_t registrations() const;  // successful RegisterServer2 calls
    // Called (on the registrar's thread) after the first successful registration with an
    // LDS-ME (again after a move to another one), for logs and tests.
    void onLdsChanged(std::function<void(const std::string& ldsUrl)> callback);

  private:
    std::string choose() const;
    bool registerWith(const std::string& url, bool online);
    void run(std::stop_token stop);

    server::Server& server_;
    mdns::Mdns* mdns_;
    RegistrarConfig config_;
    mutable std::mutex mutex_;
    std::condition_variable_any wake_;
    bool changed_ = true;  // the announcements changed: choose again
    std::string current_;
    std::string registeredWith_;
    std::uint64_t registrations_ = 0;
    // Used by the worker thread (and by stop() once it ended) only.
    std::unique_ptr<client::Client> client_;
    std::function<void(const std::string&)> onLdsChanged_;
    BrowsingWorker worker_;  // last: stopped before the rest goes
};

}  // namespace pnp::ua::discovery
