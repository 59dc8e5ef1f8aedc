// Two network namespaces joined by a veth pair (the client's and the server's side of the
// network load scenario and of the package-overhead capture), optionally both ends shaped
// with tbf, and helpers to reach into a namespace. Everything is removed by remove() / the
// destructor, also after a partial set-up.
#pragma once

#include <chrono>
#include <string>
#include <vector>

namespace pnp::bench::runner {

struct NetPairConfig {
    std::string name;  // prefix of namespace and device names, <= 13 characters
    bool shape = true;
    std::string rate = "200mbit";  // tbf on both veth ends
    std::string burst = "16kb";
    std::string latency = "1ms";
    std::string log;  // the ip / tc commands and their output
};

class NetPair {
  public:
    explicit NetPair(NetPairConfig config);  // throws std::runtime_error (nothing left behind)
    NetPair(const NetPair&) = delete;
    NetPair& operator=(const NetPair&) = delete;
    ~NetPair();
    void remove();  // idempotent

    const std::string& clientNs() const { return clientNs_; }
    const std::string& serverNs() const { return serverNs_; }
    const std::string& clientDev() const { return clientNs_; }  // the device is named as its ns
    const std::string& serverDev() const { return serverNs_; }
    static constexpr const char* kClientAddr = "10.77.0.1";
    static constexpr const char* kServerAddr = "10.77.0.2";
    // What was set up, for summary.json.
    std::string describe() const;

  private:
    void ip(const std::vector<std::string>& args);
    NetPairConfig config_;
    std::string clientNs_, serverNs_;
    bool created_ = false;
};

// Does ADDR:PORT accept a TCP connection within the timeout? Connects from a thread that
// entered `netns` (empty: the runner's own).
bool waitForPort(const std::string& netns, const std::string& addr, int port,
                 std::chrono::milliseconds timeout);

// Namespaces and veth devices named pnpmw<PID>... of runners that no longer run (a runner
// killed with SIGKILL cannot clean up): removed. Returns their names.
std::vector<std::string> removeStaleNamespaces(const std::string& log);

// Names of the network namespaces in /var/run/netns.
std::vector<std::string> listNamespaces();

// Sets up the loopback of namespace `ns` (up, multicast on, a multicast route via `dev`).
void enableMulticast(const std::string& ns, const std::string& dev, const std::string& log);

}  // namespace pnp::bench::runner
