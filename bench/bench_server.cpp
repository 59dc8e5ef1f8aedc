// pnp_bench_server: the same server as `pnp ua serve` (full namespace 0 + the demo namespace,
// anonymous access) built only on pnp_ua_server + pnp_ua_demo, without the CLI. Used by the
// benchmark with --server bench (and to tell what the CLI itself adds to start-up and RSS).
//
//   pnp_bench_server [--host 127.0.0.1] [--port N] [--ticker MS] [--max-sessions N]
//                    [--event-loops N]
//
// --event-loops N: the transport's I/O threads (default: one per core, at most 4).
// --max-sessions N: sessions (and connections) allowed at once (default: the server's 100
// sessions, 1000 connections), for bench/load's many-sessions runs.
//
// --ticker MS: a variable ns=<demo>;s=Bench.Ticker (Int64) set every MS ms by a thread of
// its own (AddressSpace::setValue) to CLOCK_MONOTONIC in ns taken just before the call: a
// subscriber in another process on this machine computes "value change -> callback" from it.
//
// Prints "listening on opc.tcp://HOST:PORT" (flushed) once accepting; stops on SIGINT/SIGTERM.
#include <pthread.h>
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <exception>
#include <string>
#include <thread>
#include <vector>

#include "ua/demo/demo.hpp"
#include "ua/server/server.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types_parameters.hpp"

int main(int argc, char** argv) {
    using namespace pnp::ua;
    std::string host = "127.0.0.1";
    int port = 0;
    int tickerMs = 0;
    long maxSessions = 0;
    long eventLoops = 0;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        if (a == "--host" && i + 1 < argc)
            host = argv[++i];
        else if (a == "--port" && i + 1 < argc)
            port = std::stoi(argv[++i]);
        else if (a == "--ticker" && i + 1 < argc)
            tickerMs = std::stoi(argv[++i]);
        else if (a == "--max-sessions" && i + 1 < argc)
            maxSessions = std::clamp(std::stol(argv[++i]), 1L, 100000L);
        else if (a == "--event-loops" && i + 1 < argc)
            eventLoops = std::clamp(std::stol(argv[++i]), 1L, 64L);
        else {
            std::fprintf(stderr,
                         "usage: %s [--host ADDR] [--port N] [--ticker MS] [--max-sessions N] "
                         "[--event-loops N]\n",
                         argv[0]);
            return 2;
        }
    }
    sigset_t stop;
    sigemptyset(&stop);
    sigaddset(&stop, SIGINT);
    sigaddset(&stop, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stop, nullptr);
    try {
        server::ServerConfig config;
        config.host = host;
        config.publicHost = host;
        config.port = static_cast<UInt16>(port);
        config.transport.eventLoops = static_cast<std::size_t>(eventLoops);
        if (maxSessions > 0) {
            config.maxSessions = static_cast<UInt32>(maxSessions);
            config.transport.maxConnections = std::max<std::size_t>(
                config.transport.maxConnections, static_cast<std::size_t>(maxSessions) + 16);
        }
        // Section (e) also runs with changes every few ms (--tick-ms): allow publishing
        // intervals down to 1 ms (the product default stays 10 ms).
        if (tickerMs > 0) config.subscriptionLimits.minPublishingIntervalMs = 1;
        server::Server server(config);
        demo::DemoNamespace demoNamespace(server);
        NodeId tickerId;
        if (tickerMs > 0) {
            const UInt16 ns = server.addNamespace("urn:pnp:demo");
            server::VariableAttributes a;
            a.dataType = NodeId(0, ns0::Int64);
            a.value = DataValue(Variant(Int64{0}));
            tickerId = server.addressSpace().addVariable(NodeId(0, ns0::ObjectsFolder),
                                                         NodeId(ns, "Bench.Ticker"),
                                                         QualifiedName{ns, "Bench.Ticker"}, a);
        }
        server.start();
        std::jthread ticker;
        // How long setValue() takes on the ticker thread (a subscribed change is written to
        // the socket inside it): the server's part of (e), printed on stderr at exit.
        std::vector<double> setValueUs;
        setValueUs.reserve(200000);
        if (tickerMs > 0) {
            ticker = std::jthread([&](std::stop_token stopToken) {
                while (!stopToken.stop_requested()) {
                    std::this_thread::sleep_for(std::chrono::milliseconds(tickerMs));
                    const auto t0 = std::chrono::steady_clock::now();
                    server.addressSpace().setValue(
                        tickerId, DataValue(Variant(
                                      Int64{std::chrono::duration_cast<std::chrono::nanoseconds>(
                                                t0.time_since_epoch())
                                                .count()})));
                    const auto t1 = std::chrono::steady_clock::now();
                    if (setValueUs.size() < setValueUs.capacity())
                        setValueUs.push_back(
                            std::chrono::duration<double, std::micro>(t1 - t0).count());
                }
            });
        }
        std::printf("listening on %s\n", server.endpointUrl().c_str());
        std::fflush(stdout);
        int sig = 0;
        while (sigwait(&stop, &sig) != 0) {
        }
        if (ticker.joinable()) {
            ticker.request_stop();
            ticker.join();
            if (!setValueUs.empty()) {
                std::sort(setValueUs.begin(), setValueUs.end());
                std::fprintf(stderr,
                             "pnp_bench_server: setValue on the ticker: median %.1f us (%zu)\n",
                             setValueUs[setValueUs.size() / 2], setValueUs.size());
            }
        }
        server.stop();
    } catch (const std::exception& e) {
        std::fprintf(stderr, "pnp_bench_server: %s\n", e.what());
        return 1;
    }
    return 0;
}
