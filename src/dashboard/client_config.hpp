// The dashboard's OPC UA client configuration, one for its monitoring (CellView) and its
// pages' actions (Actions).
#pragma once

#include <chrono>

#include "ua/client/client.hpp"

namespace pnp::dashboard {

inline ua::client::ClientConfig clientConfig(std::chrono::milliseconds requestTimeout,
                                             std::chrono::milliseconds connectTimeout) {
    ua::client::ClientConfig c;
    c.applicationName = "pnp dashboard";
    c.requestTimeout = requestTimeout;
    c.connectTimeout = connectTimeout;
    // A dead server must not hold a page's action or the view's clean-up for long.
    c.closeTimeout = std::chrono::milliseconds(500);
    return c;
}

}  // namespace pnp::dashboard
