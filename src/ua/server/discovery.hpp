// The Local Discovery Server (OPC 10000-12 §4.3, OPC 10000-4 §5.4): RegisterServer,
// RegisterServer2, FindServers and FindServersOnNetwork of an LDS (an LDS-ME once the mDNS
// glue is plugged in), embeddable in any server::Server.
//
// The mDNS part lives elsewhere: the glue (a module above the server) feeds the servers it
// sees on the network in with addNetworkRecord()/removeNetworkRecord() and learns about
// registrations through onRegistrationsChanged(), to announce them and send goodbyes.
//
// Threading: every public member is thread-safe. The services are called on the network
// thread and only touch the tables under the LDS's own mutex (never held while calling out).
// Expiry and observer calls run on the LDS's own thread, so an observer never holds up the
// network thread and an expired registration goes at its deadline, not at the next 500 ms
// session sweep.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

// ServerConfig::discovery.
struct DiscoveryConfig {
    // Serve RegisterServer, RegisterServer2 and FindServersOnNetwork and list registered
    // servers in FindServers. Off: those services answer BadServiceUnsupported.
    bool localDiscoveryServer = false;
    // A registration not renewed within this is dropped. Part 12 suggests 10 min; Plug &
    // Produce wants a crashed device gone within seconds.
    std::chrono::milliseconds registrationExpiry{2000};
    std::size_t maxRegisteredServers = 10000;
    // Part 4 §5.4.5 wants RegisterServer over a signed (or signed and encrypted) channel,
    // whose certificate names the registered ServerUri (else BadServerUriInvalid). true also
    // accepts registrations over SecurityPolicy None (a server without security); false
    // refuses them (BadSecurityModeInsufficient). pnp's secured LDS sets it to false.
    bool allowInsecureRegistration = true;
    // This server's own capability identifiers (Part 12 Annex D: "LDS", "DA", "NA", ...).
    // "LDS" is added when localDiscoveryServer is on.
    std::vector<std::string> serverCapabilities;
    // Stored for the mDNS glue (TXT record); not used by the LDS itself.
    std::string discoveryGroup;
    int discoveryLevel = 0;

    // Bounds on what a client may register (the decoder's limits are far larger).
    std::size_t maxStringLength = 4096;     // serverUri, a URL, a name, a capability, a path
    std::size_t maxListLength = 32;         // discoveryUrls, serverNames, capabilities, configs
    std::size_t maxNetworkRecords = 10000;  // records fed in by the mDNS glue
    // Events waiting for slow observers; beyond it they are dropped and one Overflow event
    // follows (so a stuck observer cannot make clients' requests grow the queue forever).
    std::size_t maxPendingEvents = 10000;
};

// One registered server as the LDS keeps it.
struct Registration {
    RegisteredServer server;
    std::optional<MdnsDiscoveryConfiguration> mdns;  // RegisterServer2 with an mDNS config
};

struct RegistrationEvent {
    // Overflow: events were dropped (maxPendingEvents) because the observers fell behind;
    // re-read registeredServers() to resynchronise. It carries no registration.
    enum class Kind { Added, Updated, Removed, Overflow };
    enum class Reason {
        Registered,    // Added: a new serverUri
        Replaced,      // Updated: a re-registration changed its data (previous = the old one)
        Unregistered,  // Removed: isOnline = false
        Expired,       // Removed: not renewed within registrationExpiry
    };
    Kind kind = Kind::Added;
    Reason reason = Reason::Registered;
    Registration registration;             // the new data; for Removed, the last data
    std::optional<Registration> previous;  // Updated only
};

// A server seen on the network (by the mDNS glue): one ServerOnNetwork record.
struct NetworkRecord {
    std::string serverName;
    std::string discoveryUrl;
    std::vector<std::string> serverCapabilities;
};

// The channel a registration came over: secured (Sign or SignAndEncrypt) with the URIs of
// the registering server's certificate, or not.
struct RegistrationChannel {
    bool secured = false;
    std::vector<std::string> certificateUris;
};

class LocalDiscovery {
  public:
    using Observer = std::function<void(const RegistrationEvent&)>;

    explicit LocalDiscovery(DiscoveryConfig config);
    ~LocalDiscovery();  // stop()
    LocalDiscovery(const LocalDiscovery&) = delete;
    LocalDiscovery& operator=(const LocalDiscovery&) = delete;

    // Starts / joins the expiry and notification thread. stop() drops pending events.
    void start();
    void stop();

    // This server's own record (FindServersOnNetwork lists it); set by the Server once its
    // port is known.
    void setSelf(NetworkRecord self);

    // ---- plug-in surface for the mDNS glue (any thread) ----------------------------------
    // Adds or updates (same serverName + discoveryUrl: same record id) a server seen on the
    // network. Returns its record id, or 0 when refused (empty or oversized fields, or
    // maxNetworkRecords reached).
    std::uint32_t addNetworkRecord(NetworkRecord record);
    // Removes it again (a goodbye or a TTL that ran out); false when unknown.
    bool removeNetworkRecord(const std::string& serverName, const std::string& discoveryUrl);
    // Called on the LDS's thread, one event at a time, in order, without any lock of the LDS
    // held: the observer may call back into it. Returns an id for removeObserver().
    std::size_t onRegistrationsChanged(Observer observer);
    void removeObserver(std::size_t id);
    std::vector<Registration> registeredServers() const;
    std::vector<ServerOnNetwork> records() const;  // the FindServersOnNetwork table
    const DiscoveryConfig& config() const { return config_; }
    // Tests: the next record id, to reach the wrap-around (renumbering) without 4e9 records.
    void setNextRecordIdForTesting(std::uint32_t id);

    // ---- services (called by the Server on the network thread) ---------------------------
    void registerServer(const RegisterServerRequest& req, RegisterServerResponse& resp,
                        const RegistrationChannel& channel = {});
    void registerServer2(const RegisterServer2Request& req, RegisterServer2Response& resp,
                         const RegistrationChannel& channel = {});
    // Adds the registered servers to resp.servers (which holds this server's own description
    // when it matched the filter).
    void findServers(const FindServersRequest& req, FindServersResponse& resp) const;
    void findServersOnNetwork(const FindServersOnNetworkRequest& req,
                              FindServersOnNetworkResponse& resp) const;

  private:
    using Clock = std::chrono::steady_clock;
    struct Entry {
        Registration registration;
        Clock::time_point expiresAt;
    };
    enum class Source { Registration, Network, Self };
    // A record stays while anything still announces it: registrations (two may name the same
    // mDNS name and URL), the network (the glue also hears our own announcements) or this
    // server itself.
    struct Record {
        ServerOnNetwork data;
        std::vector<std::string> lowerCapabilities;  // for the case-insensitive filter
        std::size_t registrations = 0;
        bool network = false;
        bool self = false;
    };

    StatusCode validate(const RegisteredServer& s) const;
    bool validRecord(const NetworkRecord& r) const;
    StatusCode apply(Registration reg);
    void removeLocked(const std::string& serverUri, RegistrationEvent::Reason reason);
    void queueLocked(RegistrationEvent event);
    void addRecordsLocked(const Registration& reg);
    void dropRecordsLocked(const Registration& reg);
    std::uint32_t upsertRecordLocked(const std::string& name, const std::string& url,
                                     const std::vector<std::string>& caps, Source source);
    bool releaseRecordLocked(const std::string& name, const std::string& url, Source source);
    std::uint32_t nextRecordIdLocked();
    void run();

    const DiscoveryConfig config_;
    mutable std::mutex mutex_;
    std::condition_variable wake_;
    bool stopping_ = false;
    std::thread thread_;

    std::map<std::string, Entry, std::less<>> registrations_;     // by serverUri (sorted)
    std::set<std::pair<Clock::time_point, std::string>> expiry_;  // (deadline, serverUri)
    std::map<std::uint32_t, Record> records_;                     // by record id, for paging
    std::unordered_map<std::string, std::uint32_t> recordIds_;    // name + '\0' + url -> id
    std::size_t networkRecordCount_ = 0;
    std::uint32_t nextRecordId_ = 1;
    DateTime lastCounterResetTime_;
    std::optional<NetworkRecord> self_;

    std::vector<RegistrationEvent> pending_;  // delivered by run()
    bool overflowed_ = false;                 // events were dropped since the last delivery
    std::map<std::size_t, Observer> observers_;
    std::size_t nextObserverId_ = 1;
};

}  // namespace pnp::ua::server
