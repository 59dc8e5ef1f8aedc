#include "ua/discovery/lds_me.hpp"

#include <arpa/inet.h>
#include <netdb.h>

#include "ua/discovery/txt_record.hpp"
#include "ua/server/discovery.hpp"
#include "ua/server/server.hpp"
#include "ua/transport/client_connection.hpp"

namespace pnp::ua::discovery {
namespace {

// An IPv4 address for a discovery URL's host (a dotted address as is, a name resolved).
std::string ipv4Of(const std::string& host) {
    in_addr a{};
    if (::inet_pton(AF_INET, host.c_str(), &a) == 1) return host;
    addrinfo hints{};
    hints.ai_family = AF_INET;
    addrinfo* res = nullptr;
    if (::getaddrinfo(host.c_str(), nullptr, &hints, &res) != 0 || !res) return {};
    char text[INET_ADDRSTRLEN] = {};
    ::inet_ntop(AF_INET, &reinterpret_cast<sockaddr_in*>(res->ai_addr)->sin_addr, text,
                sizeof text);
    ::freeaddrinfo(res);
    return text;
}

}  // namespace

LdsMe::LdsMe(server::Server& server, mdns::Mdns& mdns, LdsMeConfig config)
    : server_(server), mdns_(mdns), config_(std::move(config)) {
    if (config_.instance.empty())
        config_.instance =
            dnsLabel(server_.config().applicationName + "-" + std::to_string(server_.port()));
    if (config_.hostLabel.empty()) config_.hostLabel = dnsLabel(config_.instance + "-host");
    instance_ = config_.instance;
}

LdsMe::~LdsMe() { stop(); }

std::string LdsMe::instance() const {
    std::lock_guard lock(mutex_);
    return instance_;
}

void LdsMe::start() {
    auto* lds = server_.localDiscovery();
    if (!lds) throw std::logic_error("LdsMe: the server's LDS is not enabled");
    {
        std::lock_guard lock(mutex_);
        if (started_) return;
        started_ = true;
    }
    const auto& dc = server_.config().discovery;
    Announcement self;
    self.path = server_.config().endpointPath;
    self.capabilities = {"LDS"};
    for (const auto& c : dc.serverCapabilities)
        if (!hasCapability(self.capabilities, c)) self.capabilities.push_back(c);
    self.group = dc.discoveryGroup;
    self.level = dc.discoveryLevel;
    mdns::ServiceRecord record;
    record.instance = config_.instance;
    record.type = kServiceType;
    record.host = config_.hostLabel;
    record.port = server_.port();
    record.txt = makeTxt(self);
    self_ = mdns_.publish(std::move(record), [this](const std::string& renamed) {
        std::lock_guard lock(mutex_);
        instance_ = renamed;
    });
    observer_ = lds->onRegistrationsChanged(
        [this](const server::RegistrationEvent& e) { onRegistration(e); });
    browse_ = mdns_.browse(kServiceType, [lds](const mdns::DiscoveredService& s, bool up) {
        const Announcement a = parseTxt(s.txt);
        const std::string host = urlHost(s.host, s.addresses);
        const std::string url = discoveryUrl(host, s.port, a.path);
        if (up)
            lds->addNetworkRecord({s.instance, url, a.capabilities});
        else
            lds->removeNetworkRecord(s.instance, url);
    });
    // Servers that registered before the glue was started.
    for (const auto& r : lds->registeredServers()) {
        server::RegistrationEvent e;
        e.registration = r;
        onRegistration(e);
    }
}

void LdsMe::stop() {
    std::map<std::string, mdns::Mdns::PublicationId> announced;
    {
        std::lock_guard lock(mutex_);
        if (!started_) return;
        started_ = false;
        announced.swap(announced_);
    }
    if (auto* lds = server_.localDiscovery()) lds->removeObserver(observer_);
    mdns_.stopBrowse(browse_);
    for (const auto& [uri, id] : announced) mdns_.withdraw(id);
    mdns_.withdraw(self_);
}

void LdsMe::onRegistration(const server::RegistrationEvent& e) {
    using Kind = server::RegistrationEvent::Kind;
    if (e.kind == Kind::Overflow) {
        // Events were dropped: announce again from the LDS's current table.
        std::map<std::string, mdns::Mdns::PublicationId> announced;
        {
            std::lock_guard lock(mutex_);
            if (!started_) return;
            announced.swap(announced_);
        }
        for (const auto& [uri, id] : announced) mdns_.withdraw(id);
        if (auto* lds = server_.localDiscovery())
            for (const auto& r : lds->registeredServers()) {
                server::RegistrationEvent added;
                added.registration = r;
                onRegistration(added);
            }
        return;
    }
    const auto& reg = e.registration;
    const std::string& uri = reg.server.serverUri;
    mdns::Mdns::PublicationId old = 0;
    {
        std::lock_guard lock(mutex_);
        if (!started_) return;
        auto it = announced_.find(uri);
        if (it != announced_.end()) {
            old = it->second;
            announced_.erase(it);
        }
    }
    if (old) mdns_.withdraw(old);
    if (e.kind == Kind::Removed || !reg.mdns || reg.server.discoveryUrls.empty()) return;
    // The first opc.tcp discovery URL is announced (Part 12: one service per URL would
    // need one instance name per URL, which MdnsDiscoveryConfiguration has only one of).
    for (const auto& url : reg.server.discoveryUrls) {
        transport::EndpointUrl u;
        try {
            u = transport::parseEndpointUrl(url);
        } catch (const std::exception&) {
            continue;
        }
        const std::string address = ipv4Of(u.host);
        if (address.empty()) continue;
        Announcement a;
        a.path = u.path == "/" ? std::string() : u.path;
        a.capabilities = reg.mdns->serverCapabilities;
        mdns::ServiceRecord record;
        record.instance =
            dnsLabel(reg.mdns->mdnsServerName.empty() ? uri : reg.mdns->mdnsServerName);
        record.type = kServiceType;
        record.host = dnsLabel(record.instance + "-host");
        record.port = u.port;
        record.txt = makeTxt(a);
        record.address = address;
        try {
            const auto id = mdns_.publish(std::move(record));
            std::lock_guard lock(mutex_);
            announced_[uri] = id;
        } catch (const std::exception&) {
            continue;  // not announceable (name); FindServersOnNetwork still lists it
        }
        break;
    }
}

}  // namespace pnp::ua::discovery
