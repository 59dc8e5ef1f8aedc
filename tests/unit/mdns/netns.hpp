// Private network namespaces joined by veth pairs, for mDNS tests over real sockets.
// Needs root (ip netns); tests call skipReason() and GTEST_SKIP() when it is not "".
// Every namespace is deleted by its RAII owner (also when a test fails), which deletes the
// veth ends inside it as well; names contain the PID, so parallel runs do not collide.
// Every external command runs under `timeout`.
#pragma once

#include <arpa/inet.h>
#include <fcntl.h>
#include <net/if.h>
#include <netinet/in.h>
#include <poll.h>
#include <sched.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace pnp::mdns::test {

inline bool sh(const std::string& cmd) {
    return std::system(("timeout 10 " + cmd + " >/dev/null 2>&1").c_str()) == 0;
}

constexpr const char* kNetnsPrefix = "pnpmdns-";

// Namespaces of earlier runs that crashed (no destructor ran): "pnpmdns-<pid>-<n>" whose
// process no longer exists. Once per process.
inline void removeStaleNamespaces() {
    static bool done = false;
    if (done) return;
    done = true;
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator("/var/run/netns", ec)) {
        std::string name = e.path().filename().string();
        if (!name.starts_with(kNetnsPrefix)) continue;
        pid_t pid = static_cast<pid_t>(std::atol(name.c_str() + std::strlen(kNetnsPrefix)));
        if (pid > 0 && ::kill(pid, 0) != 0 && errno == ESRCH) sh("ip netns del " + name);
    }
}

// "" when namespaces can be used, else why not.
inline std::string skipReason() {
    if (::geteuid() != 0) return "needs root to create network namespaces (ip netns)";
    if (!sh("ip -V")) return "the ip command (iproute2) is missing";
    removeStaleNamespaces();
    return "";
}

class Netns {
  public:
    Netns() {
        static std::atomic<int> counter{0};
        name_ = kNetnsPrefix + std::to_string(::getpid()) + "-" + std::to_string(counter++);
        if (!sh("ip netns add " + name_)) throw std::runtime_error("ip netns add " + name_);
        sh("ip -n " + name_ + " link set lo up");
    }
    ~Netns() { sh("ip netns del " + name_); }
    Netns(const Netns&) = delete;
    Netns& operator=(const Netns&) = delete;
    const std::string& name() const { return name_; }

  private:
    std::string name_;
};

// Waits (at most 3 s) until the link has carrier: packets sent before that are lost.
inline bool waitLowerUp(const Netns& ns, const std::string& ifName) {
    auto end = std::chrono::steady_clock::now() + std::chrono::seconds(3);
    while (std::chrono::steady_clock::now() < end) {
        if (sh("ip -n " + ns.name() + " link show dev " + ifName + " | grep -q LOWER_UP")) {
            return true;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
}

// A veth pair with one end in each namespace, addresses a/24 and b/24, both up (with
// carrier).
inline void link(const Netns& nsA, const std::string& ifA, const std::string& addrA,
                 const Netns& nsB, const std::string& ifB, const std::string& addrB) {
    bool ok = sh("ip link add " + ifA + " netns " + nsA.name() + " type veth peer name " + ifB +
                 " netns " + nsB.name()) &&
              sh("ip -n " + nsA.name() + " addr add " + addrA + "/24 dev " + ifA) &&
              sh("ip -n " + nsB.name() + " addr add " + addrB + "/24 dev " + ifB) &&
              sh("ip -n " + nsA.name() + " link set " + ifA + " up") &&
              sh("ip -n " + nsB.name() + " link set " + ifB + " up") && waitLowerUp(nsA, ifA) &&
              waitLowerUp(nsB, ifB);
    if (!ok) throw std::runtime_error("cannot create veth " + ifA + "/" + ifB);
}

// Runs f on a thread that has joined the namespace: sockets and threads created there
// (an Mdns started there) stay in it.
template <class F>
void inNetns(const Netns& ns, F&& f) {
    std::exception_ptr error;
    std::thread t([&] {
        try {
            int fd = ::open(("/var/run/netns/" + ns.name()).c_str(), O_RDONLY | O_CLOEXEC);
            if (fd < 0) throw std::runtime_error("open netns " + ns.name());
            int r = ::setns(fd, CLONE_NEWNET);
            ::close(fd);
            if (r != 0) throw std::runtime_error("setns " + ns.name());
            f();
        } catch (...) {
            error = std::current_exception();
        }
    });
    t.join();
    if (error) std::rethrow_exception(error);
}

// A plain UDP socket for playing a foreign mDNS host or a legacy resolver. Create it
// inside inNetns().
class UdpPeer {
  public:
    // port 0: ephemeral. ifName non-empty: send multicast through it and (join) join the
    // group on it; a peer that has not joined receives unicast only.
    UdpPeer(std::uint16_t port, const std::string& ifName, const std::string& group,
            bool join = true) {
        fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
        if (fd_ < 0) throw std::runtime_error("socket");
        int one = 1;
        ::setsockopt(fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        ::setsockopt(fd_, SOL_SOCKET, SO_REUSEPORT, &one, sizeof one);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(port);
        if (::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
            throw std::runtime_error("bind");
        }
        ::inet_pton(AF_INET, group.c_str(), &group_);
        if (!ifName.empty()) {
            ip_mreqn m{};
            m.imr_multiaddr = group_;
            m.imr_ifindex = static_cast<int>(::if_nametoindex(ifName.c_str()));
            if (join) ::setsockopt(fd_, IPPROTO_IP, IP_ADD_MEMBERSHIP, &m, sizeof m);
            ::setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_IF, &m, sizeof m);
        }
    }
    ~UdpPeer() {
        if (fd_ >= 0) ::close(fd_);
    }
    UdpPeer(const UdpPeer&) = delete;
    UdpPeer& operator=(const UdpPeer&) = delete;

    void sendToGroup(const std::vector<std::uint8_t>& b, std::uint16_t port) const {
        sockaddr_in d{};
        d.sin_family = AF_INET;
        d.sin_port = htons(port);
        d.sin_addr = group_;
        ::sendto(fd_, b.data(), b.size(), 0, reinterpret_cast<sockaddr*>(&d), sizeof d);
    }

    struct Packet {
        std::vector<std::uint8_t> bytes;
        sockaddr_in from{};
    };
    std::optional<Packet> receive(std::chrono::milliseconds timeout) const {
        pollfd p{fd_, POLLIN, 0};
        if (::poll(&p, 1, static_cast<int>(timeout.count())) <= 0) return std::nullopt;
        Packet pk;
        pk.bytes.resize(9000);
        socklen_t len = sizeof pk.from;
        ssize_t n = ::recvfrom(fd_, pk.bytes.data(), pk.bytes.size(), 0,
                               reinterpret_cast<sockaddr*>(&pk.from), &len);
        if (n < 0) return std::nullopt;
        pk.bytes.resize(static_cast<std::size_t>(n));
        return pk;
    }

  private:
    int fd_ = -1;
    in_addr group_{};
};

}  // namespace pnp::mdns::test
