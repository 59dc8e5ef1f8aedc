// The thread of a Registrar or a DiscoveryWatcher: it browses _opcua-tcp._tcp, hands each
// report to the owner (under the owner's mutex) and wakes the owner's loop, which waits on
// the owner's condition variable with the thread's stop token. Stopping ends the browse
// first (no report after stop() returns), then the thread.
#pragma once

#include <condition_variable>
#include <functional>
#include <mutex>
#include <stop_token>
#include <thread>

#include "mdns/mdns.hpp"

namespace pnp::ua::discovery {

class BrowsingWorker {
  public:
    using Report = std::function<void(const mdns::DiscoveredService&, bool up)>;
    BrowsingWorker(std::mutex& mutex, std::condition_variable_any& wake)
        : mutex_(mutex), wake_(wake) {}
    ~BrowsingWorker() { stop(); }
    BrowsingWorker(const BrowsingWorker&) = delete;
    BrowsingWorker& operator=(const BrowsingWorker&) = delete;

    // report runs on the mDNS thread with the owner's mutex held; mdns may be null (no
    // browse). No-op when running.
    void start(mdns::Mdns* mdns, Report report, std::function<void(std::stop_token)> loop);
    void stop();
    bool running() const { return thread_.joinable(); }

  private:
    std::mutex& mutex_;
    std::condition_variable_any& wake_;
    mdns::Mdns* mdns_ = nullptr;
    mdns::Mdns::BrowseId browse_ = 0;
    std::jthread thread_;
};

}  // namespace pnp::ua::discovery
