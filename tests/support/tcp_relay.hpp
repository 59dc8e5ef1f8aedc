// A TCP relay for tests: 127.0.0.1:port() -> 127.0.0.1:target, whose connections can be cut
// (cut()) so that a client loses its channel while the server keeps its session.
#pragma once

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <atomic>
#include <cstdint>
#include <thread>
#include <utility>
#include <vector>

namespace pnp::testing {

// A TCP relay 127.0.0.1:port() -> 127.0.0.1:target whose connections can be cut, so that
// the client loses its channel while the server keeps the session.
class TcpRelay {
  public:
    explicit TcpRelay(std::uint16_t target) : target_(target) {
        listen_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        int one = 1;
        ::setsockopt(listen_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        ::bind(listen_, reinterpret_cast<sockaddr*>(&a), sizeof a);
        ::listen(listen_, 8);
        socklen_t len = sizeof a;
        ::getsockname(listen_, reinterpret_cast<sockaddr*>(&a), &len);
        port_ = ntohs(a.sin_port);
        thread_ = std::thread([this] { run(); });
    }
    ~TcpRelay() {
        stop_ = true;
        thread_.join();
        closeAll();
        ::close(listen_);
    }
    std::uint16_t port() const { return port_; }
    void cut() { cut_ = true; }
    // While blocked, connections are cut and new ones closed at once (the server looks
    // unreachable, long enough for a session to time out).
    void block(bool on) {
        blocked_ = on;
        if (on) cut_ = true;
    }

  private:
    void closeAll() {
        for (auto& [a, b] : pairs_) {
            ::close(a);
            ::close(b);
        }
        pairs_.clear();
    }
    void run() {
        while (!stop_) {
            if (cut_.exchange(false)) closeAll();
            std::vector<pollfd> fds{{listen_, POLLIN, 0}};
            for (auto& [a, b] : pairs_) {
                fds.push_back({a, POLLIN, 0});
                fds.push_back({b, POLLIN, 0});
            }
            if (::poll(fds.data(), fds.size(), 20) <= 0) continue;
            const std::size_t polled = pairs_.size();  // a pair accepted below is not in fds
            if (fds[0].revents & POLLIN) {
                int c = ::accept4(listen_, nullptr, nullptr, SOCK_CLOEXEC);
                int s = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
                sockaddr_in a{};
                a.sin_family = AF_INET;
                a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
                a.sin_port = htons(target_);
                // A peer that stops reading must not stall the relay (and the test) forever.
                timeval sendTimeout{1, 0};
                for (int fd : {c, s})
                    if (fd >= 0)
                        ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &sendTimeout, sizeof sendTimeout);
                if (c >= 0 && !blocked_ &&
                    ::connect(s, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0) {
                    pairs_.emplace_back(c, s);
                } else {
                    if (c >= 0) ::close(c);
                    ::close(s);
                }
            }
            for (std::size_t i = 0; i < polled; ++i) {
                bool dead = false;
                for (int side = 0; side < 2 && !dead; ++side) {
                    const pollfd& p = fds[1 + 2 * i + side];
                    if (!(p.revents & (POLLIN | POLLHUP | POLLERR))) continue;
                    int from = side == 0 ? pairs_[i].first : pairs_[i].second;
                    int to = side == 0 ? pairs_[i].second : pairs_[i].first;
                    char buf[65536];
                    ssize_t n = ::read(from, buf, sizeof buf);
                    if (n <= 0 || ::send(to, buf, static_cast<std::size_t>(n), MSG_NOSIGNAL) != n)
                        dead = true;
                }
                if (dead) {
                    ::close(pairs_[i].first);
                    ::close(pairs_[i].second);
                    pairs_.erase(pairs_.begin() + static_cast<std::ptrdiff_t>(i));
                    break;  // the poll set no longer matches
                }
            }
        }
    }

    std::uint16_t target_;
    std::uint16_t port_ = 0;
    int listen_ = -1;
    std::atomic<bool> stop_{false};
    std::atomic<bool> cut_{false};
    std::atomic<bool> blocked_{false};
    std::vector<std::pair<int, int>> pairs_;
    std::thread thread_;
};

}  // namespace pnp::testing
