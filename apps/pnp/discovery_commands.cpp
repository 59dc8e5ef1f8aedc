// Discovery in the CLI: `pnp lds`, `pnp discover`, and the registration / LDS-ME part of
// `pnp ua serve` (docs/discovery.md).
#include "discovery_commands.hpp"

#include <arpa/inet.h>
#include <ifaddrs.h>
#include <net/if.h>
#include <netinet/in.h>
#include <pthread.h>
#include <signal.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <mutex>
#include <nlohmann/json.hpp>

#include "output.hpp"
#include "ua/discovery/lds_me.hpp"
#include "ua/discovery/registrar.hpp"
#include "ua/discovery/txt_record.hpp"
#include "ua/discovery/watcher.hpp"
#include "ua/server/server.hpp"

namespace pnp::cli {
namespace {

bool isLoopback(const std::string& host) {
    return host == "localhost" || host.rfind("127.", 0) == 0 || host == "::1";
}
bool isWildcard(const std::string& host) {
    return host.empty() || host == "0.0.0.0" || host == "::";
}

// The interface that owns an IPv4 address, or "".
std::string interfaceOf(const std::string& address) {
    in_addr want{};
    if (::inet_pton(AF_INET, address.c_str(), &want) != 1) return {};
    ifaddrs* list = nullptr;
    if (::getifaddrs(&list) != 0) return {};
    std::string name;
    for (auto* i = list; i; i = i->ifa_next)
        if (i->ifa_addr && i->ifa_addr->sa_family == AF_INET &&
            reinterpret_cast<sockaddr_in*>(i->ifa_addr)->sin_addr.s_addr == want.s_addr) {
            name = i->ifa_name;
            break;
        }
    ::freeifaddrs(list);
    return name;
}

std::string hostName() {
    char buf[256] = {};
    if (::gethostname(buf, sizeof buf - 1) != 0) return "localhost";
    return buf;
}

}  // namespace

mdns::MdnsConfig mdnsConfig(const std::vector<std::string>& interfaces, int port, int ttl) {
    mdns::MdnsConfig c;
    c.interfaces = interfaces;
    c.port = static_cast<std::uint16_t>(port);
    c.hostTtl = c.otherTtl = static_cast<std::uint32_t>(ttl);
    return c;
}

void applyDiscoveryConfig(ua::server::ServerConfig& config, const DiscoveryOptions& o, bool lds) {
    if (!o.publicHost.empty())
        config.publicHost = o.publicHost;
    else if (!isWildcard(config.host))
        config.publicHost = config.host;
    const std::string host = config.publicHost.empty() ? hostName() : config.publicHost;
    config.applicationUri =
        !o.applicationUri.empty()
            ? o.applicationUri
            : "urn:pnp:" + host + ":" +
                  (config.port ? std::to_string(config.port) : "pid" + std::to_string(::getpid()));
    if (!o.name.empty()) config.applicationName = o.name;
    auto& d = config.discovery;
    d.localDiscoveryServer = lds || o.ldsMe;
    d.discoveryGroup = o.group;
    d.discoveryLevel = o.level >= 0 ? o.level : (lds ? 0 : 1);
    d.registrationExpiry = std::chrono::milliseconds(o.expiryMs);
    // Secure by default; an ApplicationUri made from the pid lives as long as the process.
    secureServer(config, o.security, o.applicationUri.empty() && config.port == 0);
}

MdnsScope mdnsScope(const std::string& host, const std::vector<std::string>& mdnsInterfaces) {
    MdnsScope scope{.multicast = true, .interfaces = mdnsInterfaces};
    if (!scope.interfaces.empty() || isWildcard(host)) return scope;
    // Listening on one address: announce and look only where we can be reached.
    if (isLoopback(host))
        scope.multicast = false;
    else if (auto ifname = interfaceOf(host); !ifname.empty())
        scope.interfaces = {ifname};
    return scope;
}

DiscoveryRuntime::DiscoveryRuntime(ua::server::Server& server, const DiscoveryOptions& o) {
    const auto& config = server.config();
    const bool lds = config.discovery.localDiscoveryServer;
    const bool registering = !o.noRegister && !(lds && !o.ldsMe && o.lds.empty());
    // `pnp lds` registers nowhere unless told (--lds); `pnp ua serve` does by default.
    const MdnsScope scope = mdnsScope(config.host, o.mdnsInterfaces);
    if (!scope.multicast) status_ = kLoopbackNoMdns;
    const bool needMdns = scope.multicast && (lds || (registering && o.lds.empty()));
    if (needMdns) {
        mdns_ = std::make_unique<mdns::Mdns>(mdnsConfig(scope.interfaces, o.mdnsPort, o.mdnsTtl));
        mdns_->start();
    }
    if (lds && mdns_) {
        ua::discovery::LdsMeConfig lc;
        if (!o.name.empty()) lc.instance = ua::discovery::dnsLabel(o.name);
        ldsMe_ = std::make_unique<ua::discovery::LdsMe>(server, *mdns_, lc);
        ldsMe_->start();
    }
    if (registering && (mdns_ || !o.lds.empty())) {
        ua::discovery::RegistrarConfig rc;
        rc.ldsUrl = o.lds;
        rc.discoveryGroup = o.group;
        if (lds) {
            rc.ownLevel = config.discovery.discoveryLevel;
            rc.capabilities = {"LDS"};
            if (ldsMe_) rc.ownInstance = ldsMe_->instance();
        }
        if (!o.name.empty()) rc.mdnsServerName = ua::discovery::dnsLabel(o.name);
        rc.interval = std::chrono::milliseconds(o.registerIntervalMs);
        registrar_ = std::make_unique<ua::discovery::Registrar>(server, mdns_.get(), rc);
        registrar_->onLdsChanged([](const std::string& url) {
            std::cerr << "pnp: registered with the LDS-ME " << url << std::endl;
        });
        registrar_->start();
    }
    if (status_.empty())
        status_ = std::string(ldsMe_ ? "LDS-ME on; " : "") +
                  (registrar_ ? (o.lds.empty() ? "registering with an LDS-ME found by mDNS"
                                               : "registering with " + o.lds)
                              : "not registering");
}

DiscoveryRuntime::~DiscoveryRuntime() {
    if (registrar_) registrar_->stop();  // unregisters: gone everywhere at once
    if (ldsMe_) ldsMe_->stop();          // goodbyes for what it announced
    if (mdns_) mdns_->stop();
}

// ---- pnp lds -------------------------------------------------------------------------------

int runLds(std::uint16_t port, const std::string& host, const DiscoveryOptions& o) {
    using namespace pnp::ua;
    const sigset_t stopSignals = blockStopSignals();

    server::ServerConfig config;
    config.host = host;
    config.port = port;
    config.applicationName = "pnp LDS-ME";
    applyDiscoveryConfig(config, o, true);
    applyUsers(config, o.security, true);
    server::Server server(config);
    try {
        finishServerSecurity(server, o.security);
        server.start();
    } catch (const std::exception& e) {
        std::cerr << "error: cannot listen on " << host << ":" << port << ": " << e.what() << "\n";
        return kExitUaError;
    }
    std::cout << "listening on " << server.endpointUrl() << std::endl;
    std::unique_ptr<DiscoveryRuntime> discovery;
    try {
        discovery = std::make_unique<DiscoveryRuntime>(server, o);
    } catch (const std::exception& e) {
        std::cerr << "error: mDNS: " << e.what() << "\n";
        server.stop();
        return kExitUaError;
    }
    std::cerr << "pnp lds: " << discovery->status() << "; level " << config.discovery.discoveryLevel
              << ", group \"" << config.discovery.discoveryGroup << "\", registration expiry "
              << o.expiryMs << " ms; stop with Ctrl-C or SIGTERM" << std::endl;
    int sig = 0;
    while (sigwait(&stopSignals, &sig) != 0) {
    }
    discovery.reset();
    server.stop();
    return kExitOk;
}

// ---- pnp discover --------------------------------------------------------------------------

namespace {

nlohmann::json toJson(const ua::discovery::DiscoveredServer& s) {
    nlohmann::json j;
    j["name"] = s.name;
    j["url"] = s.discoveryUrl;
    j["capabilities"] = s.capabilities;
    j["sources"] = std::vector<std::string>(s.sources.begin(), s.sources.end());
    if (s.application) {
        j["applicationUri"] = s.application->applicationUri;
        j["applicationName"] = s.application->applicationName.text;
        j["applicationType"] = std::string(ua::toString(s.application->applicationType));
    }
    nlohmann::json eps = nlohmann::json::array();
    for (const auto& e : s.endpoints)
        eps.push_back({{"url", e.endpointUrl},
                       {"securityPolicyUri", e.securityPolicyUri},
                       {"securityMode", std::string(ua::toString(e.securityMode))}});
    j["endpoints"] = eps;
    if (!s.detailsError.empty()) j["error"] = s.detailsError;
    return j;
}

std::string joined(const std::vector<std::string>& v) {
    std::string out;
    for (const auto& x : v) out += (out.empty() ? "" : ",") + x;
    return out;
}

}  // namespace

int runDiscover(const DiscoverOptions& o) {
    using namespace pnp::ua;
    const sigset_t stopSignals = blockStopSignals();

    std::unique_ptr<mdns::Mdns> mdns;
    if (o.noMdns && o.lds.empty()) throw UsageError("--no-mdns needs at least one --lds URL");
    try {
        if (!o.noMdns) {
            mdns = std::make_unique<mdns::Mdns>(mdnsConfig(o.mdnsInterfaces, o.mdnsPort, 120));
            mdns->start();
        }
    } catch (const std::exception& e) {
        if (o.lds.empty()) {
            std::cerr << "error: mDNS: " << e.what() << "\n";
            return kExitUaError;
        }
        std::cerr << "pnp discover: no mDNS (" << e.what() << "), polling the LDS-MEs only"
                  << std::endl;
        mdns.reset();
    }
    discovery::WatcherConfig wc;
    wc.ldsUrls = o.lds;
    wc.fetchDetails = !o.noDetails;
    wc.pollInterval = std::chrono::milliseconds(o.pollMs);
    std::mutex printMutex;
    const auto t0 = std::chrono::steady_clock::now();
    discovery::DiscoveryWatcher watcher(
        mdns.get(), wc, [&](const discovery::DiscoveredServer& s, bool up) {
            if (o.once) return;
            std::lock_guard lock(printMutex);
            const double ms =
                std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                    .count();
            if (o.json) {
                auto j = toJson(s);
                j["event"] = up ? "up" : "down";
                j["ms"] = ms;
                std::cout << j.dump() << std::endl;
            } else {
                std::cout << (up ? "+ " : "- ") << s.name << "  " << s.discoveryUrl
                          << "  caps=" << joined(s.capabilities);
                if (up)  // a server that went has no source left
                    std::cout << "  via "
                              << joined(
                                     std::vector<std::string>(s.sources.begin(), s.sources.end()));
                if (up && s.application)
                    std::cout << "  (" << s.application->applicationUri << ", "
                              << s.endpoints.size() << " endpoint(s))";
                std::cout << std::endl;
            }
        });
    watcher.start();
    const int duration = o.durationMs > 0 ? o.durationMs : (o.once ? 2000 : 0);
    timespec ts{duration / 1000, (duration % 1000) * 1'000'000L};
    if (duration > 0) {
        while (sigtimedwait(&stopSignals, nullptr, &ts) < 0 && errno == EINTR) {
        }
    } else {
        int sig = 0;
        while (sigwait(&stopSignals, &sig) != 0) {
        }
    }
    auto list = watcher.servers();
    watcher.stop();
    if (o.once) {
        if (o.json) {
            nlohmann::json arr = nlohmann::json::array();
            for (const auto& s : list) arr.push_back(toJson(s));
            std::cout << arr.dump(2) << std::endl;
        } else {
            Table t({"NAME", "URL", "CAPABILITIES", "VIA"});
            for (const auto& s : list)
                t.add({s.name, s.discoveryUrl, joined(s.capabilities),
                       joined(std::vector<std::string>(s.sources.begin(), s.sources.end()))});
            t.print(std::cout);
        }
    }
    return kExitOk;
}

void addDiscoveryOptions(CLI::App* cmd, DiscoveryOptions& o, bool lds) {
    cmd->add_option("--public-host", o.publicHost,
                    "host name or address put into endpoint URLs (default: --host, or the "
                    "host name)");
    cmd->add_option("--application-uri", o.applicationUri,
                    "ApplicationUri (default urn:pnp:<public host>:<port>)");
    cmd->add_option("--name", o.name, "ApplicationName, also the mDNS instance name");
    cmd->add_option("--lds", o.lds,
                    lds ? "register with this (higher) LDS-ME" : "register with this LDS-ME only");
    if (!lds) {
        cmd->add_flag("--no-register", o.noRegister, "do not register with any LDS-ME");
        cmd->add_flag("--lds-me", o.ldsMe,
                      "also be an LDS-ME (a workstation: its devices register here)");
    }
    cmd->add_option("--discovery-group", o.group,
                    "discovery group: register only with LDS-MEs of this group (TXT dg=)");
    cmd->add_option("--discovery-level", o.level,
                    "LDS-ME level (0 = cell bus; default 0 for `pnp lds`, 1 for --lds-me)")
        ->check(CLI::Range(0, 100));
    cmd->add_option("--mdns-interface", o.mdnsInterfaces,
                    "mDNS on this interface (repeatable; default: every multicast interface "
                    "for --host 0.0.0.0, the address's interface otherwise)");
    cmd->add_option("--mdns-port", o.mdnsPort, "mDNS UDP port (5353; tests use another)")
        ->capture_default_str()
        ->check(CLI::Range(1, 65535));
    cmd->add_option("--mdns-ttl", o.mdnsTtl, "TTL of our mDNS records, s")
        ->capture_default_str()
        ->check(CLI::Range(1, 4500));
    cmd->add_option("--registration-expiry", o.expiryMs,
                    "LDS-ME: drop a registration not renewed within MS ms")
        ->capture_default_str()
        ->check(CLI::Range(100, 3600000));
    cmd->add_option("--register-interval", o.registerIntervalMs, "re-register every MS ms")
        ->capture_default_str()
        ->check(CLI::Range(10, 3600000));
    addServerSecurityOptions(cmd, o.security);
}

}  // namespace pnp::cli
