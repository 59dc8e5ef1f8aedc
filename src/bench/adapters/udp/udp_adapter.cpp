// Raw UDP: the floor for the UDP-based middlewares. One datagram per request and one per
// answer, each starting with an 8-byte little-endian sequence number: the client discards an
// answer whose number is not the one of the request it waits for (the late answer of a
// request that timed out), and retransmits the request every retransmit-ms until the
// request's timeout. The server answers every datagram at once (ACK: the number and one
// byte; echo: the datagram as received) and keeps no state.
//
// Ports: server at --port (default 7311) on --host; chain node i at port + 1 + i on --host,
// the client's sink at port + 1 + streams * hops on --local (nodes send to setting sink-host,
// default 127.0.0.1). Settings: retransmit-ms=N (default 200).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <iostream>
#include <thread>
#include <utility>

#include "bench/driver/driver.hpp"
#include "bench/driver/net.hpp"

namespace pnp::bench::udp {
namespace {

using driver::Bytes;
using driver::Clock;
using driver::Options;
using driver::failErrno;
using driver::ipv4Address;

constexpr int kDefaultPort = 7311;
constexpr std::size_t kHeader = 8;           // the sequence number
constexpr std::size_t kMaxDatagram = 65507;  // IPv4: 65535 - 20 (IP) - 8 (UDP)
constexpr std::size_t kMaxPayload = kMaxDatagram - kHeader;
// How often a blocked receive wakes up to look at stop requests and deadlines.
constexpr std::chrono::milliseconds kPoll{50};

int basePort(const Options& o) { return o.port ? o.port : kDefaultPort; }
int sinkPort(const Options& o) { return basePort(o) + 1 + o.nodes(); }

void checkPayload(std::size_t n) {
    if (n > kMaxPayload)
        throw std::runtime_error("a payload of " + std::to_string(n) +
                                 " bytes does not fit into one UDP datagram (at most " +
                                 std::to_string(kMaxPayload) + " bytes: 65507 minus the " +
                                 std::to_string(kHeader) + "-byte sequence number)");
}

void putSeq(std::byte* out, std::uint64_t seq) {
    for (std::size_t i = 0; i < kHeader; ++i)
        out[i] = static_cast<std::byte>((seq >> (8 * i)) & 0xFF);
}
std::uint64_t getSeq(const std::byte* in) {
    std::uint64_t seq = 0;
    for (std::size_t i = 0; i < kHeader; ++i) seq |= static_cast<std::uint64_t>(in[i]) << (8 * i);
    return seq;
}

class Socket {
  public:
    Socket() : fd_(::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0)) {
        if (fd_ < 0) failErrno("socket");
        // Several 32 KiB datagrams in flight (chain streams) fit without loss.
        int size = 4 << 20;
        ::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &size, sizeof size);
        ::setsockopt(fd_, SOL_SOCKET, SO_SNDBUF, &size, sizeof size);
        timeval tv{0, static_cast<suseconds_t>(kPoll.count() * 1000)};
        ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    }
    Socket(const Socket&) = delete;
    Socket& operator=(const Socket&) = delete;
    ~Socket() { ::close(fd_); }
    int fd() const { return fd_; }

    void bind(const std::string& host, int port) {
        sockaddr_in a = ipv4Address(host, port);
        if (::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0)
            failErrno("bind " + host + ":" + std::to_string(port));
    }

  private:
    int fd_;
};

// Sends header + body as one datagram (to the connected peer when `to` is null).
void sendDatagram(int fd, const sockaddr_in* to, const std::byte* header,
                  std::span<const std::byte> body) {
    iovec v[2] = {{const_cast<std::byte*>(header), kHeader},
                  {const_cast<std::byte*>(body.data()), body.size()}};
    msghdr m{};
    m.msg_name = const_cast<sockaddr_in*>(to);
    m.msg_namelen = to ? sizeof *to : 0;
    m.msg_iov = v;
    m.msg_iovlen = 2;
    for (;;) {
        if (::sendmsg(fd, &m, MSG_NOSIGNAL) >= 0) return;
        // A refused earlier datagram is reported on the next call: not this one's failure.
        if (errno == EINTR || errno == ECONNREFUSED) continue;
        failErrno("send");
    }
}

// Receives one datagram into buf; its size, or -1 when the receive timed out (kPoll).
ssize_t receive(int fd, std::byte* buf, std::size_t size, sockaddr_in* from = nullptr) {
    socklen_t len = sizeof(sockaddr_in);
    const ssize_t r =
        ::recvfrom(fd, buf, size, 0, reinterpret_cast<sockaddr*>(from), from ? &len : nullptr);
    if (r >= 0) return r;
    if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR || errno == ECONNREFUSED)
        return -1;
    failErrno("receive");
}

class UdpClient final : public driver::Client {
  public:
    explicit UdpClient(const Options& o)
        : timeout_(o.timeoutMs),
          retransmit_(std::stoi(o.setting("retransmit-ms", "200"))),
          ack_(o.mode != driver::Mode::Echo),
          peer_(o.host + ":" + std::to_string(basePort(o))),
          spare_(kMaxDatagram) {
        if (retransmit_.count() < 1) throw std::invalid_argument("retransmit-ms must be >= 1");
        sockaddr_in a = ipv4Address(o.host, basePort(o));
        // Connected: only the server's datagrams arrive, and a port without a server is
        // reported (ECONNREFUSED from the ICMP answer).
        if (::connect(socket_.fd(), reinterpret_cast<sockaddr*>(&a), sizeof a) != 0)
            failErrno("connect " + peer_);
    }

    ~UdpClient() override {
        std::cerr << "pnp-mw-udp: " << retransmissions_ << " retransmissions, " << discarded_
                  << " late or foreign datagrams discarded" << std::endl;
    }

    void request(std::span<const std::byte> payload, Bytes& reply) override {
        checkPayload(payload.size());
        const std::uint64_t seq = ++seq_;
        std::byte header[kHeader];
        putSeq(header, seq);
        const auto start = Clock::now();
        const auto deadline = start + timeout_;
        auto resend = start + retransmit_;
        sendDatagram(socket_.fd(), nullptr, header, payload);
        // The answer is received straight into `reply`, sized for what is expected (no copy;
        // no zero-fill while the size stays the same); a larger one spills into spare_.
        reply.resize(ack_ ? 1 : payload.size());
        bool refused = false;
        for (;;) {
            std::byte got[kHeader];
            iovec v[3] = {
                {got, kHeader}, {reply.data(), reply.size()}, {spare_.data(), spare_.size()}};
            msghdr m{};
            m.msg_iov = v;
            m.msg_iovlen = 3;
            const ssize_t r = ::recvmsg(socket_.fd(), &m, 0);
            if (r < 0 && errno == ECONNREFUSED) refused = true;
            if (r < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR &&
                errno != ECONNREFUSED)
                failErrno("receive");
            if (r >= static_cast<ssize_t>(kHeader) && getSeq(got) == seq) {
                const auto n = static_cast<std::size_t>(r) - kHeader;
                if (n > reply.size()) {
                    const std::size_t had = reply.size();
                    reply.insert(reply.end(), spare_.begin(),
                                 spare_.begin() + static_cast<std::ptrdiff_t>(n - had));
                } else {
                    reply.resize(n);
                }
                return;
            }
            if (r >= 0) ++discarded_;
            const auto now = Clock::now();
            if (now >= deadline)
                throw std::runtime_error(
                    "no answer from " + peer_ + " within " + std::to_string(timeout_.count()) +
                    " ms (" + std::to_string(retransmissions_) + " retransmissions so far" +
                    (refused ? "; connection refused: nothing listens on that port)" : ")"));
            if (now >= resend) {
                sendDatagram(socket_.fd(), nullptr, header, payload);
                ++retransmissions_;
                resend = now + retransmit_;
            }
        }
    }

  private:
    std::chrono::milliseconds timeout_;
    std::chrono::milliseconds retransmit_;
    bool ack_;
    std::string peer_;
    Socket socket_;
    Bytes spare_;
    std::uint64_t seq_ = 0;
    std::uint64_t retransmissions_ = 0;
    std::uint64_t discarded_ = 0;
};

void runServer(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    Socket s;
    s.bind(o.host, basePort(o));
    const bool echo = o.mode == driver::Mode::Echo;
    const std::byte ack[1] = {std::byte{1}};
    Bytes buf(kMaxDatagram + 1);
    ctx.ready();
    while (!ctx.stop.stop_requested()) {
        sockaddr_in from{};
        const ssize_t r = receive(s.fd(), buf.data(), buf.size(), &from);
        if (r < static_cast<ssize_t>(kHeader)) continue;  // timeout, or not our client's
        if (echo)
            sendDatagram(s.fd(), &from, buf.data(),
                         std::span(buf.data() + kHeader, static_cast<std::size_t>(r) - kHeader));
        else
            sendDatagram(s.fd(), &from, buf.data(), ack);
    }
}

// Chain node i: forwards every datagram as it came to node i + 1, or, as the last node of
// its stream, to the client's sink. No retransmission: a lost datagram fails the chain run.
void runChainNodes(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    const std::string sinkHost = o.setting("sink-host", "127.0.0.1");
    std::vector<std::unique_ptr<Socket>> sockets;
    for (int i = o.first; i < o.first + o.count; ++i) {
        sockets.push_back(std::make_unique<Socket>());
        sockets.back()->bind(o.host, basePort(o) + 1 + i);
    }
    ctx.ready();
    std::vector<std::jthread> nodes;
    for (int k = 0; k < o.count; ++k) {
        const int i = o.first + k;
        nodes.emplace_back([&, i, fd = sockets[static_cast<std::size_t>(k)]->fd()] {
            const sockaddr_in next = (i + 1) % o.hops == 0 ? ipv4Address(sinkHost, sinkPort(o))
                                                           : ipv4Address(o.host, basePort(o) + 2 + i);
            Bytes buf(kMaxDatagram + 1);
            while (!ctx.stop.stop_requested()) {
                const ssize_t r = receive(fd, buf.data(), buf.size());
                if (r < static_cast<ssize_t>(kHeader)) continue;
                sendDatagram(
                    fd, &next, buf.data(),
                    std::span(buf.data() + kHeader, static_cast<std::size_t>(r) - kHeader));
            }
        });
    }
    // jthreads join here; their loops end on stop (checked every kPoll).
}

class UdpChainClient final : public driver::ChainClient {
  public:
    explicit UdpChainClient(const Options& o) : options_(o), buf_(kMaxDatagram + 1) {
        sink_.bind(o.local, sinkPort(o));
    }

    void send(int node, std::span<const std::byte> message) override {
        checkPayload(message.size());
        std::byte header[kHeader];
        putSeq(header, ++seq_);
        const sockaddr_in to = ipv4Address(options_.host, basePort(options_) + 1 + node);
        sendDatagram(out_.fd(), &to, header, message);
    }

    bool receive(Bytes& message, Clock::time_point deadline) override {
        while (Clock::now() < deadline) {
            const ssize_t r = udp::receive(sink_.fd(), buf_.data(), buf_.size());
            if (r < static_cast<ssize_t>(kHeader)) continue;
            message.assign(buf_.begin() + kHeader, buf_.begin() + r);
            return true;
        }
        return false;
    }

  private:
    const Options& options_;
    Socket sink_;
    Socket out_;
    Bytes buf_;
    std::uint64_t seq_ = 0;
};

}  // namespace
}  // namespace pnp::bench::udp

int main(int argc, char** argv) {
    using namespace pnp::bench;
    driver::Adapter a;
    a.name = "udp";
    a.variants = {"udp"};
    a.description =
        "raw UDP, one datagram per request with an 8-byte sequence number, retransmission "
        "(the floor)";
    a.makeClient = [](const driver::Options& o) { return std::make_unique<udp::UdpClient>(o); };
    a.runServer = udp::runServer;
    a.runChainNodes = udp::runChainNodes;
    a.makeChainClient = [](const driver::Options& o) {
        return std::make_unique<udp::UdpChainClient>(o);
    };
    return driver::adapterMain(argc, argv, a);
}
