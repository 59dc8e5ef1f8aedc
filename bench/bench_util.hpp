// Small helpers shared by the benchmark executables (bench/ only; not a library of the stack).
#pragma once

#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <pthread.h>
#include <sched.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace pnp::bench {

using Clock = std::chrono::steady_clock;  // CLOCK_MONOTONIC: comparable across processes

inline std::int64_t nowNs() {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch())
        .count();
}

[[noreturn]] inline void fail(const std::string& what) {
    throw std::runtime_error(what + (errno ? std::string(": ") + std::strerror(errno) : ""));
}

// Pins the calling thread (and what it forks afterwards) to one CPU; -1: leave as is.
inline void pinToCpu(int cpu) {
    if (cpu < 0) return;
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    if (sched_setaffinity(0, sizeof set, &set) != 0)
        fail("sched_setaffinity(" + std::to_string(cpu) + ")");
}

// The CPUs the calling thread may run on, as "0" or "0,1".
inline std::string affinityText() {
    cpu_set_t set;
    CPU_ZERO(&set);
    if (sched_getaffinity(0, sizeof set, &set) != 0) return "?";
    std::string s;
    for (int i = 0; i < CPU_SETSIZE; ++i)
        if (CPU_ISSET(i, &set)) s += (s.empty() ? "" : ",") + std::to_string(i);
    return s;
}

// A listening/connected IPv4 loopback socket with TCP_NODELAY.
inline void setNoDelay(int fd) {
    int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
}

inline int connectLoopback(std::uint16_t port) {
    int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) fail("socket");
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
        int e = errno;
        ::close(fd);
        errno = e;
        return -1;
    }
    setNoDelay(fd);
    return fd;
}

// Blocking send of all bytes. False when the peer is gone.
inline bool sendAll(int fd, const void* data, std::size_t n) {
    const char* p = static_cast<const char*>(data);
    while (n > 0) {
        ssize_t w = ::send(fd, p, n, MSG_NOSIGNAL);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) return false;
        p += w;
        n -= static_cast<std::size_t>(w);
    }
    return true;
}

// Raw echo framing: a 4-byte little-endian payload length, then the payload. Reads one
// whole frame into buf (resized as needed; as few recv calls as the kernel allows: every
// recv asks for everything still missing). Returns the payload length, -1 at EOF/error.
inline long recvFrame(int fd, std::vector<unsigned char>& buf, std::size_t maxPayload) {
    std::size_t have = 0, need = 4;
    if (buf.size() < 4 + maxPayload) buf.resize(4 + maxPayload);
    for (;;) {
        while (have < need) {
            ssize_t r = ::recv(fd, buf.data() + have, buf.size() - have, 0);
            if (r < 0 && errno == EINTR) continue;
            if (r <= 0) return -1;
            have += static_cast<std::size_t>(r);
        }
        if (need == 4) {
            std::uint32_t len = 0;
            std::memcpy(&len, buf.data(), 4);  // little-endian hosts only (x86, arm64)
            if (len > maxPayload) return -1;
            need = 4 + len;
            if (have >= need) return static_cast<long>(len);
            continue;
        }
        return static_cast<long>(need - 4);
    }
}

// Keeps CPUs from going idle while it lives: one thread per CPU spins under SCHED_IDLE, so it
// runs only when nothing else wants that CPU and yields it at once to any other thread. An
// idle vCPU is halted by the hypervisor, and waking it costs tens of µs before any code of
// ours or of the kernel's TCP runs (bench/README.md (e)); a controller core run with
// `idle=poll` or with its C-states disabled is in the state this produces.
class BusyCores {
  public:
    explicit BusyCores(std::vector<int> cpus) {
        for (int cpu : cpus)
            threads_.emplace_back([this, cpu] {
                cpu_set_t set;
                CPU_ZERO(&set);
                CPU_SET(cpu, &set);
                pthread_setaffinity_np(pthread_self(), sizeof set, &set);
                sched_param p{};
                pthread_setschedparam(pthread_self(), SCHED_IDLE, &p);
                // No pause instruction: a hypervisor may take a pause loop as a spinning lock
                // and deschedule the vCPU, which is what this is to prevent.
                while (!stop_.load(std::memory_order_relaxed)) {
                }
            });
    }
    ~BusyCores() {
        stop_ = true;
        for (auto& t : threads_) t.join();
    }
    BusyCores(const BusyCores&) = delete;
    BusyCores& operator=(const BusyCores&) = delete;

  private:
    std::atomic<bool> stop_{false};
    std::vector<std::thread> threads_;
};

// Median and nearest-rank percentiles of a sample (sorted in place).
struct Summary {
    std::size_t n = 0;
    double median = 0, p99 = 0, min = 0, max = 0, mean = 0;
};

inline Summary summarize(std::vector<double>& v) {
    Summary s;
    if (v.empty()) return s;
    std::sort(v.begin(), v.end());
    s.n = v.size();
    s.median = v.size() % 2 ? v[v.size() / 2] : (v[v.size() / 2 - 1] + v[v.size() / 2]) / 2;
    auto rank = [&](double q) {
        std::size_t k = static_cast<std::size_t>(q * static_cast<double>(v.size()) + 0.999999);
        return v[std::min(v.size(), std::max<std::size_t>(k, 1)) - 1];
    };
    s.p99 = rank(0.99);
    s.min = v.front();
    s.max = v.back();
    double sum = 0;
    for (double x : v) sum += x;
    s.mean = sum / static_cast<double>(v.size());
    return s;
}

}  // namespace pnp::bench
