// pnp_bench_echo_server: the raw TCP baseline of the benchmark. A minimal blocking-socket
// echo server: every frame (4-byte little-endian length + payload) is read completely and
// sent back unchanged with one send() call. TCP_NODELAY on every accepted socket, one thread
// per connection, no event loop: the cheapest honest request/response over TCP.
//
// A frame whose payload is "TICK" + u32 period ms + u32 count (little-endian) is not echoed:
// the thread sleeps `period` ms, then sends an 8-byte frame with CLOCK_MONOTONIC in ns taken
// just before the send, `count` times — the raw analog of a value changed in a server every
// `period` ms and reported to an idle client (benchmark section (e)).
//
//   pnp_bench_echo_server [--port N] [--max-payload BYTES]
//
// Prints "listening on 127.0.0.1:PORT" (flushed) once accepting; stops on SIGTERM/SIGINT
// (default action).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.hpp"

using namespace pnp::bench;

namespace {

bool sendTicks(int fd, const unsigned char* request) {
    std::uint32_t periodMs = 0, count = 0;
    std::memcpy(&periodMs, request + 4, 4);
    std::memcpy(&count, request + 8, 4);
    periodMs = std::min<std::uint32_t>(periodMs, 10'000);
    count = std::min<std::uint32_t>(count, 100'000);
    unsigned char frame[12] = {8, 0, 0, 0};
    for (std::uint32_t i = 0; i < count; ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(periodMs));
        const std::int64_t t = nowNs();
        std::memcpy(frame + 4, &t, 8);
        if (!sendAll(fd, frame, sizeof frame)) return false;
    }
    return true;
}

void serveConnection(int fd, std::size_t maxPayload) {
    std::vector<unsigned char> buf;
    for (;;) {
        long n = recvFrame(fd, buf, maxPayload);
        if (n < 0) break;
        if (n == 12 && std::memcmp(buf.data() + 4, "TICK", 4) == 0) {
            if (!sendTicks(fd, buf.data() + 4)) break;
            continue;
        }
        if (!sendAll(fd, buf.data(), 4 + static_cast<std::size_t>(n))) break;
    }
    ::close(fd);
}

}  // namespace

int main(int argc, char** argv) {
    try {
        std::uint16_t port = 0;
        std::size_t maxPayload = 16 * 1024 * 1024;
        for (int i = 1; i < argc; ++i) {
            std::string a = argv[i];
            if (a == "--port" && i + 1 < argc)
                port = static_cast<std::uint16_t>(std::stoi(argv[++i]));
            else if (a == "--max-payload" && i + 1 < argc)
                maxPayload = std::stoul(argv[++i]);
            else {
                std::fprintf(stderr, "usage: %s [--port N] [--max-payload BYTES]\n", argv[0]);
                return 2;
            }
        }
        int ls = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (ls < 0) fail("socket");
        int one = 1;
        ::setsockopt(ls, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(port);
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        if (::bind(ls, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) fail("bind");
        if (::listen(ls, 64) != 0) fail("listen");
        socklen_t len = sizeof a;
        ::getsockname(ls, reinterpret_cast<sockaddr*>(&a), &len);
        std::printf("listening on 127.0.0.1:%u\n", static_cast<unsigned>(ntohs(a.sin_port)));
        std::fflush(stdout);
        for (;;) {
            int fd = ::accept4(ls, nullptr, nullptr, SOCK_CLOEXEC);
            if (fd < 0) {
                if (errno == EINTR || errno == ECONNABORTED) continue;
                fail("accept");
            }
            setNoDelay(fd);
            std::thread(serveConnection, fd, maxPayload).detach();
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "pnp_bench_echo_server: %s\n", e.what());
        return 1;
    }
}
