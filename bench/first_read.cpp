// pnp_bench_first_read: one client process, timed from the top of main() to the first
// completed Read of a value (TCP connect, HEL/ACK, OpenSecureChannel, CreateSession,
// ActivateSession, Read). Started by pnp_bench for "client start -> first Read".
//
//   pnp_bench_first_read URL NAMESPACE_INDEX STRING_ID
//
// Prints one line of CLOCK_MONOTONIC nanosecond timestamps (comparable with the parent's):
//   main=<t> connected=<t> read=<t>
// The session is closed after the line is printed (not timed).
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "bench_util.hpp"
#include "ua/client/client.hpp"

int main(int argc, char** argv) {
    const std::int64_t tMain = pnp::bench::nowNs();  // the first statement of main()
    if (argc != 4) {
        std::fprintf(stderr, "usage: %s URL NAMESPACE_INDEX STRING_ID\n", argv[0]);
        return 2;
    }
    using namespace pnp::ua;
    try {
        client::Client c;
        c.connect(argv[1]);
        const std::int64_t tConnected = pnp::bench::nowNs();
        Variant v = c.readValue(NodeId(static_cast<UInt16>(std::atoi(argv[2])), std::string(argv[3])));
        const std::int64_t tRead = pnp::bench::nowNs();
        if (v.isEmpty()) throw std::runtime_error("empty value");
        std::printf("main=%lld connected=%lld read=%lld\n", static_cast<long long>(tMain),
                    static_cast<long long>(tConnected), static_cast<long long>(tRead));
        std::fflush(stdout);
    } catch (const std::exception& e) {
        std::fprintf(stderr, "pnp_bench_first_read: %s\n", e.what());
        return 1;
    }
    return 0;
}
