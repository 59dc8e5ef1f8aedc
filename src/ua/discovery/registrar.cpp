#include "ua/discovery/registrar.hpp"

#include <algorithm>
#include <tuple>

#include "ua/client/client.hpp"
#include "ua/discovery/txt_record.hpp"
#include "ua/server/server.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::discovery {

Registrar::Registrar(server::Server& server, mdns::Mdns* mdns, RegistrarConfig config)
    : server_(server), mdns_(mdns), config_(std::move(config)), worker_(mutex_, wake_) {
    const auto& sc = server_.config();
    if (config_.mdnsServerName.empty())
        config_.mdnsServerName =
            dnsLabel(sc.applicationName + "-" + std::to_string(server_.port()));
    if (config_.capabilities.empty()) config_.capabilities = {"NA"};
    if (config_.discoveryUrls.empty()) config_.discoveryUrls = {server_.endpointUrl()};
}

Registrar::~Registrar() { stop(); }

void Registrar::start() {
    if (worker_.running()) return;
    worker_.start(
        config_.ldsUrl.empty() ? mdns_ : nullptr,
        [this](const mdns::DiscoveredService& s, bool) {
            if (hasCapability(parseTxt(s.txt).capabilities, "LDS")) changed_ = true;
        },
        [this](std::stop_token st) { run(st); });
}

void Registrar::stop() {
    if (!worker_.running()) return;
    worker_.stop();
    std::string last;
    {
        std::lock_guard lock(mutex_);
        last = std::exchange(registeredWith_, {});
        current_.clear();
    }
    if (!last.empty()) registerWith(last, false);
}

std::string Registrar::currentLds() const {
    std::lock_guard lock(mutex_);
    return registeredWith_;
}

std::uint64_t Registrar::registrations() const {
    std::lock_guard lock(mutex_);
    return registrations_;
}

void Registrar::onLdsChanged(std::function<void(const std::string&)> callback) {
    std::lock_guard lock(mutex_);
    onLdsChanged_ = std::move(callback);
}

std::string Registrar::choose() const {
    if (!config_.ldsUrl.empty()) return config_.ldsUrl;
    if (!mdns_) return {};
    struct Candidate {
        int level;
        std::string instance, url;
    };
    std::optional<Candidate> best;
    for (const auto& s : mdns_->services(kServiceType)) {
        const Announcement a = parseTxt(s.txt);
        if (!hasCapability(a.capabilities, "LDS") || a.group != config_.discoveryGroup) continue;
        if (!config_.ownInstance.empty() && s.instance == config_.ownInstance) continue;
        const int level = a.level.value_or(0);
        if (config_.ownLevel && level >= *config_.ownLevel) continue;
        const std::string host = urlHost(s.host, s.addresses);
        Candidate c{level, s.instance, discoveryUrl(host, s.port, a.path)};
        if (std::find(config_.discoveryUrls.begin(), config_.discoveryUrls.end(), c.url) !=
            config_.discoveryUrls.end())
            continue;  // ourselves
        // Highest level first; then the lowest instance name and URL.
        if (!best || c.level > best->level ||
            (c.level == best->level &&
             std::tie(c.instance, c.url) < std::tie(best->instance, best->url)))
            best = c;
    }
    return best ? best->url : std::string();
}

bool Registrar::registerWith(const std::string& url, bool online) {
    const auto& sc = server_.config();
    RegisterServer2Request req{};
    req.server.serverUri = sc.applicationUri;
    req.server.productUri = sc.productUri;
    req.server.serverNames = {LocalizedText("", sc.applicationName)};
    req.server.serverType = ApplicationType::Server;
    req.server.discoveryUrls = config_.discoveryUrls;
    req.server.isOnline = online;
    MdnsDiscoveryConfiguration mdnsConfig{};
    mdnsConfig.mdnsServerName = config_.mdnsServerName;
    mdnsConfig.serverCapabilities = config_.capabilities;
    req.discoveryConfiguration = {toExtensionObject(mdnsConfig)};
    try {
        if (!client_) {
            client::ClientConfig cc;
            cc.requestTimeout = config_.requestTimeout;
            cc.connectTimeout = config_.connectTimeout;
            // One (secured) channel to the LDS-ME for all renewals, not one per renewal.
            cc.keepDiscoveryConnection = true;
            client_ = std::make_unique<client::Client>(cc);
        }
        // A registration may have to open the secured channel first; leaving (stop(), a move to
        // another LDS-ME) stays within requestTimeout.
        client_->discoveryRequest(url, std::move(req),
                                  online ? config_.connectTimeout : config_.requestTimeout);
        return true;
    } catch (const std::exception&) {
        return false;  // tried again after retryInterval
    }
}

void Registrar::run(std::stop_token stop) {
    using Clock = std::chrono::steady_clock;
    Clock::time_point due = Clock::now();
    while (!stop.stop_requested()) {
        std::string target;
        std::string previous;
        {
            std::lock_guard lock(mutex_);
            if (changed_) {
                changed_ = false;
                target = choose();
                // No candidate announced (a lost refresh, an interface that went down): keep
                // the current LDS-ME and keep trying it, rather than unregister and flap.
                if (target.empty()) target = current_;
                if (target != current_) {
                    previous = registeredWith_;
                    current_ = target;
                    due = Clock::now();  // register with the new choice at once
                }
            }
            target = current_;
        }
        if (!previous.empty() && previous != target) {
            registerWith(previous, false);  // moved: leave the old one at once
            std::lock_guard lock(mutex_);
            registeredWith_.clear();
        }
        if (!target.empty() && Clock::now() >= due) {
            const bool ok = registerWith(target, true);
            std::function<void(const std::string&)> cb;
            {
                std::lock_guard lock(mutex_);
                if (ok) {
                    ++registrations_;
                    if (registeredWith_ != target) {
                        registeredWith_ = target;
                        cb = onLdsChanged_;
                    }
                }
            }
            if (cb) cb(target);
            due = Clock::now() + (ok ? config_.interval : config_.retryInterval);
        }
        std::unique_lock lock(mutex_);
        const auto until = target.empty() ? Clock::now() + config_.interval : due;
        wake_.wait_until(lock, stop, until, [this] { return changed_; });
    }
}

}  // namespace pnp::ua::discovery
