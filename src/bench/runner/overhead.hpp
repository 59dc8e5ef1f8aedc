// The package-overhead measurement's capture analysis: TCP / UDP payload bytes per direction
// in a pcap file (as written by `dumpcap -P`).
#pragma once

#include <string>

namespace pnp::bench::runner {

struct Traffic {
    long requestBytes = 0;   // TCP / UDP payload sent from the client's address
    long responseBytes = 0;  // everything else (to the client, multicast)
    long packets = 0;
};

// Throws std::runtime_error when the file is not a pcap of Ethernet or Linux cooked frames.
Traffic readPcap(const std::string& path, const std::string& clientAddr);

}  // namespace pnp::bench::runner
