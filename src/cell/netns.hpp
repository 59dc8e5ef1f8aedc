// `pnp cell up|run --netns`: the cell's processes in network namespaces, as a plant's would
// be on machines of their own (root and iproute2 only). One bridge (in a namespace of its
// own) is the cell bus 10.77.0.0/24; the namespace "bus" (.1) holds the LDS-ME, the MES, the
// simulator and the software components; every device has a namespace of its own (.11 on);
// the runner stays in its namespace and reaches the bus through a veth (.254). Multicast
// (mDNS) works between them. Everything is removed in the destructor (deleting a namespace
// deletes its veth ends and the bridge).
#pragma once

#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace pnp::cell {

class NetworkNamespaces {
  public:
    // `groups`: "bus" and one per device; throws CellError (not root, no `ip`, a command
    // failed: which and why).
    NetworkNamespaces(const std::vector<std::string>& groups, const std::filesystem::path& logDir);
    ~NetworkNamespaces();
    NetworkNamespaces(const NetworkNamespaces&) = delete;
    NetworkNamespaces& operator=(const NetworkNamespaces&) = delete;

    // The namespace a child runs in (its own group, else "bus") and its address there.
    std::string name(const std::string& child) const;
    std::string address(const std::string& child) const;
    std::string runnerAddress() const { return "10.77.0.254"; }
    const std::string& prefix() const { return prefix_; }

  private:
    std::string group(const std::string& child) const;
    void ip(const std::vector<std::string>& args);

    std::string prefix_;
    std::string hostVeth_;
    std::filesystem::path log_;
    std::map<std::string, std::string> addresses_;  // group -> address
    std::vector<std::string> created_;              // namespaces, to delete
};

}  // namespace pnp::cell
