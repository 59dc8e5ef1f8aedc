// What an OPC UA server's mDNS announcement carries (Part 12 §C.3 DNS-SD profile) and how a
// discovery URL maps onto it: `_opcua-tcp._tcp` service, SRV = host and port, TXT `path=`
// and `caps=` (comma-separated capability identifiers, e.g. LDS, DA). pnp adds two TXT keys
// of its own (ignored by other implementations) for choosing a supervising LDS-ME:
// `dg=` (discovery group) and `lvl=` (the LDS-ME's level: 0 = cell bus, 1 = workstation, ...).
#pragma once

#include <optional>
#include <string>
#include <vector>

namespace pnp::ua::discovery {

inline constexpr const char* kServiceType = "_opcua-tcp._tcp";

struct Announcement {
    std::string path;                       // "" or "/..."
    std::vector<std::string> capabilities;  // upper case as announced
    std::string group;                      // dg=
    std::optional<int> level;               // lvl=, only for an LDS-ME
};

// TXT strings ("key=value") <-> Announcement. Unknown keys are ignored; bounded.
Announcement parseTxt(const std::vector<std::string>& txt);
std::vector<std::string> makeTxt(const Announcement& a);

bool hasCapability(const std::vector<std::string>& caps, const std::string& cap);

// opc.tcp://host:port/path from an announcement's host (an address is preferred to a name:
// `.local` names need mDNS resolution, which few resolvers do).
std::string discoveryUrl(const std::string& hostOrAddress, unsigned port, const std::string& path);

// The host for a discovery URL of an mDNS service: the SRV target itself when it is an IPv4
// literal ("10.0.0.4", also with a trailing dot: node-opcua's LDS announces the servers
// registered with it that way, and puts its *own* addresses in the A records of that name),
// else the first A record's address, else the SRV target.
std::string urlHost(const std::string& srvTarget, const std::vector<std::string>& addresses);

// A DNS label from any text: letters, digits and '-' kept, others '-', at most 63 bytes.
std::string dnsLabel(const std::string& text);

}  // namespace pnp::ua::discovery
