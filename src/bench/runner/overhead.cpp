#include "bench/runner/overhead.hpp"

#include <arpa/inet.h>

#include <cstdint>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <vector>

namespace pnp::bench::runner {

namespace {

std::uint32_t get32(const unsigned char* p, bool swap) {
    std::uint32_t v;
    std::memcpy(&v, p, 4);
    return swap ? __builtin_bswap32(v) : v;
}

unsigned be16(const unsigned char* p) { return (static_cast<unsigned>(p[0]) << 8) | p[1]; }

}  // namespace

Traffic readPcap(const std::string& path, const std::string& clientAddr) {
    std::ifstream f(path, std::ios::binary);
    if (!f) throw std::runtime_error("cannot read " + path);
    in_addr client{};
    if (::inet_pton(AF_INET, clientAddr.c_str(), &client) != 1)
        throw std::runtime_error("not an IPv4 address: " + clientAddr);
    unsigned char head[24];
    if (!f.read(reinterpret_cast<char*>(head), sizeof head))
        throw std::runtime_error(path + ": no pcap header");
    const std::uint32_t magic = get32(head, false);
    bool swap;
    if (magic == 0xa1b2c3d4u || magic == 0xa1b23c4du)
        swap = false;
    else if (magic == 0xd4c3b2a1u || magic == 0x4d3cb2a1u)
        swap = true;
    else
        throw std::runtime_error(path + ": not a pcap file (pcapng? dumpcap -P writes pcap)");
    const std::uint32_t link = get32(head + 20, swap);
    std::size_t l2;  // bytes before the IP header
    if (link == 1)
        l2 = 14;  // Ethernet
    else if (link == 113)
        l2 = 16;  // Linux cooked
    else if (link == 276)
        l2 = 20;  // Linux cooked v2
    else
        throw std::runtime_error(path + ": link type " + std::to_string(link) + " not handled");
    Traffic t;
    std::vector<unsigned char> pkt;
    unsigned char rec[16];
    while (f.read(reinterpret_cast<char*>(rec), sizeof rec)) {
        const std::uint32_t incl = get32(rec + 8, swap);
        if (incl > (1u << 20)) throw std::runtime_error(path + ": record too large");
        pkt.resize(incl);
        if (!f.read(reinterpret_cast<char*>(pkt.data()), incl)) break;
        ++t.packets;
        // The ethertype: Ethernet at 12, cooked v1 at 14, cooked v2 at 0.
        const std::size_t typeAt = link == 1 ? 12 : link == 113 ? 14 : 0;
        if (incl < l2 + 20 || be16(pkt.data() + typeAt) != 0x0800) continue;  // IPv4 only
        const unsigned char* ip = pkt.data() + l2;
        const std::size_t ihl = (ip[0] & 0x0f) * 4u;
        const unsigned total = be16(ip + 2);
        const unsigned proto = ip[9];
        const unsigned fragOffset = be16(ip + 6) & 0x1fff;
        const bool fromClient = std::memcmp(ip + 12, &client.s_addr, 4) == 0;
        long payload = 0;
        if (proto == 6) {
            if (incl < l2 + ihl + 20) continue;
            const std::size_t doff = (ip[ihl + 12] >> 4) * 4u;
            if (total >= ihl + doff) payload = static_cast<long>(total - ihl - doff);
        } else if (proto == 17) {
            // A fragmented datagram counts once, by the length in its first fragment.
            if (fragOffset != 0 || incl < l2 + ihl + 8) continue;
            const unsigned udpLen = be16(ip + ihl + 4);
            if (udpLen >= 8) payload = static_cast<long>(udpLen - 8);
        } else {
            continue;
        }
        (fromClient ? t.requestBytes : t.responseBytes) += payload;
    }
    return t;
}

}  // namespace pnp::bench::runner
