// A child process for tests: fork/exec, stdout through a pipe (to wait for a line such as
// "READY" with a bounded timeout), stderr into a log file, stopped by its PID (SIGTERM, then
// SIGKILL) in the destructor even when the test failed. The child also gets SIGTERM if the
// test process dies (PR_SET_PDEATHSIG).
#pragma once

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace pnp::testing {

// A TCP port on 127.0.0.1 that was free a moment ago.
inline unsigned short freeLoopbackPort() {
    int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
    socklen_t len = sizeof a;
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    ::close(fd);
    return ntohs(a.sin_port);
}

// The first of `count` consecutive TCP ports on 127.0.0.1 that were all free a moment ago,
// below the kernel's ephemeral range (32768..), where other tests' client sockets take theirs.
inline unsigned short freeLoopbackPortRange(int count) {
    static unsigned seed = static_cast<unsigned>(::getpid()) * 2654435761u;
    for (int attempt = 0; attempt < 200; ++attempt) {
        seed = seed * 1103515245u + 12345u;
        const int base = 20000 + static_cast<int>((seed >> 8) % 12000u);
        bool free = true;
        for (int i = 0; i < count && free; ++i) {
            int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
            sockaddr_in a{};
            a.sin_family = AF_INET;
            a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
            a.sin_port = htons(static_cast<unsigned short>(base + i));
            free = ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
            ::close(fd);
        }
        if (free) return static_cast<unsigned short>(base);
    }
    return freeLoopbackPort();
}

// The full path of an executable found in PATH, or "".
inline std::string findInPath(const std::string& name) {
    const char* path = std::getenv("PATH");
    if (!path) return {};
    std::stringstream ss(path);
    std::string dir;
    while (std::getline(ss, dir, ':')) {
        if (dir.empty()) continue;
        std::string p = dir + "/" + name;
        if (::access(p.c_str(), X_OK) == 0) return p;
    }
    return {};
}

inline bool fileExists(const std::string& p) {
    struct stat st {};
    return ::stat(p.c_str(), &st) == 0;
}

class ChildProcess {
  public:
    ChildProcess() = default;
    ChildProcess(const ChildProcess&) = delete;
    ChildProcess& operator=(const ChildProcess&) = delete;
    ~ChildProcess() { stop(); }

    // Starts argv[0] (a full path) with argv; stderr goes to logPath. With netns, the child
    // enters that network namespace (/var/run/netns/NAME, as `ip netns exec` would, but
    // without its extra exec and mount namespace) before it executes argv.
    bool start(const std::vector<std::string>& argv, const std::string& logPath, std::string& error,
               const std::string& netns = {}) {
        // Everything the child needs is prepared here: between fork and exec it may only make
        // async-signal-safe calls (another thread of the test may hold the malloc lock).
        std::vector<char*> args;
        for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
        args.push_back(nullptr);
        const std::string nsPath = netns.empty() ? std::string() : "/var/run/netns/" + netns;
        int fds[2];
        if (::pipe2(fds, O_CLOEXEC) != 0) {
            error = "pipe failed";
            return false;
        }
        logPath_ = logPath;
        pid_t parent = ::getpid();
        pid_ = ::fork();
        if (pid_ < 0) {
            error = "fork failed";
            ::close(fds[0]);
            ::close(fds[1]);
            return false;
        }
        if (pid_ == 0) {
            // Child: only async-signal-safe calls until exec.
            ::prctl(PR_SET_PDEATHSIG, SIGTERM);
            if (::getppid() != parent) ::_exit(127);
            if (!nsPath.empty()) {
                int ns = ::open(nsPath.c_str(), O_RDONLY | O_CLOEXEC);
                if (ns < 0 || ::setns(ns, CLONE_NEWNET) != 0) ::_exit(126);
            }
            ::dup2(fds[1], STDOUT_FILENO);
            int log = ::open(logPath.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
            if (log >= 0) ::dup2(log, STDERR_FILENO);
            int devnull = ::open("/dev/null", O_RDONLY);
            if (devnull >= 0) ::dup2(devnull, STDIN_FILENO);
            ::execv(args[0], args.data());
            ::_exit(127);
        }
        ::close(fds[1]);
        out_ = fds[0];
        return true;
    }

    // Reads stdout until a line equal to `line` arrives, the child exits or the timeout.
    bool waitForLine(const std::string& line, std::chrono::milliseconds timeout,
                     std::string& error) {
        return waitForLineWith(line, false, timeout, error, nullptr);
    }
    // The same for a line starting with `prefix`; the whole line goes to *found.
    bool waitForPrefix(const std::string& prefix, std::chrono::milliseconds timeout,
                       std::string& error, std::string* found = nullptr) {
        return waitForLineWith(prefix, true, timeout, error, found);
    }

    // SIGKILL (a crash: no goodbye, no unregistration) and reap.
    void kill9() {
        if (pid_ <= 0) return;
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, nullptr, 0);
        pid_ = -1;
    }

  private:
    bool waitForLineWith(const std::string& line, bool prefix, std::chrono::milliseconds timeout,
                         std::string& error, std::string* found) {
        auto end = std::chrono::steady_clock::now() + timeout;
        std::string buf;
        for (;;) {
            std::size_t nl;
            while ((nl = buf.find('\n')) != std::string::npos) {
                std::string l = buf.substr(0, nl);
                buf.erase(0, nl + 1);
                if (!l.empty() && l.back() == '\r') l.pop_back();
                if (prefix ? l.rfind(line, 0) == 0 : l == line) {
                    if (found) *found = l;
                    return true;
                }
            }
            auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                end - std::chrono::steady_clock::now());
            if (left.count() <= 0) {
                error = "no \"" + line + "\" within " + std::to_string(timeout.count()) + " ms";
                return false;
            }
            pollfd p{out_, POLLIN, 0};
            int n = ::poll(&p, 1, static_cast<int>(left.count()));
            if (n < 0) continue;
            if (n == 0) continue;
            char tmp[512];
            ssize_t r = ::read(out_, tmp, sizeof tmp);
            if (r <= 0) {
                error = "the process exited before printing \"" + line + "\"";
                return false;
            }
            buf.append(tmp, static_cast<std::size_t>(r));
        }
    }

  public:
    // SIGTERM, up to `grace` to exit, then SIGKILL. Idempotent.
    void stop(std::chrono::milliseconds grace = std::chrono::milliseconds(5000)) {
        if (pid_ > 0) {
            ::kill(pid_, SIGTERM);
            auto end = std::chrono::steady_clock::now() + grace;
            int status = 0;
            bool reaped = false;
            while (std::chrono::steady_clock::now() < end) {
                pid_t r = ::waitpid(pid_, &status, WNOHANG);
                if (r == pid_ || r < 0) {
                    reaped = true;
                    break;
                }
                std::this_thread::sleep_for(std::chrono::milliseconds(20));
            }
            if (!reaped) {
                ::kill(pid_, SIGKILL);
                ::waitpid(pid_, &status, 0);
            }
            pid_ = -1;
        }
        if (out_ >= 0) {
            ::close(out_);
            out_ = -1;
        }
    }

    // Waits up to `timeout` for the child to exit by itself and reaps it: its exit code
    // (128 + N when killed by signal N), or nullopt if it still runs.
    std::optional<int> waitExit(std::chrono::milliseconds timeout) {
        const auto end = std::chrono::steady_clock::now() + timeout;
        while (pid_ > 0) {
            int status = 0;
            const pid_t r = ::waitpid(pid_, &status, WNOHANG);
            if (r == pid_) {
                pid_ = -1;
                return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
            }
            if (r < 0 || std::chrono::steady_clock::now() >= end) break;
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
        return std::nullopt;
    }

    // Reads the rest of stdout (until the child closes it or `timeout`).
    std::string readAll(std::chrono::milliseconds timeout) {
        std::string all;
        const auto end = std::chrono::steady_clock::now() + timeout;
        while (out_ >= 0) {
            const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                end - std::chrono::steady_clock::now());
            if (left.count() <= 0) break;
            pollfd p{out_, POLLIN, 0};
            if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
            char tmp[4096];
            const ssize_t r = ::read(out_, tmp, sizeof tmp);
            if (r <= 0) break;
            all.append(tmp, static_cast<std::size_t>(r));
        }
        return all;
    }

    pid_t pid() const { return pid_; }
    bool running() const { return pid_ > 0 && ::waitpid(pid_, nullptr, WNOHANG) == 0; }

    // The last `max` bytes of the stderr log.
    std::string logTail(std::size_t max = 4000) const {
        std::ifstream f(logPath_);
        std::string s((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
        return s.size() > max ? s.substr(s.size() - max) : s;
    }

  private:
    pid_t pid_ = -1;
    int out_ = -1;
    std::string logPath_;
};

}  // namespace pnp::testing
