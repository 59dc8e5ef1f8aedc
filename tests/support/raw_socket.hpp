// A raw TCP connection to a server on 127.0.0.1 for tests that play a misbehaving client:
// send arbitrary bytes, read whole opc.tcp chunks, watch for ERR and for the close. Every
// wait has a deadline.
#pragma once

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <optional>

#include "ua/transport/chunks.hpp"
#include "ua/transport/common.hpp"
#include "ua/transport/tcp_messages.hpp"

namespace pnp::ua::test {

class RawSocket {
  public:
    using Clock = transport::Clock;
    using Deadline = transport::Deadline;

    explicit RawSocket(UInt16 port) {
        fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(port);
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        if (fd_ >= 0 && ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
            ::close(fd_);
            fd_ = -1;
        }
        if (fd_ >= 0) {
            int one = 1;
            ::setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        }
    }
    ~RawSocket() { closeNow(); }
    RawSocket(const RawSocket&) = delete;
    RawSocket& operator=(const RawSocket&) = delete;

    bool ok() const { return fd_ >= 0; }
    int fd() const { return fd_; }
    void closeNow() {
        if (fd_ >= 0) ::close(fd_);
        fd_ = -1;
    }
    // Close with a TCP reset instead of a FIN.
    void resetNow() {
        if (fd_ < 0) return;
        linger l{1, 0};
        ::setsockopt(fd_, SOL_SOCKET, SO_LINGER, &l, sizeof l);
        closeNow();
    }
    bool send(const Buffer& b) { return send(b.data(), b.size()); }
    bool send(const void* p, std::size_t n) {
        auto c = static_cast<const char*>(p);
        while (n > 0) {
            ssize_t k = ::send(fd_, c, n, MSG_NOSIGNAL);
            if (k <= 0) return false;
            c += k;
            n -= static_cast<std::size_t>(k);
        }
        return true;
    }
    // Sends without blocking for longer than `limit` in total; false when the peer did not
    // take everything in time.
    bool trySend(const Buffer& b, std::chrono::milliseconds limit) {
        auto end = Clock::now() + limit;
        std::size_t off = 0;
        while (off < b.size()) {
            ssize_t k = ::send(fd_, b.data() + off, b.size() - off, MSG_NOSIGNAL | MSG_DONTWAIT);
            if (k > 0) {
                off += static_cast<std::size_t>(k);
                continue;
            }
            if (k < 0 && errno != EAGAIN && errno != EWOULDBLOCK) return false;
            auto left = std::chrono::duration_cast<std::chrono::milliseconds>(end - Clock::now());
            if (left.count() <= 0) return false;
            pollfd p{fd_, POLLOUT, 0};
            ::poll(&p, 1, static_cast<int>(left.count()));
        }
        return true;
    }
    // Reads until `in_` holds n bytes; false on EOF, error or deadline.
    bool fill(std::size_t n, Deadline deadline) {
        while (in_.size() < n) {
            auto left =
                std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
            if (left.count() <= 0) return false;
            pollfd p{fd_, POLLIN, 0};
            if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) return false;
            Byte buf[65536];
            ssize_t k = ::recv(fd_, buf, sizeof buf, 0);
            if (k <= 0) {
                eof_ = true;
                return false;
            }
            in_.insert(in_.end(), buf, buf + k);
        }
        return true;
    }
    // The next whole chunk / message of the connection protocol (header included).
    std::optional<Buffer> readChunk(Deadline deadline = Clock::now() + std::chrono::seconds(5)) {
        if (!fill(8, deadline)) return std::nullopt;
        UInt32 size = transport::getUInt32(in_.data() + 4);
        if (size < 8 || size > (64u << 20) || !fill(size, deadline)) return std::nullopt;
        Buffer c(in_.begin(), in_.begin() + size);
        in_.erase(in_.begin(), in_.begin() + size);
        return c;
    }
    // Reads until an ERR arrives; its code, or Good when none came before EOF / deadline.
    StatusCode expectError(Deadline deadline = Clock::now() + std::chrono::seconds(5)) {
        while (auto c = readChunk(deadline)) {
            if (transport::decodeMessageHeader(c->data()).type == transport::MessageType::Error)
                return transport::decodeError(c->data() + 8, c->size() - 8).error;
        }
        return StatusCode{};
    }
    // True when the server closed the connection (EOF or reset) before the deadline.
    bool waitClosed(Deadline deadline = Clock::now() + std::chrono::seconds(5)) {
        while (!eof_) {
            in_.clear();
            if (!fill(1, deadline) && !eof_) return false;
        }
        return true;
    }

  private:
    int fd_ = -1;
    Buffer in_;
    bool eof_ = false;
};

}  // namespace pnp::ua::test
