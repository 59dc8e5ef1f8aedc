#include "ua/transport/client_connection.hpp"

#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cstring>

#include "ua/transport/gather.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {

namespace {

std::string errnoText(int err) { return std::strerror(err); }

// Waits until fd is ready for `events` or the deadline passes (a passed deadline still
// checks once). True when ready (or in error: the next call reports it).
bool waitFor(int fd, short events, Deadline deadline) {
    for (;;) {
        auto now = Clock::now();
        timespec ts{0, 0};
        if (deadline > now) {
            auto left = std::chrono::duration_cast<std::chrono::nanoseconds>(deadline - now);
            // Cap very long waits (Deadline max) to something ppoll accepts.
            constexpr std::chrono::nanoseconds kCap = std::chrono::hours(24);
            if (left > kCap) left = kCap;
            ts.tv_sec = static_cast<time_t>(left.count() / 1'000'000'000);
            ts.tv_nsec = static_cast<long>(left.count() % 1'000'000'000);
        }
        pollfd p{fd, events, 0};
        int r = ::ppoll(&p, 1, &ts, nullptr);
        if (r > 0) return true;
        if (r < 0 && errno != EINTR) return true;  // let the I/O call report the error
        if (r == 0 && Clock::now() >= deadline) return false;
    }
}

int tcpConnect(const EndpointUrl& url, Deadline deadline) {
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    hints.ai_flags = AI_NUMERICSERV;
    addrinfo* res = nullptr;
    std::string port = std::to_string(url.port);
    int rc = ::getaddrinfo(url.host.c_str(), port.c_str(), &hints, &res);
    if (rc != 0) {
        throw TransportError(status::BadCommunicationError,
                             "cannot resolve " + url.host + ": " + ::gai_strerror(rc));
    }
    std::string lastError = "no address";
    int fd = -1;
    bool timedOut = false;
    for (addrinfo* ai = res; ai && fd < 0; ai = ai->ai_next) {
        int s = ::socket(ai->ai_family, ai->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC,
                         ai->ai_protocol);
        if (s < 0) {
            lastError = errnoText(errno);
            continue;
        }
        int r = ::connect(s, ai->ai_addr, ai->ai_addrlen);
        if (r < 0 && errno == EINPROGRESS) {
            if (!waitFor(s, POLLOUT, deadline)) {
                ::close(s);
                timedOut = true;
                break;
            }
            int err = 0;
            socklen_t len = sizeof err;
            ::getsockopt(s, SOL_SOCKET, SO_ERROR, &err, &len);
            r = err == 0 ? 0 : -1;
            errno = err;
        }
        if (r < 0) {
            lastError = errnoText(errno);
            ::close(s);
            continue;
        }
        fd = s;
    }
    ::freeaddrinfo(res);
    if (timedOut) throw TransportError(status::BadTimeout, "TCP connect to " + url.host);
    if (fd < 0) {
        throw TransportError(status::BadCommunicationError,
                             "TCP connect to " + url.host + ":" + port + ": " + lastError);
    }
    int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    // Connected: from now on the socket blocks; sends pass MSG_DONTWAIT, receives wait in
    // recv() itself (see receiveBlocking).
    int flags = ::fcntl(fd, F_GETFL);
    if (flags < 0 || ::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK) != 0) {
        int err = errno;
        ::close(fd);
        throw TransportError(status::BadCommunicationError, "fcntl: " + errnoText(err));
    }
    return fd;
}

}  // namespace

EndpointUrl parseEndpointUrl(const std::string& url) {
    auto bad = [&](const char* why) -> TransportError {
        return TransportError(status::BadTcpEndpointUrlInvalid,
                              std::string(why) + ": \"" + url.substr(0, 200) + "\"");
    };
    constexpr std::string_view kScheme = "opc.tcp://";
    if (url.size() > kMaxUrlLength) throw bad("endpoint URL too long");
    if (url.size() < kScheme.size() ||
        !std::equal(kScheme.begin(), kScheme.end(), url.begin(), [](char a, char b) {
            return a == std::tolower(static_cast<unsigned char>(b));
        }))
        throw bad("not an opc.tcp URL");
    EndpointUrl r;
    std::size_t i = kScheme.size();
    if (i < url.size() && url[i] == '[') {
        auto close = url.find(']', i);
        if (close == std::string::npos) throw bad("unterminated IPv6 address");
        r.host = url.substr(i + 1, close - i - 1);
        i = close + 1;
    } else {
        auto end = url.find_first_of(":/", i);
        if (end == std::string::npos) end = url.size();
        r.host = url.substr(i, end - i);
        i = end;
    }
    if (r.host.empty()) throw bad("no host");
    if (i < url.size() && url[i] == ':') {
        ++i;
        auto end = url.find('/', i);
        if (end == std::string::npos) end = url.size();
        std::string p = url.substr(i, end - i);
        if (p.empty() || p.size() > 5 ||
            !std::all_of(p.begin(), p.end(), [](char c) { return c >= '0' && c <= '9'; }))
            throw bad("invalid port");
        unsigned long v = std::stoul(p);
        if (v == 0 || v > 65535) throw bad("invalid port");
        r.port = static_cast<UInt16>(v);
        i = end;
    }
    if (i < url.size()) {
        if (url[i] != '/') throw bad("invalid character after host");
        r.path = url.substr(i);
    }
    return r;
}

// =======================================================================================
ClientConnection::ClientConnection(const std::string& url, const ClientConfig& config)
    : url_(url), config_(config), channel_(config_, url, *this) {
    // Bodies stay in the receive buffer until the next read (see receive()).
    channel_.setViewBodies(true);
}

ClientConnection::~ClientConnection() { close(); }

std::unique_ptr<ClientConnection> ClientConnection::connect(const std::string& endpointUrl,
                                                            const ClientConfig& config,
                                                            Deadline deadline) {
    EndpointUrl ep = parseEndpointUrl(endpointUrl);
    std::unique_ptr<ClientConnection> c(new ClientConnection(endpointUrl, config));
    c->fd_ = tcpConnect(ep, deadline);
    c->writeDeadline_ = deadline;
    c->channel_.start(Clock::now());
    while (!c->channel_.isOpen()) {
        if (!c->readOnce(deadline)) {
            c->closeSocket();
            throw TransportError(status::BadTimeout, "opening a secure channel to " + endpointUrl);
        }
    }
    return c;
}

bool ClientConnection::isOpen() const { return fd_ >= 0 && channel_.isOpen(); }

void ClientConnection::closeSocket() {
    if (fd_ >= 0) {
        ::close(fd_);
        fd_ = -1;
    }
}

void ClientConnection::failClosed(StatusCode status, const std::string& what) {
    closeSocket();
    throw TransportError(status, what);
}

void ClientConnection::write(Buffer&& bytes) {
    iovec v{bytes.data(), bytes.size()};
    writeAll(&v, 1);
    keepForReuse(std::move(bytes));
}

void ClientConnection::writeSpliced(Buffer&& bytes, const Splices& splices) {
    // Usually one spliced run: header, run, trailer.
    constexpr std::size_t kOnStack = 8;
    iovec onStack[kOnStack];
    std::vector<iovec> onHeap;
    const std::size_t most = 2 * splices.size() + 1;
    iovec* v = onStack;
    if (most > kOnStack) {
        onHeap.resize(most);
        v = onHeap.data();
    }
    std::size_t count = 0;
    forEachPiece(bytes, splices, 0, [&](const Byte* p, std::size_t n) {
        v[count++] = {const_cast<Byte*>(p), n};
        return true;
    });
    writeAll(v, count);
    keepForReuse(std::move(bytes));
}

void ClientConnection::writeAll(iovec* iov, std::size_t count) {
    if (fd_ < 0) throw TransportError(status::BadConnectionClosed, "connection closed");
    while (count > 0) {
        ssize_t n = sendPieces(fd_, iov, count, MSG_NOSIGNAL | MSG_DONTWAIT);
        if (n > 0) {
            iov = advanceIovecs(iov, count, static_cast<std::size_t>(n));
            continue;
        }
        int err = n < 0 ? errno : EPIPE;
        if (err == EINTR) continue;
        if (err == EAGAIN || err == EWOULDBLOCK) {
            if (!waitFor(fd_, POLLOUT, writeDeadline_))
                failClosed(status::BadTimeout, "send: the server does not take the data");
            continue;
        }
        failClosed(err == EPIPE || err == ECONNRESET ? status::BadConnectionClosed
                                                     : status::BadCommunicationError,
                   "send: " + errnoText(err));
    }
}

void ClientConnection::keepForReuse(Buffer&& bytes) {
    // Kept for the next request's memory; a large one is not: one big request should not
    // pin its memory.
    constexpr std::size_t kKeepUpTo = 64 * 1024;
    if (bytes.capacity() <= kKeepUpTo) {
        bytes.clear();
        spare_ = std::move(bytes);
    }
}

Buffer ClientConnection::messageBuffer() {
    if (spare_.capacity() == 0) return newMessageBuffer();
    Buffer b = std::move(spare_);
    spare_ = Buffer();
    b.resize(kSymmetricHeaderSize);
    return b;
}

void ClientConnection::response(IncomingResponse&& r) { ready_.push_back(std::move(r)); }

// Why a blocking socket: a round trip is one send() and one recv() that sleeps in the kernel
// until the response is there. poll() + non-blocking recv() costs one more system call
// (~0.75 us of a ~15 us loopback round trip). The deadline becomes SO_RCVTIMEO; it is re-set
// only when the armed one would overshoot the deadline by more than kTimeoutSlack or wake
// far too early, so a series of requests with the same timeout sets it once. SO_RCVTIMEO
// rounds to scheduler ticks (and the time left is taken from the coarse clock), so a
// deadline more than 20 ms away is kept to within a few ms; shorter waits keep to the precise
// ppoll() path.
namespace {
constexpr std::chrono::nanoseconds kTimeoutSlack = std::chrono::milliseconds(2);
constexpr std::chrono::nanoseconds kPreciseBelow = std::chrono::milliseconds(20);
constexpr std::chrono::nanoseconds kTimeoutCap = std::chrono::hours(24);
}  // namespace

long ClientConnection::receiveBlocking(std::span<Byte> space, std::chrono::nanoseconds left) {
    left = std::min(left, kTimeoutCap);
    if (receiveTimeout_ == std::chrono::nanoseconds{0} || receiveTimeout_ > left + kTimeoutSlack ||
        receiveTimeout_ < left / 2) {
        auto us = std::chrono::duration_cast<std::chrono::microseconds>(left).count();
        timeval tv{static_cast<time_t>(us / 1'000'000), static_cast<suseconds_t>(us % 1'000'000)};
        if (::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv) != 0) {
            // Cannot arm a timeout: wait precisely instead of blocking without one.
            if (!waitFor(fd_, POLLIN, Clock::now() + left)) {
                errno = EAGAIN;
                return -1;
            }
            return ::recv(fd_, space.data(), space.size(), MSG_DONTWAIT);
        }
        receiveTimeout_ = left;
    }
    return ::recv(fd_, space.data(), space.size(), 0);
}

bool ClientConnection::readOnce(Deadline deadline) {
    if (fd_ < 0) throw TransportError(status::BadConnectionClosed, "connection closed");
    // Responses not yet handed out must not point into the buffer about to be read into.
    for (std::size_t i = readyHead_; i < ready_.size(); ++i) ready_[i].body.own();
    auto space = channel_.readSpace();
    for (;;) {
        // Coarse: the deadline is kept to within a scheduler tick (see receiveBlocking).
        auto now = coarseNow();
        ssize_t n;
        if (deadline <= now) {
            n = ::recv(fd_, space.data(), space.size(), MSG_DONTWAIT);
        } else if (deadline - now < kPreciseBelow) {
            if (!waitFor(fd_, POLLIN, deadline)) return false;
            n = ::recv(fd_, space.data(), space.size(), MSG_DONTWAIT);
        } else {
            n = receiveBlocking(space, deadline - now);
        }
        if (n > 0) {
            try {
                channel_.received(static_cast<std::size_t>(n), coarseNow());
            } catch (const TransportError&) {
                closeSocket();
                throw;
            }
            return true;
        }
        if (n == 0) failClosed(status::BadConnectionClosed, "the server closed the connection");
        int err = errno;
        if (err == EINTR) continue;
        if (err == EAGAIN || err == EWOULDBLOCK) {
            if (Clock::now() >= deadline) return false;
            continue;
        }
        failClosed(err == ECONNRESET ? status::BadConnectionClosed : status::BadCommunicationError,
                   "recv: " + errnoText(err));
    }
}

void ClientConnection::drainAvailable() {
    while (fd_ >= 0 && readOnce(TimePoint::min())) {
    }
}

UInt32 ClientConnection::send(Buffer&& message) {
    return send(std::move(message), Clock::now() + config_.sendTimeout);
}

UInt32 ClientConnection::send(Buffer&& message, Deadline deadline) {
    return send(std::move(message), Splices{}, deadline);
}

UInt32 ClientConnection::send(Buffer&& message, Splices&& splices, Deadline deadline) {
    if (!isOpen()) throw TransportError(status::BadConnectionClosed, "connection closed");
    writeDeadline_ = deadline;
    channel_.renewIfDue(coarseNow());
    // A renew response that is already there switches us to the new token before sending.
    if (channel_.renewPending()) drainAvailable();
    return channel_.send(std::move(message), std::move(splices));
}

std::optional<IncomingResponse> ClientConnection::receive(Deadline deadline) {
    for (;;) {
        if (readyHead_ < ready_.size()) return receiveReady(false);
        if (!isOpen()) throw TransportError(status::BadConnectionClosed, "connection closed");
        renewIfDue();
        Deadline wake = deadline;
        if (!channel_.renewPending()) wake = std::min(wake, channel_.renewalDue());
        if (!readOnce(wake) && Clock::now() >= deadline) {
            if (readyHead_ < ready_.size()) continue;
            return std::nullopt;
        }
    }
}

std::optional<IncomingResponse> ClientConnection::receiveReady(bool readable) {
    if (readyHead_ == ready_.size() && readable && isOpen()) readOnce(TimePoint::min());
    if (readyHead_ == ready_.size()) return std::nullopt;
    IncomingResponse r = std::move(ready_[readyHead_++]);
    if (readyHead_ == ready_.size()) {
        ready_.clear();
        readyHead_ = 0;
    }
    return r;
}

bool ClientConnection::renewIfDue() {
    if (!isOpen()) return false;
    auto now = coarseNow();
    writeDeadline_ = now + config_.sendTimeout;
    return channel_.renewIfDue(now);
}

void ClientConnection::close() {
    if (fd_ < 0) return;
    writeDeadline_ = Clock::now() + std::chrono::milliseconds(500);
    try {
        channel_.close();  // writes CLO when open
    } catch (...) {
    }
    if (fd_ >= 0) ::shutdown(fd_, SHUT_WR);
    closeSocket();
}

}  // namespace pnp::ua::transport
