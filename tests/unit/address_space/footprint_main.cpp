// Loads the full namespace 0 into an AddressSpace in a bare process and reports what it
// costs: time from main() to a ready address space and the resident memory of the whole
// process. With --check it fails (exit 1) above the budget: ready in < 100 ms, ns0 decoded
// in < 50 ms, whole process <= 8 MB RSS.
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>

#include "ua/server/address_space.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace {

long statusKb(const char* field) {
    std::ifstream in("/proc/self/status");
    std::string line;
    const std::size_t n = std::strlen(field);
    while (std::getline(in, line))
        if (line.compare(0, n, field) == 0) return std::stol(line.substr(n + 1));
    return -1;
}

}  // namespace

int main(int argc, char** argv) {
    const auto t0 = std::chrono::steady_clock::now();
    const bool check = argc > 1 && std::strcmp(argv[1], "--check") == 0;
    const long rssBefore = statusKb("VmRSS:");
    pnp::ua::server::AddressSpace space;
    const double readyMs =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    // Touch the model the way a first client would (browse the Objects folder, read a value).
    pnp::ua::server::ContinuationPointStore points;
    pnp::ua::BrowseDescription d;
    d.nodeId = pnp::ua::NodeId(0, pnp::ua::ns0::ObjectsFolder);
    d.browseDirection = pnp::ua::BrowseDirection::Both;
    d.resultMask = 63;
    auto browsed = space.browse(d, 0, points);
    auto value = space.readValue(pnp::ua::NodeId(0, pnp::ua::ns0::Server_NamespaceArray));
    const auto stats = space.statistics();
    const long rss = statusKb("VmRSS:");
    const long hwm = statusKb("VmHWM:");
    std::printf(
        "address space: %zu nodes, %zu references, model %.1f KiB\n"
        "namespace 0 decoded in %.2f ms; ready %.2f ms after main()\n"
        "process RSS: %ld KiB before, %ld KiB after (peak %ld KiB)\n"
        "(objects folder: %zu references, namespace array ok: %d)\n",
        stats.nodes, stats.references, stats.bytesUsed / 1024.0, stats.namespaceZeroLoadMs, readyMs,
        rssBefore, rss, hwm, browsed.references.size(),
        value.value && value.value->isArray() ? 1 : 0);
    if (!check) return 0;
    bool ok = readyMs < 100 && stats.namespaceZeroLoadMs < 50 && hwm <= 8 * 1024;
    std::printf("%s\n", ok ? "within budget" : "OVER BUDGET");
    return ok ? 0 : 1;
}
