// Polls a condition another thread makes true, until it holds or the timeout passes.
#pragma once

#include <chrono>
#include <thread>

namespace pnp::testing {

template <class Pred>
bool waitUntil(Pred pred, std::chrono::milliseconds timeout = std::chrono::milliseconds(3000)) {
    auto end = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < end) {
        if (pred()) return true;
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return pred();
}

}  // namespace pnp::testing
