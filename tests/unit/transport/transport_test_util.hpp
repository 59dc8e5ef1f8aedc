// Helpers shared by the transport tests.
#pragma once

#include <cstddef>
#include <random>

#include "ua/transport/common.hpp"
#include "ua/types/binary.hpp"

namespace pnp::ua::transport::test_util {

// The status of the TransportError f() throws; Good when it throws none.
template <class F>
StatusCode statusOf(F&& f) {
    try {
        f();
    } catch (const TransportError& e) {
        return e.status();
    }
    return StatusCode{};
}

// n pseudo-random bytes, the same for the same seed.
inline Buffer pattern(std::size_t n, unsigned seed = 1) {
    Buffer b(n);
    std::mt19937 rng(seed);
    for (auto& x : b) x = static_cast<Byte>(rng());
    return b;
}

}  // namespace pnp::ua::transport::test_util
