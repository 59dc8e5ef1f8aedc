// LDS-ME: a server's Local Discovery Server (server::LocalDiscovery) joined to mDNS.
//   - announces the server itself (caps LDS, TXT dg= and lvl=) on every interface;
//   - announces every server registered with RegisterServer2 + MdnsDiscoveryConfiguration
//     (instance = its mdnsServerName, address and port from its discovery URL) and sends
//     goodbyes when it unregisters or its registration expires;
//   - feeds the _opcua-tcp._tcp services seen on the network into FindServersOnNetwork.
// Runs as `pnp lds`, and inside `pnp ua serve --lds-me` (a workstation is a server and an
// LDS-ME for its devices).
#pragma once

#include <cstdint>
#include <map>
#include <mutex>
#include <string>

#include "mdns/mdns.hpp"

namespace pnp::ua::server {
class Server;
struct RegistrationEvent;
}  // namespace pnp::ua::server

namespace pnp::ua::discovery {

struct LdsMeConfig {
    std::string instance;   // mDNS instance name; default from the ApplicationName and port
    std::string hostLabel;  // mDNS host label of the A records; default instance + "-host"
};

class LdsMe {
  public:
    // The server's config must have discovery.localDiscoveryServer on; the server must have
    // been started (its port is announced). mdns must be started.
    LdsMe(server::Server& server, mdns::Mdns& mdns, LdsMeConfig config = {});
    ~LdsMe();
    LdsMe(const LdsMe&) = delete;
    LdsMe& operator=(const LdsMe&) = delete;

    void start();
    void stop();                   // withdraws every announcement (goodbyes)
    std::string instance() const;  // as announced (a name conflict renames it)

  private:
    void onRegistration(const server::RegistrationEvent& e);

    server::Server& server_;
    mdns::Mdns& mdns_;
    LdsMeConfig config_;
    mutable std::mutex mutex_;
    std::string instance_;
    mdns::Mdns::PublicationId self_ = 0;
    std::map<std::string, mdns::Mdns::PublicationId> announced_;  // serverUri -> publication
    std::size_t observer_ = 0;
    mdns::Mdns::BrowseId browse_ = 0;
    bool started_ = false;
};

}  // namespace pnp::ua::discovery
