// mDNS responder and DNS-SD browser (RFC 6762 / RFC 6763, as OPC 10000-12 uses them for
// the LDS-ME), IPv4 only. One background thread does all socket I/O; the public methods
// may be called from any thread. Callbacks run on the background thread without the
// internal lock held (they may call back into the Mdns object, but must not destroy it).
// See README.md for the deliberate deviations from the RFCs.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace pnp::mdns {

struct MdnsConfig {
    // Interface names; empty = every interface that is UP, MULTICAST and has an IPv4
    // address (loopback only when named explicitly).
    std::vector<std::string> interfaces;
    std::uint16_t port = 5353;  // tests use another port to stay private
    std::string group = "224.0.0.251";
    std::uint32_t hostTtl = 120;   // seconds: A records we announce
    std::uint32_t otherTtl = 120;  // seconds: PTR / SRV / TXT records we announce
    // getifaddrs() poll period; netlink notifications trigger a rescan at once as well.
    std::chrono::milliseconds interfaceCheckInterval{1000};
};

struct ServiceRecord {
    std::string instance;                  // instance label, e.g. "robot-1" (UTF-8, <= 63 bytes)
    std::string type = "_opcua-tcp._tcp";  // in domain "local"
    std::string host;                      // host label: "robot-1-host" -> "robot-1-host.local"
    std::uint16_t port = 4840;
    std::vector<std::string> txt;        // e.g. {"path=/", "caps=LDS,DA"}
    std::optional<std::string> address;  // IPv4 dotted; unset = each interface's own address
};

struct DiscoveredService {
    std::string instance;  // the instance label (unescaped)
    std::string type;      // as given to browse()
    std::string host;      // SRV target, e.g. "robot-1-host.local"
    std::uint16_t port = 0;
    std::vector<std::string> txt;
    std::vector<std::string> addresses;  // IPv4 dotted, sorted
    std::string interfaceName;
    int interfaceIndex = 0;

    std::string txtValue(std::string_view key) const;  // "" if missing
};

class Mdns {
  public:
    explicit Mdns(MdnsConfig config = {});
    ~Mdns();  // withdraws everything (goodbye, TTL 0) and stops
    Mdns(const Mdns&) = delete;
    Mdns& operator=(const Mdns&) = delete;

    // Opens the socket (throws std::system_error) and starts the thread. The thread and
    // its sockets live in the network namespace of the calling thread.
    void start();
    // Sends goodbyes for every publication and joins the thread. Publications and browses
    // are kept: start() again re-announces them.
    void stop();

    using PublicationId = std::uint64_t;
    // Announces at once (no probe delay), probes alongside; on a conflict the instance is
    // renamed "name (2)", "name (3)"... and onRename is called. Throws std::invalid_argument
    // for a record that cannot be encoded (empty or too long labels, bad address).
    PublicationId publish(ServiceRecord record,
                          std::function<void(const std::string& newInstance)> onRename = {});
    void update(PublicationId id, std::vector<std::string> txt);  // re-announces the TXT
    void withdraw(PublicationId id);                              // goodbyes, TTL 0

    using BrowseId = std::uint64_t;
    // The callback reports a resolved service (SRV + TXT + A) up, again up when it changed
    // (TXT, port, addresses), and down (goodbye, TTL expired, interface gone, stopBrowse
    // does not report).
    BrowseId browse(std::string type,
                    std::function<void(const DiscoveredService& service, bool up)> callback);
    void stopBrowse(BrowseId id);
    std::vector<DiscoveredService> services(const std::string& type) const;
    void queryNow(const std::string& type);
    std::vector<std::string> interfaceNames() const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::mdns
