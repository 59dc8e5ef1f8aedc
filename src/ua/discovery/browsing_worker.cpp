#include "ua/discovery/browsing_worker.hpp"

#include "ua/discovery/txt_record.hpp"

namespace pnp::ua::discovery {

void BrowsingWorker::start(mdns::Mdns* mdns, Report report,
                           std::function<void(std::stop_token)> loop) {
    if (thread_.joinable()) return;
    mdns_ = mdns;
    if (mdns_ && report) {
        browse_ = mdns_->browse(kServiceType, [this, report = std::move(report)](
                                                  const mdns::DiscoveredService& s, bool up) {
            std::lock_guard lock(mutex_);
            report(s, up);
            wake_.notify_all();
        });
    }
    thread_ = std::jthread(std::move(loop));
}

void BrowsingWorker::stop() {
    if (!thread_.joinable()) return;
    if (browse_ && mdns_) mdns_->stopBrowse(browse_);
    browse_ = 0;
    thread_.request_stop();
    {
        std::lock_guard lock(mutex_);
        wake_.notify_all();
    }
    thread_.join();
}

}  // namespace pnp::ua::discovery
