// Raw TCP: the floor for the TCP-based middlewares. Every message is one frame, a 4-byte
// little-endian length and the bytes (the thesis's baseline read without framing, so a
// large echo could come back in pieces and be timed early). TCP_NODELAY on every socket.
//
// Ports: server at --port (default 7310); chain node i at port + 1 + i, the client's sink at
// port + 1 + streams * hops on the address of setting sink-host (default 127.0.0.1).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/uio.h>
#include <unistd.h>

#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <list>
#include <map>
#include <mutex>
#include <thread>
#include <utility>

#include "bench/driver/driver.hpp"
#include "bench/driver/net.hpp"

namespace pnp::bench::tcp {
namespace {

using driver::Bytes;
using driver::Clock;
using driver::Options;
using driver::failErrno;
using driver::ipv4Address;

constexpr int kDefaultPort = 7310;
constexpr std::uint32_t kMaxFrame = 64u << 20;

int basePort(const Options& o) { return o.port ? o.port : kDefaultPort; }

class Socket {
  public:
    explicit Socket(int fd = -1) : fd_(fd) {}
    Socket(Socket&& o) noexcept : fd_(std::exchange(o.fd_, -1)) {}
    Socket& operator=(Socket&& o) noexcept {
        if (this != &o) {
            reset();
            fd_ = std::exchange(o.fd_, -1);
        }
        return *this;
    }
    ~Socket() { reset(); }
    void reset() {
        if (fd_ >= 0) ::close(fd_);
        fd_ = -1;
    }
    int fd() const { return fd_; }

  private:
    int fd_;
};

// A connected socket: TCP_NODELAY, and reads that return every 100 ms without data.
void connected(int fd) {
    int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    timeval tv{0, 100000};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
}

Socket listenOn(const std::string& host, int port) {
    Socket s(::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0));
    if (s.fd() < 0) failErrno("socket");
    int one = 1;
    ::setsockopt(s.fd(), SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in a = ipv4Address(host, port);
    if (::bind(s.fd(), reinterpret_cast<sockaddr*>(&a), sizeof a) != 0)
        failErrno("bind " + host + ":" + std::to_string(port));
    if (::listen(s.fd(), 128) != 0) failErrno("listen");
    return s;
}

// Connects, retrying until the deadline (a chain's next node may still be starting).
Socket connectTo(const std::string& host, int port, Clock::time_point deadline) {
    for (;;) {
        Socket s(::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0));
        if (s.fd() < 0) failErrno("socket");
        sockaddr_in a = ipv4Address(host, port);
        if (::connect(s.fd(), reinterpret_cast<sockaddr*>(&a), sizeof a) == 0) {
            connected(s.fd());
            return s;
        }
        if (Clock::now() >= deadline) failErrno("connect " + host + ":" + std::to_string(port));
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
}

// Waits until fd is readable; false when stop was requested or the deadline passed.
bool waitReadable(int fd, const std::stop_token& stop, Clock::time_point deadline) {
    for (;;) {
        if (stop.stop_requested() || Clock::now() >= deadline) return false;
        pollfd p{fd, POLLIN, 0};
        const int r = ::poll(&p, 1, 100);
        if (r > 0) return true;
        if (r < 0 && errno != EINTR) failErrno("poll");
    }
}

// Reads exactly n bytes; false at end of stream, stop or deadline. Blocking reads (one
// syscall per read when data is there: the floor must not pay for a poll per message); the
// sockets' 100 ms receive timeout (connected()) lets the loop see stop and the deadline.
bool readAll(int fd, std::byte* out, std::size_t n, const std::stop_token& stop,
             Clock::time_point deadline) {
    std::size_t done = 0;
    while (done < n) {
        const ssize_t r = ::recv(fd, out + done, n - done, 0);
        if (r > 0) {
            done += static_cast<std::size_t>(r);
            continue;
        }
        if (r == 0) return false;
        if (errno == EINTR) continue;
        if (errno != EAGAIN && errno != EWOULDBLOCK) return false;
        if (stop.stop_requested() || Clock::now() >= deadline) return false;
    }
    return true;
}

void writeFrame(int fd, std::span<const std::byte> bytes) {
    const auto n = static_cast<std::uint32_t>(bytes.size());
    std::byte head[4];
    for (int i = 0; i < 4; ++i) head[i] = static_cast<std::byte>((n >> (8 * i)) & 0xFF);
    iovec v[2] = {{head, 4}, {const_cast<std::byte*>(bytes.data()), bytes.size()}};
    std::size_t left = 4 + bytes.size();
    int first = 0;
    while (left > 0) {
        msghdr m{};
        m.msg_iov = v + first;
        m.msg_iovlen = static_cast<std::size_t>(2 - first);
        const ssize_t w = ::sendmsg(fd, &m, MSG_NOSIGNAL);
        if (w < 0) {
            if (errno == EINTR) continue;
            failErrno("send");
        }
        auto k = static_cast<std::size_t>(w);
        left -= k;
        while (k > 0 && first < 2) {
            const std::size_t take = std::min(k, v[first].iov_len);
            v[first].iov_base = static_cast<std::byte*>(v[first].iov_base) + take;
            v[first].iov_len -= take;
            k -= take;
            if (v[first].iov_len == 0) ++first;
        }
    }
}

bool readFrame(int fd, Bytes& out, const std::stop_token& stop, Clock::time_point deadline) {
    std::byte head[4];
    if (!readAll(fd, head, 4, stop, deadline)) return false;
    std::uint32_t n = 0;
    for (int i = 0; i < 4; ++i) n |= static_cast<std::uint32_t>(head[i]) << (8 * i);
    if (n > kMaxFrame) return false;  // not our peer: drop the connection
    out.resize(n);
    return readAll(fd, out.data(), n, stop, deadline);
}

constexpr auto kForever = Clock::time_point::max();

// Accepts connections until stop; each is served by `serve` on a thread of its own.
void acceptLoop(int listenFd, const std::stop_token& stop,
                const std::function<void(Socket)>& serve) {
    std::list<std::jthread> workers;
    for (std::size_t accepted = 0; !stop.stop_requested();) {
        if (!waitReadable(listenFd, stop, kForever)) break;
        Socket c(::accept4(listenFd, nullptr, nullptr, SOCK_CLOEXEC));
        if (c.fd() < 0) continue;
        if (++accepted > 4096) break;  // bounded: a benchmark peer opens a handful
        connected(c.fd());
        workers.emplace_back([&serve, s = std::move(c)]() mutable { serve(std::move(s)); });
    }
    // jthreads join here; their loops end on stop (checked every 100 ms).
}

class TcpClient final : public driver::Client {
  public:
    explicit TcpClient(const Options& o)
        : timeout_(o.timeoutMs),
          socket_(connectTo(o.host, basePort(o),
                            Clock::now() + std::chrono::milliseconds(o.timeoutMs))) {}

    void request(std::span<const std::byte> payload, Bytes& reply) override {
        writeFrame(socket_.fd(), payload);
        if (!readFrame(socket_.fd(), reply, stop_.get_token(),
                       Clock::now() + std::chrono::milliseconds(timeout_)))
            throw std::runtime_error("no answer from the server");
    }

  private:
    int timeout_;
    std::stop_source stop_;
    Socket socket_;
};

void runServer(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    Socket l = listenOn(o.host, basePort(o));
    const bool echo = o.mode == driver::Mode::Echo;
    ctx.ready();
    acceptLoop(l.fd(), ctx.stop, [&](Socket c) {
        Bytes buf;
        const std::byte ack[1] = {std::byte{1}};
        while (readFrame(c.fd(), buf, ctx.stop, kForever)) {
            if (echo)
                writeFrame(c.fd(), buf);
            else
                writeFrame(c.fd(), ack);
        }
    });
}

int sinkPort(const Options& o) { return basePort(o) + 1 + o.nodes(); }

void runChainNodes(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    const std::string sinkHost = o.setting("sink-host", "127.0.0.1");
    std::vector<Socket> listeners;
    for (int i = o.first; i < o.first + o.count; ++i)
        listeners.push_back(listenOn(o.host, basePort(o) + 1 + i));
    ctx.ready();
    std::vector<std::jthread> nodes;
    for (int k = 0; k < o.count; ++k) {
        const int i = o.first + k;
        nodes.emplace_back([&, i, fd = listeners[static_cast<std::size_t>(k)].fd()] {
            // One outgoing connection per node, shared by its incoming connections.
            std::mutex sendLock;
            Socket next;
            acceptLoop(fd, ctx.stop, [&](Socket c) {
                Bytes buf;
                while (readFrame(c.fd(), buf, ctx.stop, kForever)) {
                    std::lock_guard lock(sendLock);
                    if (next.fd() < 0) {
                        const bool last = (i + 1) % o.hops == 0;
                        next = last ? connectTo(sinkHost, sinkPort(o),
                                                Clock::now() + std::chrono::seconds(10))
                                    : connectTo(o.host, basePort(o) + 2 + i,
                                                Clock::now() + std::chrono::seconds(10));
                    }
                    writeFrame(next.fd(), buf);
                }
            });
        });
    }
}

class TcpChainClient final : public driver::ChainClient {
  public:
    explicit TcpChainClient(const Options& o) : options_(o), sink_(listenOn(o.local, sinkPort(o))) {
        acceptor_ = std::jthread([this](std::stop_token stop) {
            acceptLoop(sink_.fd(), stop, [this, stop](Socket c) {
                Bytes buf;
                while (readFrame(c.fd(), buf, stop, kForever)) {
                    std::lock_guard lock(mutex_);
                    inbox_.push_back(std::move(buf));
                    ready_.notify_one();
                }
            });
        });
    }

    void send(int node, std::span<const std::byte> message) override {
        auto it = firsts_.find(node);
        if (it == firsts_.end())
            it = firsts_
                     .emplace(node, connectTo(options_.host, basePort(options_) + 1 + node,
                                              Clock::now() + std::chrono::seconds(10)))
                     .first;
        writeFrame(it->second.fd(), message);
    }

    bool receive(Bytes& message, Clock::time_point deadline) override {
        std::unique_lock lock(mutex_);
        if (!ready_.wait_until(lock, deadline, [&] { return !inbox_.empty(); })) return false;
        message = std::move(inbox_.front());
        inbox_.pop_front();
        return true;
    }

  private:
    const Options& options_;
    Socket sink_;
    std::map<int, Socket> firsts_;
    std::mutex mutex_;
    std::condition_variable ready_;
    std::deque<Bytes> inbox_;
    std::jthread acceptor_;  // last: stopped and joined first
};

}  // namespace
}  // namespace pnp::bench::tcp

int main(int argc, char** argv) {
    using namespace pnp::bench;
    driver::Adapter a;
    a.name = "tcp";
    a.variants = {"tcp"};
    a.description = "raw TCP, 4-byte length frames, TCP_NODELAY (the floor)";
    a.makeClient = [](const driver::Options& o) { return std::make_unique<tcp::TcpClient>(o); };
    a.runServer = tcp::runServer;
    a.runChainNodes = tcp::runChainNodes;
    a.makeChainClient = [](const driver::Options& o) {
        return std::make_unique<tcp::TcpChainClient>(o);
    };
    return driver::adapterMain(argc, argv, a);
}
