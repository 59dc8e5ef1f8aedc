// Discovery parts of the CLI (docs/discovery.md): the config a discovery-enabled server gets
// from the command line, and what runs beside it (mDNS, LDS-ME glue, registration).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "commands.hpp"
#include "mdns/mdns.hpp"
#include "ua/discovery/lds_me.hpp"
#include "ua/discovery/registrar.hpp"
#include "ua/server/server.hpp"

namespace CLI {
class App;
}

namespace pnp::cli {

// The discovery options of a server subcommand (`pnp lds`: lds = true).
void addDiscoveryOptions(CLI::App* cmd, DiscoveryOptions& options, bool lds);

// ApplicationUri (unique per server: urn:pnp:<public host>:<port>), public host, name and
// the LDS settings. lds: the server is an LDS-ME (`pnp lds`).
void applyDiscoveryConfig(ua::server::ServerConfig& config, const DiscoveryOptions& options,
                          bool lds);

// mDNS on these interfaces (empty: by the default rules), UDP port, TTL of our records (s).
mdns::MdnsConfig mdnsConfig(const std::vector<std::string>& interfaces, int port, int ttl);

// Where a server listening on `host` announces itself and looks for LDS-MEs: the
// --mdns-interface list if given; else the interface that owns the address (all for a
// wildcard address: `interfaces` empty); no multicast at all on a loopback address.
struct MdnsScope {
    bool multicast = true;
    std::vector<std::string> interfaces;  // empty: mDNS's default rules
};
MdnsScope mdnsScope(const std::string& host, const std::vector<std::string>& mdnsInterfaces);
inline constexpr const char* kLoopbackNoMdns = "listening on loopback only: no mDNS";

// Started after server.start(); the destructor unregisters, sends goodbyes and stops mDNS.
// mDNS runs on the interfaces the server is reachable on (all for 0.0.0.0, the address's
// interface otherwise, none for loopback: mdnsScope) unless --mdns-interface names them.
class DiscoveryRuntime {
  public:
    DiscoveryRuntime(ua::server::Server& server, const DiscoveryOptions& options);
    ~DiscoveryRuntime();
    DiscoveryRuntime(const DiscoveryRuntime&) = delete;
    DiscoveryRuntime& operator=(const DiscoveryRuntime&) = delete;
    const std::string& status() const { return status_; }

  private:
    std::unique_ptr<mdns::Mdns> mdns_;
    std::unique_ptr<ua::discovery::LdsMe> ldsMe_;
    std::unique_ptr<ua::discovery::Registrar> registrar_;
    std::string status_;
};

}  // namespace pnp::cli
