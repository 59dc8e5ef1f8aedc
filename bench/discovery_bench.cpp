// Discovery load: N servers registered with an embedded LDS (RegisterServer2 with an
// MdnsDiscoveryConfiguration, so N + 1 FindServersOnNetwork records), then the round trip of
// FindServersOnNetwork, FindServers and a filtered FindServersOnNetwork through our client
// on 127.0.0.1, next to a Read of one attribute on the same server in the same run (the
// round-trip floor). Server and client run in this process.
//
// usage: pnp_bench_discovery [--servers N] [--runs R]
#include <malloc.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include "ua/client/client.hpp"
#include "ua/server/server.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"

using namespace pnp::ua;
using Clock = std::chrono::steady_clock;

namespace {

struct Stats {
    double median = 0, p99 = 0;
};

template <class F>
Stats measure(int runs, F&& f) {
    std::vector<double> us;
    us.reserve(static_cast<std::size_t>(runs));
    for (int i = 0; i < runs; ++i) {
        auto t0 = Clock::now();
        f();
        us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
    }
    std::sort(us.begin(), us.end());
    return {us[us.size() / 2], us[std::min(us.size() - 1, us.size() * 99 / 100)]};
}

// VmRSS of this process, kB.
long rssKb() {
    std::ifstream f("/proc/self/status");
    std::string line;
    while (std::getline(f, line))
        if (line.rfind("VmRSS:", 0) == 0) return std::atol(line.c_str() + 6);
    return -1;
}
std::size_t heapBytes() { return mallinfo2().uordblks; }

}  // namespace

int main(int argc, char** argv) {
    int servers = 1000, runs = 200;
    for (int i = 1; i + 1 < argc; i += 2) {
        std::string a = argv[i];
        if (a == "--servers")
            servers = std::atoi(argv[i + 1]);
        else if (a == "--runs")
            runs = std::atoi(argv[i + 1]);
    }
    runs = std::max(runs, 1);

    server::ServerConfig cfg;
    cfg.host = cfg.publicHost = "127.0.0.1";
    cfg.port = 0;
    cfg.discovery.localDiscoveryServer = true;
    cfg.discovery.registrationExpiry = std::chrono::hours(1);  // no expiry during the run
    server::Server server(cfg);
    server.start();
    client::Client c;
    c.connect("opc.tcp://127.0.0.1:" + std::to_string(server.port()));

    const long rssBefore = rssKb();
    const std::size_t heapBefore = heapBytes();
    for (int i = 0; i < servers; ++i) {
        std::string id = std::to_string(i);
        RegisterServer2Request r;
        r.server.serverUri = "urn:pnp:dev:" + id;
        r.server.productUri = "urn:pnp:device";
        r.server.serverNames = {LocalizedText("en", "device " + id)};
        r.server.serverType = ApplicationType::Server;
        r.server.discoveryUrls = {"opc.tcp://dev-" + id + ".local:4840"};
        r.server.isOnline = true;
        MdnsDiscoveryConfiguration m;
        m.mdnsServerName = "dev-" + id;
        m.serverCapabilities = {"DA", i % 2 ? "NA" : "AC"};
        r.discoveryConfiguration = {toExtensionObject(m)};
        c.request(std::move(r));
    }

    const long rssAfter = rssKb();
    const std::size_t heapAfter = heapBytes();

    ReadRequest read;
    read.nodesToRead.resize(1);
    read.nodesToRead[0].nodeId = NodeId(0, ns0::Server_ServerStatus_State);
    read.nodesToRead[0].attributeId = 13;
    FindServersOnNetworkRequest filtered;
    filtered.serverCapabilityFilter = {"na"};

    auto readStats = measure(runs, [&] { c.request(ReadRequest(read)); });
    std::size_t records = 0, found = 0;
    auto fson =
        measure(runs, [&] { records = c.request(FindServersOnNetworkRequest{}).servers.size(); });
    auto fs = measure(runs, [&] { found = c.request(FindServersRequest{}).servers.size(); });
    auto ff = measure(runs, [&] { c.request(FindServersOnNetworkRequest(filtered)); });

    std::printf(
        "pnp_bench_discovery: %d registered servers (%zu records, %zu servers), %d runs "
        "each, 127.0.0.1\n",
        servers, records, found, runs);
    std::printf("%-38s %12s %12s\n", "call", "median us", "p99 us");
    auto row = [](const char* name, const Stats& s) {
        std::printf("%-38s %12.1f %12.1f\n", name, s.median, s.p99);
    };
    row("Read 1 attribute (baseline)", readStats);
    row("FindServersOnNetwork (all)", fson);
    row("FindServers (all)", fs);
    row("FindServersOnNetwork (filter NA)", ff);
    std::printf(
        "memory of the %d registrations (server and client in this process): heap "
        "+%.1f KiB (%.0f B each), VmRSS %ld -> %ld kB\n",
        servers, static_cast<double>(heapAfter - heapBefore) / 1024.0,
        servers ? static_cast<double>(heapAfter - heapBefore) / servers : 0.0, rssBefore, rssAfter);
    c.disconnect();
    server.stop();
    return 0;
}
