// A Modbus TCP server configuration on 127.0.0.1 (port 0: any free port) for these tests.
#pragma once

#include <cstdint>

#include "modbus/modbus.hpp"

namespace pnp::testing {

inline modbus::TcpServerConfig modbusLoopback(std::uint16_t port = 0) {
    modbus::TcpServerConfig c;
    c.bindAddress = "127.0.0.1";
    c.port = port;
    return c;
}

}  // namespace pnp::testing
