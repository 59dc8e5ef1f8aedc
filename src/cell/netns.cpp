#include "cell/netns.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <thread>

#include "cell/cell.hpp"

namespace pnp::cell {

namespace {

// `ip` from the usual places (the runner may run with a minimal PATH).
std::string ipBinary() {
    for (const char* p : {"/usr/sbin/ip", "/sbin/ip", "/usr/bin/ip", "/bin/ip"})
        if (::access(p, X_OK) == 0) return p;
    return {};
}

}  // namespace

NetworkNamespaces::NetworkNamespaces(const std::vector<std::string>& groups,
                                     const std::filesystem::path& logDir)
    : prefix_("pnpcell" + std::to_string(::getpid()) + "-"),
      hostVeth_("pnpc" + std::to_string(::getpid() % 1000000)),
      log_(logDir / "netns.log") {
    if (::geteuid() != 0)
        throw CellError(
            "--netns needs root (network namespaces, veth, a bridge); run without "
            "--netns for the cell on loopback");
    if (ipBinary().empty()) throw CellError("--netns needs iproute2 (`ip`), not found");
    try {
        const std::string sw = prefix_ + "sw";
        ip({"netns", "add", sw});
        created_.push_back(sw);
        ip({"-n", sw, "link", "add", "bus", "type", "bridge"});
        ip({"-n", sw, "link", "set", "bus", "up"});
        int host = 11;
        int port = 0;
        for (const auto& g : groups) {
            const std::string ns = prefix_ + g;
            const std::string addr = g == "bus" ? "10.77.0.1" : "10.77.0." + std::to_string(host++);
            addresses_[g] = addr;
            ip({"netns", "add", ns});
            created_.push_back(ns);
            ip({"-n", ns, "link", "set", "lo", "up"});
            const std::string peer = "p" + std::to_string(++port);
            ip({"-n", ns, "link", "add", "eth0", "type", "veth", "peer", "name", peer, "netns",
                sw});
            ip({"-n", sw, "link", "set", peer, "master", "bus", "up"});
            ip({"-n", ns, "addr", "add", addr + "/24", "dev", "eth0"});
            ip({"-n", ns, "link", "set", "eth0", "up"});
        }
        // The runner's way onto the bus (its detector, the MES client, the world's reads).
        ip({"link", "add", hostVeth_, "type", "veth", "peer", "name", "runner", "netns", sw});
        ip({"-n", sw, "link", "set", "runner", "master", "bus", "up"});
        ip({"addr", "add", runnerAddress() + "/24", "dev", hostVeth_});
        ip({"link", "set", hostVeth_, "up"});
    } catch (...) {
        for (auto it = created_.rbegin(); it != created_.rend(); ++it) {
            try {
                ip({"netns", "del", *it});
            } catch (...) {
            }
        }
        throw;
    }
}

NetworkNamespaces::~NetworkNamespaces() {
    for (auto it = created_.rbegin(); it != created_.rend(); ++it) {
        try {
            ip({"netns", "del", *it});  // the bridge's namespace takes the runner's veth along
        } catch (...) {
        }
    }
}

std::string NetworkNamespaces::group(const std::string& child) const {
    return addresses_.count(child) ? child : std::string("bus");
}

std::string NetworkNamespaces::name(const std::string& child) const {
    return prefix_ + group(child);
}

std::string NetworkNamespaces::address(const std::string& child) const {
    return addresses_.at(group(child));
}

// Runs `ip ARGS` (10 s at most); throws CellError with its output when it fails.
void NetworkNamespaces::ip(const std::vector<std::string>& args) {
    std::vector<std::string> argv = {ipBinary()};
    argv.insert(argv.end(), args.begin(), args.end());
    std::vector<char*> a;
    for (auto& s : argv) a.push_back(s.data());
    a.push_back(nullptr);
    const std::string log = log_.string();
    const pid_t pid = ::fork();
    if (pid < 0) throw CellError("fork failed");
    if (pid == 0) {
        const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
        if (fd >= 0) {
            ::dup2(fd, STDOUT_FILENO);
            ::dup2(fd, STDERR_FILENO);
        }
        ::execv(a[0], a.data());
        ::_exit(127);
    }
    int status = 0;
    const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (::waitpid(pid, &status, WNOHANG) == 0) {
        if (std::chrono::steady_clock::now() > end) {
            ::kill(pid, SIGKILL);
            ::waitpid(pid, &status, 0);
            throw CellError("ip " + args.front() + ": no answer within 10 s");
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
        std::string cmd = "ip";
        for (const auto& s : args) cmd += " " + s;
        std::ifstream f(log_);
        std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
        if (text.size() > 500) text = text.substr(text.size() - 500);
        throw CellError("`" + cmd + "` failed: " + text);
    }
}

}  // namespace pnp::cell
