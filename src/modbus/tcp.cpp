// Modbus TCP (Messaging on TCP/IP Implementation Guide V1.0b): the MBAP header (transaction
// id, protocol id 0, length of unit id + PDU, unit id) before each PDU; one poll() thread for
// the listening socket and every connection, answers in order per connection.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <list>
#include <system_error>
#include <thread>

#include "modbus/modbus.hpp"

namespace pnp::modbus {

namespace {

constexpr std::size_t kHeader = 7;       // MBAP
constexpr std::size_t kMinLength = 2;    // unit id + function code
constexpr std::size_t kMaxLength = 254;  // unit id + PDU of 253: an ADU of 260

[[noreturn]] void fail(const char* what) {
    throw std::system_error(errno, std::generic_category(), what);
}

struct Connection {
    int fd = -1;
    std::vector<std::uint8_t> in;
    std::vector<std::uint8_t> out;
    bool closing = false;
};

}  // namespace

struct TcpServer::Impl {
    Impl(TcpServerConfig config, Registers& registers)
        : config(std::move(config)), registers(registers) {}

    void run() {
        std::vector<pollfd> fds;
        while (true) {
            fds.clear();
            fds.push_back({wake[0], POLLIN, 0});
            fds.push_back({listener, POLLIN, 0});
            for (const Connection& c : connections) {
                fds.push_back(
                    {c.fd, static_cast<short>(POLLIN | (c.out.empty() ? 0 : POLLOUT)), 0});
            }
            // stop() wakes the poll at once; the cap only bounds the wait.
            const int n = ::poll(fds.data(), fds.size(), 1000);
            if (n < 0 && errno != EINTR) return;
            if (fds[0].revents != 0) return;
            std::size_t i = 2;
            for (Connection& c : connections) serve(c, fds[i++].revents);
            connections.remove_if([](const Connection& c) {
                if (c.closing) ::close(c.fd);
                return c.closing;
            });
            if (fds[1].revents & POLLIN) accept();
        }
    }

    void accept() {
        const int fd = ::accept4(listener, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0) return;
        if (connections.size() >= config.maxConnections) {
            ::close(fd);
            return;
        }
        const int one = 1;
        setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        connections.push_back({fd, {}, {}, false});
    }

    void serve(Connection& c, short revents) {
        if (revents & POLLIN) {
            std::array<std::uint8_t, 4096> buffer{};
            const ssize_t got = ::recv(c.fd, buffer.data(), buffer.size(), 0);
            if (got == 0 || (got < 0 && errno != EAGAIN && errno != EINTR)) {
                c.closing = true;
                return;
            }
            if (got > 0) {
                c.in.insert(c.in.end(), buffer.begin(), buffer.begin() + got);
                parse(c);
            }
        } else if (revents & (POLLHUP | POLLERR | POLLNVAL)) {
            c.closing = true;
            return;
        }
        if (!c.out.empty() && !c.closing) {
            const ssize_t w = ::send(c.fd, c.out.data(), c.out.size(), MSG_NOSIGNAL);
            if (w > 0) {
                c.out.erase(c.out.begin(), c.out.begin() + w);
            } else if (w < 0 && errno != EAGAIN && errno != EINTR) {
                c.closing = true;
            }
        }
        // A client that sends but does not read would grow the buffer without bound.
        if (c.out.size() > config.maxPendingOutput) c.closing = true;
    }

    // Every complete ADU in the buffer; a partial one (at most 259 bytes) waits for the rest.
    void parse(Connection& c) {
        std::size_t at = 0;
        while (!c.closing && c.in.size() - at >= kHeader) {
            const std::uint8_t* h = c.in.data() + at;
            const std::size_t protocol = static_cast<std::size_t>(h[2] << 8 | h[3]);
            const std::size_t length = static_cast<std::size_t>(h[4] << 8 | h[5]);
            if (protocol != 0 || length < kMinLength || length > kMaxLength) {
                c.closing = true;  // not Modbus: resynchronising on a byte stream is guesswork
                break;
            }
            if (c.in.size() - at < 6 + length) break;
            respond(c, std::span(h, 6 + length));
            at += 6 + length;
        }
        c.in.erase(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(at));
    }

    void respond(Connection& c, std::span<const std::uint8_t> adu) {
        if (!registers.answering()) return;
        const std::uint8_t unit = adu[6];
        const std::span<const std::uint8_t> pdu = adu.subspan(kHeader);
        std::vector<std::uint8_t> reply;
        if (config.unitId && unit != *config.unitId) {
            reply = {static_cast<std::uint8_t>(pdu[0] | 0x80),
                     static_cast<std::uint8_t>(Exception::kGatewayTargetFailed)};
        } else {
            reply = answer(registers, pdu);
        }
        if (reply.empty()) return;
        const std::size_t length = reply.size() + 1;
        c.out.insert(c.out.end(), {adu[0], adu[1], 0, 0, static_cast<std::uint8_t>(length >> 8),
                                   static_cast<std::uint8_t>(length & 0xFF), unit});
        c.out.insert(c.out.end(), reply.begin(), reply.end());
    }

    TcpServerConfig config;
    Registers& registers;
    int listener = -1;
    std::uint16_t port = 0;
    std::array<int, 2> wake{-1, -1};
    std::list<Connection> connections;
    std::thread thread;
};

TcpServer::TcpServer(TcpServerConfig config, Registers& registers)
    : impl_(std::make_unique<Impl>(std::move(config), registers)) {}

TcpServer::~TcpServer() { stop(); }

void TcpServer::start() {
    if (impl_->thread.joinable()) return;
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_port = htons(impl_->config.port);
    if (inet_pton(AF_INET, impl_->config.bindAddress.c_str(), &address.sin_addr) != 1) {
        errno = EINVAL;
        fail("TcpServer: bind address");
    }
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) fail("TcpServer: socket");
    try {
        const int one = 1;
        setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        if (::bind(fd, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) {
            fail("TcpServer: bind");
        }
        if (::listen(fd, 16) != 0) fail("TcpServer: listen");
        socklen_t size = sizeof address;
        if (getsockname(fd, reinterpret_cast<sockaddr*>(&address), &size) != 0) {
            fail("TcpServer: getsockname");
        }
        if (pipe2(impl_->wake.data(), O_CLOEXEC | O_NONBLOCK) != 0) fail("TcpServer: pipe");
    } catch (...) {
        ::close(fd);
        throw;
    }
    impl_->listener = fd;
    impl_->port = ntohs(address.sin_port);
    impl_->thread = std::thread([impl = impl_.get()] { impl->run(); });
}

void TcpServer::stop() {
    if (!impl_->thread.joinable()) return;
    const std::uint8_t byte = 1;
    [[maybe_unused]] const ssize_t w = ::write(impl_->wake[1], &byte, 1);
    impl_->thread.join();
    for (const Connection& c : impl_->connections) ::close(c.fd);
    impl_->connections.clear();
    ::close(impl_->listener);
    impl_->listener = -1;
    for (int& f : impl_->wake) {
        ::close(f);
        f = -1;
    }
}

std::uint16_t TcpServer::port() const { return impl_->port; }

}  // namespace pnp::modbus
