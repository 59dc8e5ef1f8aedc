// One load client process of pnp_bench_load (issue 26): our client in a loop against one
// server for a given time, every response checked, and one JSON line of what it saw.
//
//   pnp_bench_load_client URL [--mix call|read|write|mixed|publish] [--seconds S]
//                             [--payload BYTES] [--id N] [--namespace URI] [--start-at NS]
//
// Mixes (the demo namespace of `pnp ua serve` / pnp_bench_server, or any server with the
// same nodes in namespace URI):
//   call     Demo.Echo(ByteString) with a payload unique to this client and call; the output
//            must be the input (a lost, duplicated or crossed response shows as a mismatch)
//   read     Read of Scalar.Int32
//   write    Write of this client's payload to Scalar.ByteString (Good status)
//   mixed    call, read, write in turn
//   publish  a subscription (publishing interval 10 ms) on Bench.Ticker (pnp_bench_server
//            --ticker MS): each notification's value must be greater than the last (none out
//            of sequence, none duplicated); plus Read in the loop
// --start-at: CLOCK_MONOTONIC ns at which to begin (all clients start together).
// --idle-sessions K: instead of a mix, hold K idle sessions (each with a subscription and one
//            monitored item on Scalar.Int32, publishing interval 1 s) for --seconds; prints
//            "ready K" once all are open, then the JSON line {"id","sessions"} when closed.
//
// Output (one line): {"id","mix","calls","errors","mismatches","notifications",
// "outOfOrder","seconds","hist":[[µs,count]...]} — the latency histogram is exact to 1 µs
// below 1 ms, to 10 µs below 10 ms, to 100 µs above.
#include <time.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"

namespace {

namespace ua = pnp::ua;

std::int64_t monotonicNs() {
    timespec ts{};
    ::clock_gettime(CLOCK_MONOTONIC, &ts);
    return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

std::uint32_t bucketOf(std::int64_t ns) {
    const std::int64_t us = ns / 1000;
    if (us < 1000) return static_cast<std::uint32_t>(us);
    if (us < 10000) return static_cast<std::uint32_t>(us / 10 * 10);
    return static_cast<std::uint32_t>(std::min<std::int64_t>(us, 100'000'000) / 100 * 100);
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: pnp_bench_load_client URL [--mix M] [--seconds S] ...\n");
        return 2;
    }
    const std::string url = argv[1];
    std::string mix = "call", nsUri = "urn:pnp:demo";
    double seconds = 5;
    std::size_t payload = 2;
    int id = 0;
    std::int64_t startAt = 0;
    int idleSessions = 0;
    for (int i = 2; i + 1 < argc; i += 2) {
        const std::string a = argv[i], v = argv[i + 1];
        if (a == "--mix")
            mix = v;
        else if (a == "--seconds")
            seconds = std::clamp(std::stod(v), 0.1, 86400.0);
        else if (a == "--payload")
            payload = std::clamp<std::size_t>(std::stoul(v), 1, 1 << 20);
        else if (a == "--id")
            id = std::stoi(v);
        else if (a == "--namespace")
            nsUri = v;
        else if (a == "--start-at")
            startAt = std::stoll(v);
        else if (a == "--idle-sessions")
            idleSessions = std::clamp(std::stoi(v), 1, 5000);
        else {
            std::fprintf(stderr, "unknown option %s\n", a.c_str());
            return 2;
        }
    }
    if (mix != "call" && mix != "read" && mix != "write" && mix != "mixed" && mix != "publish") {
        std::fprintf(stderr, "unknown mix %s\n", mix.c_str());
        return 2;
    }
    if (idleSessions > 0) {
        // No background threads: the sessions stay idle (their Publish requests wait in the
        // server), which is what an idle session costs it.
        struct Held {
            std::unique_ptr<ua::client::Client> client;
            ua::client::Subscription subscription;
            ua::client::MonitoredItem item;
        };
        std::vector<Held> held;
        held.reserve(static_cast<std::size_t>(idleSessions));
        try {
            for (int k = 0; k < idleSessions; ++k) {
                Held h;
                h.client = std::make_unique<ua::client::Client>();
                h.client->connect(url, ua::client::Anonymous{}, std::chrono::seconds(10));
                const ua::UInt16 ns = h.client->namespaceIndex(nsUri, std::chrono::seconds(5));
                h.subscription = ua::client::Subscription(
                    *h.client, {.publishingInterval = 1000, .lifetimeCount = 6000});
                h.item = h.subscription.monitorValue(ua::NodeId(ns, "Scalar.Int32"),
                                                     [](const ua::DataValue&) {});
                held.push_back(std::move(h));
            }
        } catch (const std::exception& e) {
            std::fprintf(stderr, "load client %d: session %zu: %s\n", id, held.size(), e.what());
            std::printf("{\"id\":%d,\"error\":\"sessions\",\"sessions\":%zu}\n", id, held.size());
            return 1;
        }
        std::printf("ready %d\n", idleSessions);
        std::fflush(stdout);
        std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
        for (auto& h : held) h.client->disconnect();
        std::printf("{\"id\":%d,\"sessions\":%d}\n", id, idleSessions);
        return 0;
    }
    std::map<std::uint32_t, std::uint64_t> hist;
    std::uint64_t calls = 0, errors = 0, mismatches = 0;
    std::atomic<std::uint64_t> notifications{0}, outOfOrder{0};
    double elapsed = 0;
    try {
        ua::client::Client client;
        client.connect(url, ua::client::Anonymous{}, std::chrono::seconds(10));
        const ua::UInt16 ns = client.namespaceIndex(nsUri, std::chrono::seconds(5));
        const ua::NodeId object(ns, "Demo"), echo(ns, "Demo.Echo");
        const ua::NodeId int32Node(ns, "Scalar.Int32"), bytesNode(ns, "Scalar.ByteString");
        ua::client::Subscription subscription;
        ua::client::MonitoredItem ticker;
        std::mutex lastMutex;
        std::int64_t last = 0;
        if (mix == "publish") {
            client.startBackgroundThread();
            subscription = ua::client::Subscription(client, {.publishingInterval = 10});
            ticker = subscription.monitorValue(
                ua::NodeId(ns, "Bench.Ticker"),
                [&](const ua::DataValue& v) {
                    const auto* x = v.value ? v.value->scalar<ua::Int64>() : nullptr;
                    if (!x) return;
                    std::lock_guard lock(lastMutex);
                    if (*x <= last) ++outOfOrder;
                    last = *x;
                    ++notifications;
                },
                {.samplingInterval = 0, .queueSize = 100});
        }
        std::string buffer(payload, '\0');
        while (startAt > 0 && monotonicNs() < startAt)
            std::this_thread::sleep_for(std::chrono::microseconds(200));
        const std::int64_t t0 = monotonicNs();
        const std::int64_t end = t0 + static_cast<std::int64_t>(seconds * 1e9);
        for (std::uint64_t n = 0;; ++n) {
            // The call's number and this client's id in the payload: a response that belongs
            // to another request cannot pass the check.
            std::memcpy(buffer.data(), &n, std::min<std::size_t>(payload, sizeof n));
            if (payload > sizeof n)
                std::memcpy(buffer.data() + sizeof n, &id,
                            std::min<std::size_t>(payload - sizeof n, sizeof id));
            const ua::ByteString mine{std::string_view(buffer)};
            const std::int64_t before = monotonicNs();
            if (before >= end) break;
            const std::string kind = mix == "mixed"     ? (n % 3 == 0   ? "call"
                                                           : n % 3 == 1 ? "read"
                                                                        : "write")
                                     : mix == "publish" ? "read"
                                                        : mix;
            try {
                if (kind == "call") {
                    const auto r =
                        client.call(object, echo, {ua::Variant(mine)}, std::chrono::seconds(5));
                    const auto* out = r.ok() && r.outputs.size() == 1
                                          ? r.outputs[0].scalar<ua::ByteString>()
                                          : nullptr;
                    if (!r.ok())
                        ++errors;
                    else if (!out || *out != mine)
                        ++mismatches;
                } else if (kind == "read") {
                    const ua::Variant v = client.readValue(int32Node, std::chrono::seconds(5));
                    if (!v.scalar<ua::Int32>()) ++mismatches;
                } else {
                    if (!client.writeValue(bytesNode, ua::Variant(mine), std::chrono::seconds(5))
                             .isGood())
                        ++errors;
                }
            } catch (const std::exception&) {
                ++errors;
            }
            ++hist[bucketOf(monotonicNs() - before)];
            ++calls;
        }
        elapsed = static_cast<double>(monotonicNs() - t0) / 1e9;
        ticker = {};
        subscription = {};
        client.disconnect();
    } catch (const std::exception& e) {
        std::fprintf(stderr, "load client %d: %s\n", id, e.what());
        std::printf("{\"id\":%d,\"error\":\"connect\"}\n", id);
        return 1;
    }
    std::string h;
    for (const auto& [us, count] : hist)
        h += (h.empty() ? "" : ",") + std::string("[") + std::to_string(us) + "," +
             std::to_string(count) + "]";
    std::printf(
        "{\"id\":%d,\"mix\":\"%s\",\"calls\":%llu,\"errors\":%llu,\"mismatches\":%llu,"
        "\"notifications\":%llu,\"outOfOrder\":%llu,\"seconds\":%.3f,\"hist\":[%s]}\n",
        id, mix.c_str(), static_cast<unsigned long long>(calls),
        static_cast<unsigned long long>(errors), static_cast<unsigned long long>(mismatches),
        static_cast<unsigned long long>(notifications.load()),
        static_cast<unsigned long long>(outOfOrder.load()), elapsed, h.c_str());
    return 0;
}
