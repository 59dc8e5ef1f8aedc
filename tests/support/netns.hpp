// Simulated hosts for tests: Linux network namespaces joined by veth pairs to layer-2
// segments (bridges living in a "switch" namespace of their own). Everything a Lab creates
// it removes in its destructor, also when the test failed: deleting a namespace destroys its
// interfaces. Names carry the test's PID, so parallel runs do not collide, and namespaces
// left behind by a killed run (its PID gone) are removed by the next one.
//
// Needs root (CAP_NET_ADMIN) and `ip` (iproute2): canCreateNetworkNamespaces() tells, so a
// test can GTEST_SKIP() with a clear message otherwise.
#pragma once

#include <fcntl.h>
#include <sched.h>
#include <signal.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace pnp::testing {

// Runs a shell command, output discarded; true on exit status 0.
inline bool shellOk(const std::string& command) {
    return std::system((command + " >/dev/null 2>&1").c_str()) == 0;
}
// Runs a shell command; throws with the command's output when it fails.
inline void shell(const std::string& command) {
    std::string out;
    FILE* p = ::popen((command + " 2>&1").c_str(), "r");
    if (!p) throw std::runtime_error("cannot run: " + command);
    char buf[512];
    while (std::fgets(buf, sizeof buf, p)) out += buf;
    if (::pclose(p) != 0) throw std::runtime_error("failed: " + command + ": " + out);
}

// Namespaces of earlier runs whose process is gone ("pnp<PID>-...").
inline void removeStaleNamespaces() {
    FILE* p = ::popen("ip netns list 2>/dev/null", "r");
    if (!p) return;
    std::vector<std::string> stale;
    char buf[256];
    while (std::fgets(buf, sizeof buf, p)) {
        std::string name(buf);
        name = name.substr(0, name.find_first_of(" \n"));
        if (name.rfind("pnp", 0) != 0) continue;
        const auto dash = name.find('-');
        if (dash == std::string::npos || dash <= 3) continue;
        const pid_t pid = static_cast<pid_t>(std::atol(name.substr(3, dash - 3).c_str()));
        if (pid > 0 && ::kill(pid, 0) != 0) stale.push_back(name);
    }
    ::pclose(p);
    for (const auto& n : stale) shellOk("ip netns del " + n);
}

inline bool canCreateNetworkNamespaces() {
    if (::geteuid() != 0) return false;
    const std::string probe = "pnp" + std::to_string(::getpid()) + "-probe";
    if (!shellOk("ip netns add " + probe)) return false;
    shellOk("ip netns del " + probe);
    return true;
}

// Moves the calling thread into a namespace until destroyed (threads it starts meanwhile
// stay there: they inherit the namespace). Sockets keep the namespace they were made in.
class EnterNetNs {
  public:
    explicit EnterNetNs(const std::string& name) {
        self_ = ::open("/proc/thread-self/ns/net", O_RDONLY | O_CLOEXEC);
        const int target = ::open(("/var/run/netns/" + name).c_str(), O_RDONLY | O_CLOEXEC);
        if (self_ < 0 || target < 0 || ::setns(target, CLONE_NEWNET) != 0) {
            if (target >= 0) ::close(target);
            if (self_ >= 0) ::close(self_);
            throw std::runtime_error("cannot enter network namespace " + name);
        }
        ::close(target);
    }
    ~EnterNetNs() {
        ::setns(self_, CLONE_NEWNET);
        ::close(self_);
    }
    EnterNetNs(const EnterNetNs&) = delete;
    EnterNetNs& operator=(const EnterNetNs&) = delete;

  private:
    int self_ = -1;
};

class Lab {
  public:
    Lab() : prefix_("pnp" + std::to_string(::getpid()) + "-") {
        removeStaleNamespaces();
        switch_ = addNamespace("sw");
    }
    ~Lab() {
        for (auto it = namespaces_.rbegin(); it != namespaces_.rend(); ++it)
            shellOk("ip netns del " + *it);
    }
    Lab(const Lab&) = delete;
    Lab& operator=(const Lab&) = delete;

    // A host: a namespace with its loopback up. Returns the namespace's full name.
    std::string host(const std::string& name) {
        auto it = hosts_.find(name);
        if (it != hosts_.end()) return it->second;
        std::string ns = addNamespace(name);
        shell("ip -n " + ns + " link set lo up");
        hosts_[name] = ns;
        return ns;
    }
    // A layer-2 segment (a bridge in the switch namespace).
    void segment(const std::string& name) {
        const std::string br = "br" + std::to_string(segments_.size());
        shell("ip -n " + switch_ + " link add " + br + " type bridge");
        shell("ip -n " + switch_ + " link set " + br + " up");
        segments_[name] = br;
    }
    // Plugs a host into a segment: interface `ifname` in the host with address `cidr`.
    void attach(const std::string& hostName, const std::string& segmentName,
                const std::string& ifname, const std::string& cidr) {
        const std::string ns = host(hostName);
        const std::string peer = "p" + std::to_string(++ports_);
        shell("ip -n " + ns + " link add " + ifname + " type veth peer name " + peer + " netns " +
              switch_);
        shell("ip -n " + switch_ + " link set " + peer + " master " + segments_.at(segmentName) +
              " up");
        shell("ip -n " + ns + " addr add " + cidr + " dev " + ifname);
        shell("ip -n " + ns + " link set " + ifname + " up");
    }
    void route(const std::string& hostName, const std::string& destination,
               const std::string& via) {
        shell("ip -n " + host(hostName) + " route add " + destination + " via " + via);
    }
    void forwarding(const std::string& hostName) {
        shell("ip netns exec " + host(hostName) + " sysctl -q -w net.ipv4.ip_forward=1");
    }
    void link(const std::string& hostName, const std::string& ifname, bool up) {
        shell("ip -n " + host(hostName) + " link set " + ifname + (up ? " up" : " down"));
    }
    // argv prefixed so that the program runs inside the host (same PID: `ip netns exec`
    // execs it).
    std::vector<std::string> inHost(const std::string& hostName, std::vector<std::string> argv) {
        std::vector<std::string> out{ipPath(), "netns", "exec", host(hostName)};
        out.insert(out.end(), argv.begin(), argv.end());
        return out;
    }

  private:
    std::string addNamespace(const std::string& name) {
        const std::string ns = prefix_ + name;
        shellOk("ip netns del " + ns);
        shell("ip netns add " + ns);
        namespaces_.push_back(ns);
        return ns;
    }
    static std::string ipPath() {
        for (const char* p : {"/usr/sbin/ip", "/sbin/ip", "/usr/bin/ip", "/bin/ip"})
            if (::access(p, X_OK) == 0) return p;
        return "ip";
    }

    std::string prefix_;
    std::string switch_;
    std::vector<std::string> namespaces_;
    std::map<std::string, std::string> hosts_;
    std::map<std::string, std::string> segments_;
    int ports_ = 0;
};

}  // namespace pnp::testing
