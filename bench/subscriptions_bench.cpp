// Subscription load: N monitored items at a sampling interval on one subscription, every
// value changing every sampling interval, for D seconds; a client thread keeps Publish
// requests flowing. Server and client run in this process (loopback socket between them).
//
// Reports: resident memory before / after creating the items (-> bytes per item), resident
// memory at every second of the run (sustained load must not grow it), notifications
// received per second, values sampled per second and CPU time of the process.
//
// With --latency N instead: one item with sampling interval 0, N times "setValue() on this
// thread -> the Publish response with the value is received" (a Publish request is waiting
// in the server each time), next to the Read round trip of the same client (median, p99).
//
// usage: pnp_bench_subscriptions [--items N] [--sampling MS] [--publishing MS] [--seconds S]
//        pnp_bench_subscriptions --latency N
#include <malloc.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <fstream>
#include <future>
#include <string>
#include <thread>
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

long residentKiB() {
    std::ifstream statm("/proc/self/statm");
    long size = 0, resident = 0;
    statm >> size >> resident;
    return resident * (sysconf(_SC_PAGESIZE) / 1024);
}

// Heap bytes in use (freed memory not counted, unlike RSS).
std::size_t heapInUse() { return mallinfo2().uordblks; }

double cpuSeconds() {
    rusage u{};
    getrusage(RUSAGE_SELF, &u);
    return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
           static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec) / 1e6;
}

double percentile(std::vector<double> v, double p) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0 : v[std::min(v.size() - 1, static_cast<std::size_t>(p * v.size()))];
}

int latency(server::Server& server, client::Client& c, UInt32 sub, const NodeId& node, int runs) {
    CreateMonitoredItemsRequest cm;
    cm.subscriptionId = sub;
    cm.timestampsToReturn = TimestampsToReturn::Both;
    MonitoredItemCreateRequest m;
    m.itemToMonitor.nodeId = node;
    m.itemToMonitor.attributeId = 13;
    m.monitoringMode = MonitoringMode::Reporting;
    m.requestedParameters.samplingInterval = 0;
    m.requestedParameters.queueSize = 1;
    cm.itemsToCreate.push_back(m);
    c.request(cm);
    c.request(PublishRequest{});  // the initial value
    std::vector<double> changeUs, readUs;
    ReadRequest read;
    read.nodesToRead.resize(1);
    read.nodesToRead[0].nodeId = node;
    read.nodesToRead[0].attributeId = 13;
    for (int i = 0; i < runs; ++i) {
        // Past the publishing interval (both measured after the same pause).
        std::this_thread::sleep_for(std::chrono::milliseconds(12));
        auto t0 = Clock::now();
        c.request(read);
        readUs.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
        // With a Publish request waiting in the server.
        std::atomic<Clock::time_point> received{};
        std::thread publisher([&] {
            c.request(PublishRequest{}, std::chrono::seconds(5));
            received = Clock::now();
        });
        for (int k = 0; k < 2000 && server.subscriptions().statistics().queuedPublishRequests == 0;
             ++k)
            std::this_thread::sleep_for(std::chrono::microseconds(50));
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
        auto t1 = Clock::now();
        server.addressSpace().setValue(node, DataValue(Variant(Double(i + 1))));
        publisher.join();
        changeUs.push_back(std::chrono::duration<double, std::micro>(received.load() - t1).count());
    }
    std::printf("setValue -> Publish response received: median %.1f us, p99 %.1f us (%d runs)\n",
                percentile(changeUs, 0.5), percentile(changeUs, 0.99), runs);
    std::printf("Read round trip (same client): median %.1f us, p99 %.1f us\n",
                percentile(readUs, 0.5), percentile(readUs, 0.99));
    c.disconnect();
    server.stop();
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    UInt32 items = 10000;
    double samplingMs = 100;
    double publishingMs = 100;
    int seconds = 20;
    int latencyRuns = 0;
    for (int i = 1; i + 1 < argc; i += 2) {
        std::string a = argv[i];
        if (a == "--items") items = static_cast<UInt32>(std::atoi(argv[i + 1]));
        if (a == "--sampling") samplingMs = std::atof(argv[i + 1]);
        if (a == "--publishing") publishingMs = std::atof(argv[i + 1]);
        if (a == "--seconds") seconds = std::atoi(argv[i + 1]);
        if (a == "--latency") latencyRuns = std::atoi(argv[i + 1]);
    }

    server::ServerConfig config;
    config.host = "127.0.0.1";
    config.publicHost = "127.0.0.1";
    config.port = 0;
    config.subscriptionLimits.maxMonitoredItemsPerCall = items;
    config.subscriptionLimits.maxNotificationsPerPublish = items * 2;
    config.subscriptionLimits.maxQueueSize = 10;
    server::Server server(config);
    auto& as = server.addressSpace();
    std::vector<NodeId> nodes;
    for (UInt32 i = 0; i < items; ++i) {
        server::VariableAttributes a;
        a.dataType = NodeId(0, ns0::Double);
        a.value = DataValue(Variant(Double{0}));
        nodes.push_back(as.addVariable(NodeId(0, ns0::ObjectsFolder), NodeId(1, 100000 + i),
                                       QualifiedName{1, "V" + std::to_string(i)}, a));
    }
    server.start();
    client::Client c;
    c.connect("opc.tcp://127.0.0.1:" + std::to_string(server.port()));

    CreateSubscriptionRequest cs;
    cs.requestedPublishingInterval = publishingMs;
    cs.requestedMaxKeepAliveCount = 10;
    cs.requestedLifetimeCount = 1000;
    cs.publishingEnabled = true;
    UInt32 sub = c.request(cs).subscriptionId;

    if (latencyRuns > 0) return latency(server, c, sub, nodes[0], latencyRuns);

    long rssBefore = residentKiB();
    std::size_t heapBefore = heapInUse();
    CreateMonitoredItemsRequest cm;
    cm.subscriptionId = sub;
    cm.timestampsToReturn = TimestampsToReturn::Both;
    for (UInt32 i = 0; i < items; ++i) {
        MonitoredItemCreateRequest m;
        m.itemToMonitor.nodeId = nodes[i];
        m.itemToMonitor.attributeId = 13;
        m.monitoringMode = MonitoringMode::Reporting;
        m.requestedParameters.clientHandle = i;
        m.requestedParameters.samplingInterval = samplingMs;
        m.requestedParameters.queueSize = 1;
        m.requestedParameters.discardOldest = true;
        cm.itemsToCreate.push_back(std::move(m));
    }
    auto created = c.request(std::move(cm), std::chrono::seconds(60));
    std::size_t good = 0;
    for (const auto& r : created.results) good += r.statusCode.isGood() ? 1 : 0;
    cm = {};
    created = {};
    long rssAfter = residentKiB();
    std::size_t heapAfter = heapInUse();
    std::printf("items created: %zu of %u (sampling %.0f ms, publishing %.0f ms)\n", good, items,
                samplingMs, publishingMs);
    std::printf("RSS before items: %ld KiB, after: %ld KiB -> %.0f bytes per item\n", rssBefore,
                rssAfter, (rssAfter - rssBefore) * 1024.0 / items);
    std::printf("heap in use before items: %zu KiB, after: %zu KiB -> %.0f bytes per item\n",
                heapBefore / 1024, heapAfter / 1024,
                (static_cast<double>(heapAfter) - static_cast<double>(heapBefore)) / items);

    // Every value changes once per sampling interval.
    std::atomic<bool> stop{false};
    std::thread writer([&] {
        Double v = 0;
        auto next = Clock::now();
        while (!stop) {
            v += 1;
            for (const auto& n : nodes) as.setValue(n, DataValue(Variant(v)));
            next += std::chrono::duration_cast<Clock::duration>(
                std::chrono::duration<double, std::milli>(samplingMs));
            std::this_thread::sleep_until(next);
        }
    });

    std::uint64_t notifications = 0;
    std::uint64_t messages = 0;
    std::vector<SubscriptionAcknowledgement> acks;
    auto start = Clock::now();
    double cpuStart = cpuSeconds();
    auto samplesStart = server.subscriptions().statistics().samples;
    int second = 0;
    std::vector<long> rss;
    // Three Publish requests in flight (as clients do), so that the server never waits for
    // one while the client decodes.
    std::deque<std::future<PublishResponse>> inFlight;
    while (Clock::now() - start < std::chrono::seconds(seconds)) {
        while (inFlight.size() < 3) {
            PublishRequest p;
            p.subscriptionAcknowledgements = std::move(acks);
            acks.clear();
            inFlight.push_back(c.requestAsync(std::move(p), std::chrono::seconds(10)));
        }
        c.runIterate(std::chrono::milliseconds(10));
        while (!inFlight.empty() &&
               inFlight.front().wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
            auto r = inFlight.front().get();
            inFlight.pop_front();
            ++messages;
            for (const auto& x : r.notificationMessage.notificationData)
                if (auto d = fromExtensionObject<DataChangeNotification>(x))
                    notifications += d->monitoredItems.size();
            if (!r.notificationMessage.notificationData.empty())
                acks.push_back({sub, r.notificationMessage.sequenceNumber});
        }
        if (Clock::now() - start >= std::chrono::seconds(second + 1)) {
            ++second;
            rss.push_back(residentKiB());
        }
    }
    double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
    double cpu = cpuSeconds() - cpuStart;
    auto samples = server.subscriptions().statistics().samples - samplesStart;
    stop = true;
    writer.join();

    std::printf(
        "run: %.1f s, %llu Publish responses, %.0f notifications/s (expected %.0f), "
        "%.0f samples/s\n",
        elapsed, static_cast<unsigned long long>(messages), notifications / elapsed,
        items * 1000.0 / samplingMs, samples / elapsed);
    std::printf("CPU (server + client + writer): %.2f s = %.0f %% of one core\n", cpu,
                100 * cpu / elapsed);
    std::printf("RSS per second (KiB):");
    for (long k : rss) std::printf(" %ld", k);
    std::printf("\n");
    if (rss.size() >= 4) {
        long early = rss[1], late = rss.back();
        std::printf("RSS growth from second 2 to the end: %ld KiB\n", late - early);
    }
    c.disconnect();
    server.stop();
    return good == items ? 0 : 1;
}
