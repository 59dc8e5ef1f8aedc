// pnp_bench_empty: the floor of "spawn -> top of main()" on this machine: a C++ program that
// links libstdc++ like the clients do but has no static initialisers of its own. Prints the
// same line as pnp_bench_first_read, with all three timestamps taken at the top of main().
#include <cstdio>
#include <string>

#include "bench_util.hpp"

int main(int argc, char**) {
    const long long t = static_cast<long long>(pnp::bench::nowNs());
    std::string keep(static_cast<std::size_t>(argc), 'x');  // a real libstdc++ dependency
    std::printf("main=%lld connected=%lld read=%lld\n", t, t, t + static_cast<long long>(keep.size()) * 0);
    std::fflush(stdout);
    return 0;
}
