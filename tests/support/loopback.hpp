// Helpers of the tests that talk to a server on 127.0.0.1 through our client.
#pragma once

#include <cstdint>
#include <string>
#include <utility>

#include "ua/client/error.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::testing {

// The endpoint URL of a server (or of a relay in front of it) listening on 127.0.0.1:port.
inline std::string url(std::uint16_t port) { return "opc.tcp://127.0.0.1:" + std::to_string(port); }

// The StatusCode of a client call expected to fail (Good when it did not throw).
template <class F>
ua::StatusCode errorOf(F&& f) {
    try {
        std::forward<F>(f)();
    } catch (const ua::client::Error& e) {
        return e.status();
    }
    return ua::status::Good;
}

}  // namespace pnp::testing
