#include "bench/runner/netns.hpp"

#include <arpa/inet.h>
#include <dirent.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sched.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdlib>
#include <stdexcept>
#include <thread>

#include "bench/runner/process.hpp"

namespace pnp::bench::runner {

NetPair::NetPair(NetPairConfig config) : config_(std::move(config)) {
    if (config_.name.empty() || config_.name.size() > 13)
        throw std::runtime_error("netns name must be 1..13 characters: " + config_.name);
    if (config_.log.empty()) config_.log = "/dev/null";
    clientNs_ = config_.name + "c";
    serverNs_ = config_.name + "s";
    created_ = true;
    try {
        ip({"netns", "add", clientNs_});
        ip({"netns", "add", serverNs_});
        ip({"link", "add", clientNs_, "type", "veth", "peer", "name", serverNs_});
        ip({"link", "set", clientNs_, "netns", clientNs_});
        ip({"link", "set", serverNs_, "netns", serverNs_});
        ip({"-n", clientNs_, "addr", "add", std::string(kClientAddr) + "/24", "dev", clientNs_});
        ip({"-n", serverNs_, "addr", "add", std::string(kServerAddr) + "/24", "dev", serverNs_});
        for (const auto& ns : {clientNs_, serverNs_}) {
            // IPv6 off: its router solicitations would be captured as noise.
            runCommand(
                {"ip", "netns", "exec", ns, "sysctl", "-qw", "net.ipv6.conf.all.disable_ipv6=1"},
                config_.log);
            ip({"-n", ns, "link", "set", ns, "up"});
            ip({"-n", ns, "link", "set", "lo", "up"});
            ip({"-n", ns, "route", "add", "224.0.0.0/4", "dev", ns});
            if (config_.shape)
                if (runCommand({"tc", "-n", ns, "qdisc", "add", "dev", ns, "root", "tbf", "rate",
                                config_.rate, "burst", config_.burst, "latency", config_.latency},
                               config_.log) != 0)
                    throw std::runtime_error("tc qdisc add ... tbf failed (see " + config_.log +
                                             ")");
        }
    } catch (...) {
        remove();
        throw;
    }
}

NetPair::~NetPair() { remove(); }

void NetPair::ip(const std::vector<std::string>& args) {
    std::vector<std::string> argv = {"ip"};
    argv.insert(argv.end(), args.begin(), args.end());
    if (runCommand(argv, config_.log) != 0) {
        std::string cmd;
        for (const auto& a : argv) cmd += (cmd.empty() ? "" : " ") + a;
        throw std::runtime_error("`" + cmd + "` failed (see " + config_.log + ")");
    }
}

void NetPair::remove() {
    if (!created_) return;
    created_ = false;
    // The qdiscs go with the devices, the devices (a veth pair goes as a pair) with the
    // namespaces; deleting the device first does not depend on every process having left.
    for (const auto& ns : {clientNs_, serverNs_}) {
        runCommand({"ip", "-n", ns, "link", "del", ns}, config_.log);
        runCommand({"ip", "netns", "del", ns}, config_.log);
    }
    runCommand({"ip", "link", "del", clientNs_}, config_.log);  // if it never moved
}

std::string NetPair::describe() const {
    std::string s = "veth pair " + clientNs_ + " (" + kClientAddr + ", client netns " + clientNs_ +
                    ") <-> " + serverNs_ + " (" + kServerAddr + ", server netns " + serverNs_ + ")";
    if (config_.shape)
        s += ", both ends `tc qdisc add dev ... root tbf rate " + config_.rate + " burst " +
             config_.burst + " latency " + config_.latency + "`";
    return s;
}

bool waitForPort(const std::string& netns, const std::string& addr, int port,
                 std::chrono::milliseconds timeout) {
    bool ok = false;
    // setns affects only the calling thread: a short-lived thread does the probing.
    std::thread t([&] {
        if (!netns.empty()) {
            const int fd = ::open(("/var/run/netns/" + netns).c_str(), O_RDONLY | O_CLOEXEC);
            if (fd < 0) return;
            const bool entered = ::setns(fd, CLONE_NEWNET) == 0;
            ::close(fd);
            if (!entered) return;
        }
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(static_cast<std::uint16_t>(port));
        if (::inet_pton(AF_INET, addr.c_str(), &a.sin_addr) != 1) return;
        const auto end = std::chrono::steady_clock::now() + timeout;
        while (!stopRequested()) {
            const int s = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
            if (s < 0) return;
            const bool connected = ::connect(s, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
            ::close(s);
            if (connected) {
                ok = true;
                return;
            }
            if (std::chrono::steady_clock::now() >= end) return;
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
    });
    t.join();
    return ok;
}

std::vector<std::string> listNamespaces() {
    std::vector<std::string> out;
    DIR* d = ::opendir("/var/run/netns");
    if (!d) return out;
    while (dirent* e = ::readdir(d)) {
        const std::string n = e->d_name;
        if (n != "." && n != "..") out.push_back(n);
    }
    ::closedir(d);
    return out;
}

std::vector<std::string> removeStaleNamespaces(const std::string& log) {
    std::vector<std::string> removed;
    for (const auto& n : listNamespaces()) {
        if (n.rfind("pnpmw", 0) != 0 || n.size() < 7) continue;
        const std::string digits = n.substr(5, n.size() - 6);
        if (digits.empty() || digits.find_first_not_of("0123456789") != std::string::npos) continue;
        const pid_t owner = static_cast<pid_t>(std::atol(digits.c_str()));
        if (owner == ::getpid() || ::kill(owner, 0) == 0) continue;  // its runner still runs
        runCommand({"ip", "-n", n, "link", "del", n}, log);
        runCommand({"ip", "netns", "del", n}, log);
        removed.push_back(n);
    }
    return removed;
}

void enableMulticast(const std::string& ns, const std::string& dev, const std::string& log) {
    runCommand({"ip", "-n", ns, "link", "set", "lo", "up"}, log);
    runCommand({"ip", "-n", ns, "link", "set", dev, "multicast", "on"}, log);
    runCommand({"ip", "-n", ns, "route", "add", "224.0.0.0/4", "dev", dev}, log);
}

}  // namespace pnp::bench::runner
