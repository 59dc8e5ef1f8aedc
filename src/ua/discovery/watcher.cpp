#include "ua/discovery/watcher.hpp"

#include <algorithm>
#include <cctype>

#include "ua/client/client.hpp"
#include "ua/discovery/txt_record.hpp"
#include "ua/transport/client_connection.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::discovery {

std::string normaliseUrl(const std::string& url) {
    try {
        auto u = transport::parseEndpointUrl(url);
        std::string host = u.host;
        for (auto& c : host) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        std::string path = u.path == "/" ? std::string() : u.path;
        return discoveryUrl(host, u.port, path);
    } catch (const std::exception&) {
        return {};
    }
}

DiscoveryWatcher::DiscoveryWatcher(mdns::Mdns* mdns, WatcherConfig config, Callback callback)
    : mdns_(mdns),
      config_(std::move(config)),
      callback_(std::move(callback)),
      worker_(mutex_, wake_) {}

DiscoveryWatcher::~DiscoveryWatcher() { stop(); }

void DiscoveryWatcher::start() {
    worker_.start(
        mdns_,
        [this](const mdns::DiscoveredService& s, bool up) {
            if (events_.size() < 4 * config_.maxServers) events_.push_back({s, up});
        },
        [this](std::stop_token st) { run(st); });
}

void DiscoveryWatcher::stop() { worker_.stop(); }

std::vector<DiscoveredServer> DiscoveryWatcher::servers() const {
    std::lock_guard lock(mutex_);
    std::vector<DiscoveredServer> out;
    for (const auto& [url, e] : servers_)
        if (e.reported) out.push_back(e.server);
    return out;
}

void DiscoveryWatcher::addSource(const std::string& rawUrl, const std::string& name,
                                 const std::vector<std::string>& caps, const std::string& source) {
    const std::string url = normaliseUrl(rawUrl);
    if (url.empty()) return;
    std::lock_guard lock(mutex_);
    auto it = servers_.find(url);
    if (it == servers_.end()) {
        if (servers_.size() >= config_.maxServers) return;
        it = servers_.emplace(url, Entry{}).first;
        it->second.server.discoveryUrl = url;
    }
    auto& s = it->second.server;
    if (s.name.empty() || source == "mdns") s.name = name;
    for (const auto& c : caps)
        if (!hasCapability(s.capabilities, c)) s.capabilities.push_back(c);
    s.sources.insert(source);
}

void DiscoveryWatcher::removeSource(const std::string& rawUrl, const std::string& source) {
    const std::string url = normaliseUrl(rawUrl);
    std::lock_guard lock(mutex_);
    auto it = servers_.find(url);
    if (it != servers_.end()) it->second.server.sources.erase(source);
}

void DiscoveryWatcher::pollLds(const std::string& ldsUrl) {
    std::set<std::string> listed;
    bool ok = false;
    try {
        client::ClientConfig cc;
        cc.requestTimeout = config_.requestTimeout;
        cc.connectTimeout = config_.requestTimeout;
        client::Client c(cc);
        FindServersOnNetworkRequest req{};
        auto resp = c.discoveryRequest(ldsUrl, std::move(req), config_.requestTimeout);
        ok = true;
        for (const auto& r : resp.servers) {
            const std::string url = normaliseUrl(r.discoveryUrl);
            if (url.empty() || listed.size() >= config_.maxServers) continue;
            listed.insert(url);
            addSource(url, r.serverName, r.serverCapabilities, ldsUrl);
        }
    } catch (const std::exception&) {
        // Not answering: whatever it listed is no longer vouched for by it.
    }
    (void)ok;
    auto& before = ldsListed_[ldsUrl];
    for (const auto& url : before)
        if (!listed.count(url)) removeSource(url, ldsUrl);
    before = std::move(listed);
}

void DiscoveryWatcher::settle() {
    // Servers without a source: down. New servers: details, then up.
    std::vector<DiscoveredServer> gone;
    std::vector<std::string> fresh;
    {
        std::lock_guard lock(mutex_);
        for (auto it = servers_.begin(); it != servers_.end();) {
            if (it->second.server.sources.empty()) {
                if (it->second.reported) gone.push_back(it->second.server);
                it = servers_.erase(it);
            } else {
                if (!it->second.reported) fresh.push_back(it->first);
                ++it;
            }
        }
    }
    for (const auto& s : gone) callback_(s, false);
    for (const auto& url : fresh) {
        std::optional<ApplicationDescription> app;
        std::vector<EndpointDescription> endpoints;
        std::string error;
        if (config_.fetchDetails) {
            try {
                client::ClientConfig cc;
                cc.requestTimeout = config_.requestTimeout;
                cc.connectTimeout = config_.requestTimeout;
                client::Client c(cc);
                // One round trip: every EndpointDescription carries the server's
                // ApplicationDescription.
                endpoints = c.getEndpoints(url, config_.requestTimeout);
                if (!endpoints.empty()) app = endpoints.front().server;
            } catch (const std::exception& e) {
                error = e.what();
            }
        }
        DiscoveredServer copy;
        {
            std::lock_guard lock(mutex_);
            auto it = servers_.find(url);
            if (it == servers_.end() || it->second.server.sources.empty()) continue;
            it->second.server.application = std::move(app);
            it->second.server.endpoints = std::move(endpoints);
            it->second.server.detailsError = std::move(error);
            it->second.reported = true;
            copy = it->second.server;
        }
        callback_(copy, true);
    }
}

void DiscoveryWatcher::run(std::stop_token stop) {
    using Clock = std::chrono::steady_clock;
    Clock::time_point nextPoll = Clock::now();
    int quickPolls = 0;  // after a goodbye: polls 20 ms apart (an LDS-ME may not have seen it yet)
    while (!stop.stop_requested()) {
        std::deque<MdnsEvent> events;
        {
            std::lock_guard lock(mutex_);
            events.swap(events_);
        }
        for (const auto& e : events) {
            const Announcement a = parseTxt(e.service.txt);
            const std::string host = urlHost(e.service.host, e.service.addresses);
            const std::string url = discoveryUrl(host, e.service.port, a.path);
            if (e.up) {
                addSource(url, e.service.instance, a.capabilities, "mdns");
            } else {
                removeSource(url, "mdns");
                // A goodbye: the LDS-MEs have most likely dropped it too; ask them now (and
                // twice more shortly, for one that had not processed the goodbye yet) rather
                // than report it gone only at the next regular poll.
                nextPoll = Clock::now();
                quickPolls = 3;
            }
        }
        if (Clock::now() >= nextPoll) {
            // Every LDS-ME known (configured, announced, or listed by another one).
            std::set<std::string> lds;
            for (const auto& u : config_.ldsUrls) lds.insert(normaliseUrl(u));
            if (config_.followLds) {
                std::lock_guard lock(mutex_);
                for (const auto& [url, e] : servers_)
                    if (hasCapability(e.server.capabilities, "LDS") && lds.size() < config_.maxLds)
                        lds.insert(url);
            }
            lds.erase(std::string());
            for (const auto& url : lds) pollLds(url);
            // An LDS-ME no longer known: forget what it listed.
            for (auto it = ldsListed_.begin(); it != ldsListed_.end();) {
                if (lds.count(it->first)) {
                    ++it;
                    continue;
                }
                for (const auto& url : it->second) removeSource(url, it->first);
                it = ldsListed_.erase(it);
            }
            nextPoll = Clock::now() +
                       (quickPolls > 0 ? std::chrono::milliseconds(20) : config_.pollInterval);
            if (quickPolls > 0) --quickPolls;
        }
        settle();
        std::unique_lock lock(mutex_);
        wake_.wait_until(lock, stop, nextPoll, [this] { return !events_.empty(); });
    }
}

}  // namespace pnp::ua::discovery
