// Socket helpers of the raw adapters (tcp, udp): IPv4 addresses and errno errors.
#pragma once

#include <arpa/inet.h>
#include <netinet/in.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>

namespace pnp::bench::driver {

// Throws `what` with the text of errno.
[[noreturn]] inline void failErrno(const std::string& what) {
    throw std::runtime_error(what + ": " + std::strerror(errno));
}

inline sockaddr_in ipv4Address(const std::string& host, int port) {
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<std::uint16_t>(port));
    if (inet_pton(AF_INET, host.c_str(), &a.sin_addr) != 1)
        throw std::runtime_error("not an IPv4 address: " + host);
    return a;
}

}  // namespace pnp::bench::driver
