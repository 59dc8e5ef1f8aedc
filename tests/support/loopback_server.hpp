// Set-up shared by the tests that run our server on 127.0.0.1 (ephemeral port) and talk to
// it over real sockets.
#pragma once

#include <string>

#include "support/loopback.hpp"
#include "ua/server/server.hpp"

namespace pnp::testing {

// Listens on 127.0.0.1 only, on an ephemeral port, with endpoint URLs naming 127.0.0.1.
inline ua::server::ServerConfig loopbackConfig() {
    ua::server::ServerConfig c;
    c.host = "127.0.0.1";
    c.publicHost = "127.0.0.1";
    c.port = 0;
    return c;
}

// The endpoint URL of a started server.
inline std::string url(const ua::server::Server& s) { return url(s.port()); }

}  // namespace pnp::testing
